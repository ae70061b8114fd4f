"""Cancelling a queued command (``CommandDesk.cancel``, ``POST /api/v1/commands/{id}/cancel``): it ends
``cancelled`` with who and when and is never signed for transmission; a cancel that loses the race with
a transmission is a 409 saying so; the queue's cap is explained in the 429 and shown. On a shore with no
modem of its own (nothing is sent while the test looks), and through gateways on a real broker."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from tests.integration.server.test_gateway_claims import MuteModem, running
from tests.integration.server.test_routing import until
from tests.support.api import OP, offline_settings
from tests.support.nats import Secured

READ = {"Authorization": "Bearer observer-token"}


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    with TestClient(create_app(offline_settings(tmp_path))) as client:
        answer = client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP)
        assert answer.status_code == 201, answer.text
        yield client


def hold(client: TestClient) -> dict[str, Any]:
    answer = client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=OP)
    assert answer.status_code == 202, answer.text
    return dict(answer.json())


def test_a_queued_command_is_cancelled_by_whom_and_when_and_never_signed(client: TestClient) -> None:
    command = hold(client)
    assert client.post(f"/api/v1/commands/{command['id']}/cancel", headers=READ).status_code == 403
    assert client.post("/api/v1/commands/99/cancel", headers=OP).status_code == 404
    answer = client.post(f"/api/v1/commands/{command['id']}/cancel", headers=OP)
    assert answer.status_code == 200, answer.text
    assert answer.json()["status"] == "cancelled"
    step = answer.json()["history"][-1]
    assert (step["status"], step["source"], step["via"], step["detail"]) == (
        "cancelled", "operator", "config-operator-1", "by config-operator-1",
    )  # fmt: skip
    assert step["at"] >= answer.json()["history"][0]["at"]
    desk = client.app.state.shore.commands  # type: ignore[attr-defined]
    record, _ = desk.get(command["id"])
    assert desk.frame(record) is None  # the link's attempt finds it cancelled: never on the air
    assert desk.get(command["id"])[0].frame == b""
    assert desk.next_to_send(1, 0.0) is None
    again = client.post(f"/api/v1/commands/{command['id']}/cancel", headers=OP)
    assert again.status_code == 409 and "cancelled: nothing left to cancel" in again.json()["detail"]


def test_a_cancel_that_loses_the_race_with_a_transmission_says_so(client: TestClient) -> None:
    command = hold(client)
    desk = client.app.state.shore.commands  # type: ignore[attr-defined]
    record, _ = desk.get(command["id"])
    assert desk.frame(record)  # the link signed it for an attempt: from here it goes
    answer = client.post(f"/api/v1/commands/{command['id']}/cancel", headers=OP)
    assert answer.status_code == 409
    assert answer.json()["detail"].endswith("too late to cancel, it goes on as sent")
    assert answer.json()["field"] == "command_id"
    assert client.get(f"/api/v1/commands/{command['id']}", headers=OP).json()["status"] == "queued"


def test_the_queue_cap_is_explained_and_shown(client: TestClient) -> None:
    queued = [hold(client) for _ in range(20)]
    fleet = client.get("/api/v1/fleet", headers=OP).json()["vehicles"][0]
    assert (fleet["queued"], fleet["queue_cap"]) == (20, 20)
    full = client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=OP)
    assert full.status_code == 429 and full.headers["Retry-After"]
    assert "its queue's cap (20" in full.json()["detail"] and "cancel queued ones" in full.json()["detail"]
    assert client.post(f"/api/v1/commands/{queued[-1]['id']}/cancel", headers=OP).status_code == 200
    assert client.get("/api/v1/fleet", headers=OP).json()["vehicles"][0]["queued"] == 19
    hold(client)  # room again


def test_through_gateways_a_command_not_yet_dispatched_is_cancelled_and_never_dispatched(
    secured: Secured, tmp_path: Path, sqlite_url: str
) -> None:
    """The first command is handed to the ship (signed, published): too late to cancel. The second waits
    behind it at the center: cancelled, it is never dispatched; the third, after it, is."""
    with running(secured, tmp_path, sqlite_url, ship=MuteModem, gateway_faulty_slots=1000) as shore:
        vehicle_id = shore.register()
        shore.heard({"ship": 20.0, "buoy": 12.0})
        until(lambda: shore.route(vehicle_id)["gateway"] == "ship", what="the ship to take the vehicle")
        routing = shore.client.app.state.shore.routing  # type: ignore[attr-defined]
        first = shore.command(vehicle_id)
        until(lambda: [d.state for d in routing.dispatches(first)] == ["stored"], what="the ship's receipt")
        second = shore.command(vehicle_id)
        late = shore.client.post(f"/api/v1/commands/{first}/cancel", headers=OP)
        assert late.status_code == 409 and "it goes on as sent" in late.json()["detail"]
        assert shore.client.post(f"/api/v1/commands/{second}/cancel", headers=OP).status_code == 200

        dispatch = routing.dispatches(first)[0].id
        shore.outboxes["ship"].add_event("attempt", {"command": dispatch, "outcome": "sent", "attempt": 1})
        shore.outboxes["ship"].add_event("attempt", {"command": dispatch, "outcome": "acked", "final": True})
        until(lambda: shore.detail(first)["status"] == "acknowledged", what="the first command's ACK")
        third = shore.command(vehicle_id)
        until(lambda: routing.dispatches(third), what="the third command dispatched")
        assert routing.dispatches(second) == []
        assert shore.detail(second)["status"] == "cancelled"
