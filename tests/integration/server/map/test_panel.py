"""The 3D map's panel per browser, with a fake viser client: it acts for an operator's token only
(none, a wrong one or an observer's cannot send, even by pressing the buttons over the websocket), offers
the same fields, ranges and checks as the dashboard (from ``server.operator``), and follows the status
of what it sent."""

from __future__ import annotations

import itertools
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlmodel import Session, select

from launch.demo import SQUARE
from server.app import create_app
from server.commands.models import CommandRecord as Command
from server.commands.schemas import CommandIn
from server.core.events import CommandChanged, PacketsSettled, TelemetryDecoded, VehicleReported
from server.core.security import Actor, Role
from server.map.panel import LEGEND, OperatorPanel
from server.map.scene import OperatorMap
from server.operators.schemas import OperatorIn
from server.screens.fleet import PALETTE, rgb
from server.vehicles.schemas import VehicleIn
from tests.support.api import OP, offline_settings
from tests.support.viser import fake_client, fake_server


@pytest.fixture
def shore_map(tmp_path: Path):
    settings = offline_settings(tmp_path, modem_log=str(tmp_path / "modem.log"))
    with TestClient(create_app(settings)) as client:
        client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2, "max_distance": 50}, headers=OP)
        shore = client.app.state.shore
        yield (
            shore,
            OperatorMap(
                shore.screens,
                shore.commands,
                shore.bus,
                settings.model_copy(update={"map_port": 0}),
                shore.operators.actor,
                shore.safety.paths,
                shore.teams.every,
            ),
        )


def client_post(shore: Any, body: dict) -> None:
    """Queue a command for rov1 through the command desk, as the API does."""
    shore.commands.submit(1, CommandIn(**body), "tester")


def panel_for(owner: OperatorMap) -> OperatorPanel:
    return OperatorPanel(owner, fake_client())


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
    panel.command_status(CommandChanged(sent.id, sent.seq, "executed"), "- #1 move")
    assert "**executed**" in panel.status_md.content and "executed" not in other.status_md.content
    panel.command_dd.value = "goto_depth"
    panel.command_dd.press()
    assert panel.inputs["depth"].label == "Target depth (m)" and not panel.inputs["distance"].visible
    panel.command_dd.value = "move"
    panel.command_dd.press()
    assert panel.inputs["depth"].label == "Depth change (m)"


def test_the_panel_sends_as_the_named_operator_until_revoked(shore_map: tuple) -> None:
    """An operator created through the API signs in on the map with the same rule as the API: its
    commands carry its name; revoked, the panel cannot send, and signing in again says why."""
    shore, owner = shore_map
    operator, token = shore.operators.create(
        OperatorIn(name="alice", role="write"), Actor("config-operator-1", Role.WRITE)
    )
    panel = panel_for(owner)
    assert panel.sign_in(token) == "write"
    panel.send(CommandIn(command="hold"))
    assert [c.issued_by for c in commands(shore)] == ["alice"]
    shore.operators.revoke(operator.id)
    panel.send(CommandIn(command="hold"))
    assert "sign in with an operator's token" in panel.status_md.content and len(commands(shore)) == 1
    assert panel.sign_in(token) is None and "revoked at" in panel.role_md.content


def test_a_blank_mission_number_is_refused_in_the_panel(shore_map: tuple) -> None:
    shore, owner = shore_map
    panel = panel_for(owner)
    assert panel.sign_in("operator-token") == "write"
    panel.inputs["param_id"].value = None  # a cleared number box, as a websocket client can send it
    panel.ask("start_mission")
    panel.confirm_btn.press()
    assert "not a mission number" in panel.status_md.content and commands(shore) == []


def decoded(packet_id: int, temperature: float) -> TelemetryDecoded:
    return TelemetryDecoded(
        packet_id=packet_id,
        vehicle="rov1",
        stream="env",
        channels=["temperature", "depth"],
        period=1.0,
        times=[0.0],
        values=[[temperature, 2.0]],
        lost=None,
    )


def test_the_temperature_estimate_is_fitted_on_verified_samples_only(shore_map: tuple) -> None:
    _, owner = shore_map
    owner.attach(fake_server())
    owner.handle(
        VehicleReported(
            vehicle="rov1",
            checkpoint={"north": 5.0, "east": 5.0, "depth": 2.0, "heading": 0.0, "state": "preprogrammed"},
        )
    )
    for packet_id, temperature in ((1, 20.0), (2, 40.0), (3, 21.0)):
        owner.handle(decoded(packet_id, temperature))
    nodes = owner.server.scene.nodes
    assert len(owner.field.samples()[0]) == 0 and len(nodes["/temperature/pending"].args[0]) == 3
    assert "/temperature/samples" not in nodes  # nothing coloured (nor fitted) before a check-point vouches
    # 1 verified and trusted; 2 forged; 3 verified but decoded on a state nobody vouched for
    owner.handle(PacketsSettled(vehicle="rov1", verified=[1, 3], forged=[2], trusted=[1]))
    verified, pending = owner.field.samples()
    assert list(verified[:, 3]) == [20.0] and len(pending) == 0
    assert "/temperature/pending" not in nodes and len(nodes["/temperature/samples"].args[0]) == 1
    panel = panel_for(owner)
    assert "verified samples" in panel.estimate_cb.label and "grey squares" in LEGEND


def segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    t = np.clip(np.dot(p - a, b - a) / max(float(np.dot(b - a, b - a)), 1e-9), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t * (b - a))))


def test_the_map_opens_top_down_with_its_labels_clear_of_the_track_and_each_other(shore_map: tuple) -> None:
    _, owner = shore_map
    owner.attach(fake_server())
    camera = owner.server.initial_camera
    eye = np.array(camera.position)
    down = np.array(camera.look_at) - eye
    assert np.degrees(np.arctan2(np.hypot(down[0], down[1]), -down[2])) < 3.0  # straight down, near enough

    def seen(p: tuple) -> np.ndarray:
        """Where the camera sees a point, on the water's surface (its perspective: deep points move in)."""
        return (eye + (np.array(p) - eye) * eye[2] / (eye[2] - p[2]))[:2]

    labels = {n: seen(h.position) for n, h in owner.server.scene.nodes.items() if h.method == "add_label"}
    track = [seen((w["east"], w["north"], -w["depth"])) for w in SQUARE["waypoints"]]  # the demo's plan
    for name in (n for n in labels if n.startswith("/axes/depth")):
        nearest = min(segment_distance(labels[name], a, b) for a, b in itertools.pairwise(track))
        assert nearest > 5.0, f"{name} lies {nearest:.1f} m from the planned track, seen from above"
    for (a, pa), (b, pb) in itertools.combinations(labels.items(), 2):
        assert np.linalg.norm(pa - pb) >= 3.0, f"{a} and {b} overlap seen from above"


def test_the_command_list_is_filled_from_the_start_with_parameters_and_times(shore_map: tuple) -> None:
    shore, owner = shore_map
    for body in (
        {"command": "move", "distance": 10, "angle": 45, "depth": 1, "speed": 0.5},
        {"command": "move", "distance": 6, "angle": 270, "absolute_angle": True},
        {"command": "hold"},
    ):
        client_post(shore, body)
    text = panel_for(owner).commands_md.content
    assert text.splitlines()[0].startswith("- #3 rov1 hold: **queued** ")
    assert re.search(
        r"#1 rov1 move 10 m, turn \+45°, 1 m deeper, 0.5 m/s: \*\*queued\*\* \d\d:\d\d:\d\dZ", text
    )
    assert "#2 rov1 move 6 m, bearing 270°" in text


def test_speed_is_sent_only_when_set(shore_map: tuple) -> None:
    shore, owner = shore_map
    panel = panel_for(owner)
    assert panel.sign_in("operator-token") == "write"
    assert not panel.speed_cb.value and panel.inputs["speed"].disabled  # blank means the cruise speed
    assert "speed" not in shore.screens.form(1)["defaults"]
    panel.send_btn.press()
    panel.speed_cb.value = True
    panel.speed_cb.press()
    assert not panel.inputs["speed"].disabled
    panel.inputs["speed"].value = 0.4
    panel.send_btn.press()
    assert [c.speed for c in commands(shore)] == [0.0, 0.4]  # 0 on the wire: nothing set, the cruise speed


def test_the_fleet_buttons_send_one_command_per_vehicle_once_confirmed(shore_map: tuple) -> None:
    shore, owner = shore_map
    shore.vehicles.create(VehicleIn(name="rov2", address=3, home=(0.0, 30.0)))
    watcher, panel = panel_for(owner), panel_for(owner)
    watcher.fleet_btns["abort_mission"].press()
    watcher.confirm_btn.press()  # not signed in: nothing leaves
    assert commands(shore) == []
    assert panel.sign_in("operator-token") == "write" and not panel.fleet_btns["hold"].disabled
    panel.fleet_btns["abort_mission"].press()
    assert panel.confirm_btn.visible and panel.confirm_btn.label == "Confirm: abort all"
    assert commands(shore) == []  # asked, not yet confirmed
    panel.confirm_btn.press()
    sent = commands(shore)
    assert sorted((c.vehicle_id, c.command) for c in sent) == [(1, "abort_mission"), (2, "abort_mission")]
    assert "**Abort all**: 2 commands queued" in panel.status_md.content
    assert re.search(r"#\d+ rov2 abort mission: \*\*queued\*\*", owner.command_list())


def test_each_vehicle_in_its_colour_and_greyed_while_overdue(shore_map: tuple) -> None:
    """The shore never hears either on its link (no modem here): rov1 (a check-point a minute) is awaited,
    rov2 (one a microsecond) overdue by the time the map lists them."""
    shore, owner = shore_map
    shore.vehicles.create(VehicleIn(name="rov2", address=3, home=(0.0, 30.0), report_interval=1e-6))
    owner.attach(fake_server())
    panel = panel_for(owner)
    owner.panels[1] = panel
    for name, east in (("rov1", 0.0), ("rov2", 30.0)):
        for north in (0.0, 4.0):
            cp = {"north": north, "east": east, "depth": 2.0, "heading": 0.0, "state": "holding"}
            owner.handle(VehicleReported(vehicle=name, checkpoint=cp))
    nodes = owner.server.scene.nodes
    assert nodes["/tracks/rov1/actual"].args[1] == rgb(PALETTE[0])
    assert nodes["/tracks/rov2/actual"].args[1] == rgb(PALETTE[1])  # the dashboard's colours: one palette
    owner.tick()
    assert "rov1" in panel.fleet_html.content and "rov2" in panel.fleet_html.content
    assert (
        panel.fleet_html.content.count("(overdue)") == 1
        and "rov2</b>: no report yet <b>(overdue)" in panel.fleet_html.content
    )
    assert "rov1</b>: waiting for its first report (due by " in panel.fleet_html.content


def test_each_browser_s_view_opens_on_the_whole_fleet_and_zooms_out_as_far(shore_map: tuple) -> None:
    """Vehicles not heard yet stand at their homes, 900 m apart: a browser's camera, once it reports its
    window, looks straight down on both, left of the panel, and may zoom out beyond them (its far plane
    further still)."""
    shore, owner = shore_map
    shore.vehicles.create(VehicleIn(name="rov2", address=3, home=(0.0, 600.0)))
    shore.vehicles.set_home(1, (0.0, -300.0))
    owner.attach(fake_server())
    panel = owner.panels[1] = panel_for(owner)
    owner.tick()
    camera = panel.client.camera
    assert camera.position is None  # the window's size not known yet: not moved
    camera.report(1400, 1000)
    eye, at = np.array(camera.position), np.array(camera.look_at)
    assert eye[0] == at[0] and abs(eye[1] - at[1]) < 0.02 * eye[2]  # from above, north up
    half_height = eye[2] * np.tan(camera.fov / 2)  # metres from the view's centre to its top edge
    free_right = at[0] + half_height * 1400 / 1000 - 340 * (2 * half_height / 1000)  # the panel's edge
    for east in (-300.0, 600.0):
        assert at[0] - half_height * 1400 / 1000 < east < free_right
    assert camera.far > camera.max_orbit_distance > 2 * eye[2]  # zooming out reaches beyond the fleet
    assert not panel.unfitted
    owner.server.initial_camera.position = None
    camera.report(1400, 1000)  # the browser moving its camera after: not fitted again
    assert tuple(camera.position) == tuple(eye)


def test_an_operator_cancels_a_queued_command_from_the_panel(shore_map: tuple) -> None:
    """The panel's Cancel takes back the command it sent last (the number is filled in), as the API's
    cancel does; the status says how many of the vehicle's commands wait against the cap."""
    shore, owner = shore_map
    panel = panel_for(owner)
    panel.withdraw_btn.press()  # not signed in: nothing cancelled
    assert "sign in with an operator's token" in panel.status_md.content
    panel.sign_in("operator-token")
    panel.send(CommandIn(command="hold"))
    assert "(1 / 20 of rov1's commands waiting for the link)" in panel.status_md.content
    [sent] = commands(shore)
    assert panel.cancel_in.value == sent.id
    panel.withdraw_btn.press()
    assert "**cancelled**, never sent" in panel.status_md.content
    assert [c.status for c in commands(shore)] == ["cancelled"]
    panel.withdraw_btn.press()
    assert "nothing left to cancel" in panel.status_md.content
