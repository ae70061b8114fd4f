"""The 3D map's panel per browser, with a fake viser client: it acts for an operator's token only
(none, a wrong one or an observer's cannot send, even by pressing the buttons over the websocket), offers
the same fields, ranges and checks as the dashboard (from ``server.operator``), and follows the status
of what it sent."""

from __future__ import annotations

import contextlib
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlmodel import Session, select

from server.app import create_app
from server.map.operator_panel import OperatorPanel
from server.map.scene import OperatorMap
from server.models import Command
from server.settings import Settings

OP = {"Authorization": "Bearer operator-token"}


class Handle(SimpleNamespace):
    def __init__(self, **kw: Any) -> None:
        super().__init__(**{"visible": True, "disabled": False, "hint": None, "callbacks": [], **kw})

    def on_click(self, cb: Any) -> Any:
        self.callbacks.append(cb)
        return cb

    on_update = on_click

    def press(self) -> None:
        """What a websocket client does when it clicks (viser calls the callbacks, whatever the page shows)."""
        for cb in self.callbacks:
            cb(None)


class FakeGui:
    def __init__(self) -> None:
        self.handles: dict[str, Handle] = {}

    def _add(self, label: str, **kw: Any) -> Handle:
        handle = Handle(label=label, **kw)
        self.handles[label] = handle
        return handle

    def add_folder(self, label: str) -> contextlib.AbstractContextManager:
        return contextlib.nullcontext()

    def add_text(self, label: str, value: str, **kw: Any) -> Handle:
        return self._add(label, value=value)

    def add_number(self, label: str, value: float, **kw: Any) -> Handle:
        return self._add(label, value=value, min=None, max=None, step=kw.get("step"))

    def add_dropdown(self, label: str, options: list, initial_value: Any = None, **kw: Any) -> Handle:
        return self._add(label, value=initial_value or options[0], options=list(options))

    def add_checkbox(self, label: str, value: bool, **kw: Any) -> Handle:
        return self._add(label, value=value)

    def add_button(self, label: str, **kw: Any) -> Handle:
        return self._add(label, visible=kw.get("visible", True))

    def add_markdown(self, content: str, **kw: Any) -> Handle:
        return Handle(content=content)

    add_html = add_markdown


@pytest.fixture
def shore_map(tmp_path: Path):
    settings = Settings(database_url=f"sqlite:///{tmp_path}/tacit.db", modem_url="", map_enabled=False,
                        modem_log=str(tmp_path / "modem.log"), write_tokens=["operator-token"],
                        read_tokens=["observer-token"])  # fmt: skip
    with TestClient(create_app(settings)) as client:
        client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2, "max_distance": 50}, headers=OP)
        shore = client.app.state.shore
        yield shore, OperatorMap(shore, "127.0.0.1", 0)


def panel_for(owner: OperatorMap) -> OperatorPanel:
    return OperatorPanel(owner, SimpleNamespace(client_id=1, gui=FakeGui(), scene=None))


def commands(shore: Any) -> list[Command]:
    with Session(shore.db) as s:
        return list(s.exec(select(Command)))


def test_no_token_wrong_token_or_observer_cannot_send(shore_map: tuple) -> None:
    shore, owner = shore_map
    panel = panel_for(owner)
    assert panel.send_btn.disabled and "Watching only" in panel.role_md.content
    panel.send_btn.press()  # a websocket client pressing Send without signing in
    assert "sign in with an operator's token" in panel.status_md.content
    panel.token_in.value = "guess"
    panel.sign_in_btn.press()
    assert "Token not accepted" in panel.role_md.content and panel.send_btn.disabled
    assert panel.sign_in("observer-token") == "read"
    assert panel.send_btn.disabled and "observer" in panel.role_md.content
    panel.send_btn.press()
    panel.confirm_btn.press()
    panel.ask("return_home")
    panel.confirm_btn.press()
    assert commands(shore) == []


def test_an_operator_sends_with_the_same_rules_as_the_dashboard(shore_map: tuple) -> None:
    shore, owner = shore_map
    panel, other = panel_for(owner), panel_for(owner)
    panel.token_in.value = "operator-token"
    panel.sign_in_btn.press()
    assert panel.token_in.value == "" and not panel.send_btn.disabled  # the token does not stay on screen
    assert other.send_btn.disabled  # another browser's panel is not signed in by this one
    distance = panel.inputs["distance"]
    # the vehicle's limit, from the form
    assert (distance.label, panel.ranges["distance"]) == ("Distance (m)", (0.0, 50.0))
    distance.value = 80.0  # what a client can set over the websocket whatever the page's maximum
    panel.send_btn.press()
    assert "Distance must be 0 .. 50 m" in panel.status_md.content and commands(shore) == []
    panel.inputs["angle_mode"].value = "bearing (true)"
    panel.inputs["angle_mode"].press()
    assert panel.inputs["angle"].label == "Bearing (true) (deg)" and panel.ranges["angle"] == (0.0, 360.0)
    distance.value, panel.inputs["angle"].value = 12.0, 270.0
    panel.send_btn.press()
    [sent] = commands(shore)
    assert (sent.command, sent.distance, sent.angle, sent.absolute_angle) == ("move", 12.0, -90.0, True)
    assert "queued" in panel.status_md.content
    panel.command_status({"id": sent.id, "seq": sent.seq, "status": "executed"}, "- #1 move")
    assert "**executed**" in panel.status_md.content and "executed" not in other.status_md.content
    panel.command_dd.value = "goto_depth"
    panel.command_dd.press()
    assert panel.inputs["depth"].label == "Target depth (m)" and not panel.inputs["distance"].visible
    panel.command_dd.value = "move"
    panel.command_dd.press()
    assert panel.inputs["depth"].label == "Depth change (m)"


def test_a_blank_mission_number_is_refused_in_the_panel(shore_map: tuple) -> None:
    shore, owner = shore_map
    panel = panel_for(owner)
    assert panel.sign_in("operator-token") == "write"
    panel.inputs["param_id"].value = None  # a cleared number box, as a websocket client can send it
    panel.ask("start_mission")
    panel.confirm_btn.press()
    assert "not a mission number" in panel.status_md.content and commands(shore) == []
