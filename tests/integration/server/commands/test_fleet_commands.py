"""Commands for the whole fleet (abort all, return all home, hold all): one operator action, one command per
vehicle, each with its own seq and status; unknown vehicles are a 404 and bad bodies a 422, and neither
queues anything."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from tests.support.api import OBSERVER, OP, offline_settings


@pytest.fixture
def client(tmp_path: Path):
    settings = offline_settings(tmp_path)
    with TestClient(create_app(settings)) as c:
        for name, address in (("rov1", 2), ("rov2", 3), ("rov3", 4)):
            created = c.post("/api/v1/vehicles", json={"name": name, "address": address}, headers=OP)
            assert created.status_code == 201
        yield c


def _queued(client: TestClient) -> list[dict]:
    return [c for v in (1, 2, 3) for c in client.get(f"/api/v1/vehicles/{v}/commands", headers=OP).json()]


def test_abort_all_queues_one_command_per_vehicle_each_with_its_own_status(client: TestClient) -> None:
    sent = client.post("/api/v1/fleet/commands", json={"command": "abort_mission"}, headers=OP)
    assert sent.status_code == 202
    commands = sent.json()["commands"]
    assert [c["vehicle_id"] for c in commands] == [1, 2, 3]
    assert {c["command"] for c in commands} == {"abort_mission"}
    assert {c["status"] for c in commands} == {"queued"}
    assert len({c["id"] for c in commands}) == 3
    assert {c["issued_by"] for c in commands} == {"config-operator-1"}
    for c in commands:  # each followed on its own
        one = client.get(f"/api/v1/commands/{c['id']}", headers=OP).json()
        assert one["vehicle_id"] == c["vehicle_id"] and [h["status"] for h in one["history"]] == ["queued"]


def test_a_fleet_command_to_some_vehicles_reaches_only_them(client: TestClient) -> None:
    sent = client.post("/api/v1/fleet/commands", json={"command": "hold", "vehicle_ids": [3, 1]}, headers=OP)
    assert sent.status_code == 202
    assert [c["vehicle_id"] for c in sent.json()["commands"]] == [3, 1]
    assert client.get("/api/v1/vehicles/2/commands", headers=OP).json() == []


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"command": "move"}, "command"),  # not a fleet command: it needs a target per vehicle
        ({"command": "sync"}, "command"),
        ({"command": "hold", "vehicle_ids": []}, "vehicle_ids"),
        ({"command": "hold", "vehicle_ids": [0]}, "vehicle_ids.0"),
        ({"command": "hold", "vehicle_ids": [1, 1]}, "vehicle_ids"),
        ({"command": "hold", "distance": 5}, "distance"),
        ({}, "command"),
    ],
)
def test_a_bad_fleet_command_is_a_422_naming_the_field_and_queues_nothing(
    client: TestClient, body: dict, field: str
) -> None:
    refused = client.post("/api/v1/fleet/commands", json=body, headers=OP)
    assert refused.status_code == 422, refused.text
    assert refused.json()["field"] == field
    assert _queued(client) == []


def test_an_unknown_vehicle_is_a_404_and_queues_nothing_for_the_others(client: TestClient) -> None:
    refused = client.post(
        "/api/v1/fleet/commands", json={"command": "return_home", "vehicle_ids": [1, 9]}, headers=OP
    )
    assert refused.status_code == 404
    assert refused.json() == {"detail": "no vehicle 9", "field": "vehicle_id"}
    assert _queued(client) == []


def test_observers_cannot_send_to_the_fleet(client: TestClient) -> None:
    assert (
        client.post("/api/v1/fleet/commands", json={"command": "hold"}, headers=OBSERVER).status_code == 403
    )
    assert _queued(client) == []


def test_the_fleet_lists_every_vehicle_in_its_own_colour_with_the_one_origin(tmp_path: Path) -> None:
    settings = offline_settings(tmp_path, origin=(40.0, -74.0))
    with TestClient(create_app(settings)) as c:
        for name, address, east in (("rov1", 2, 0.0), ("rov2", 3, 15.0)):
            body = {"name": name, "address": address, "home": [0.0, east], "report_interval": 20.0}
            assert c.post("/api/v1/vehicles", json=body, headers=OP).status_code == 201
        screens = c.app.state.shore.screens
        moved = c.put("/api/v1/vehicles/2/home", json={"home": [0.0, 30.0]}, headers=OP)
        assert moved.status_code == 200 and moved.json()["home"] == [0.0, 30.0]
        assert c.put("/api/v1/vehicles/2/home", json={"home": [0.0, 1e6]}, headers=OP).status_code == 422
        assert c.put("/api/v1/vehicles/9/home", json={"home": [0.0, 1.0]}, headers=OP).status_code == 404
        fleet = c.get("/api/v1/fleet", headers=OP).json()
        due = fleet["vehicles"][0]["first_report_due"]
        late = screens.fleet(now=due + 1.0)["vehicles"][0]
    assert fleet["origin"] == {"lat": 40.0, "lon": -74.0}
    rov1, rov2 = fleet["vehicles"]
    assert (rov1["name"], rov2["name"]) == ("rov1", "rov2") and rov2["home"] == [0.0, 30.0]
    assert [rov1["colour"], rov2["colour"]] == fleet["palette"][:2] and rov1["colour"] != rov2["colour"]
    # never heard, its first report not due yet: starting, not greyed; due after its report interval
    assert rov1["awaited"] and not rov1["overdue"] and rov1["reported"] is None
    assert rov1["overdue_after_s"] == 20.0 and rov1["first_report_due"] > time.time()
    assert late["overdue"] and not late["awaited"] and late["first_report_due"] is None
    assert rov1["airtime_s"]["total"] == 0.0


def test_abort_all_overtakes_a_full_queue_and_what_was_not_sent_never_runs_after_it(
    client: TestClient,
) -> None:
    """No modem here: every command stays queued, as behind a busy channel."""
    for _ in range(20):  # Settings.max_queued_commands: the queue is full
        assert (
            client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=OP).status_code
            == 202
        )
    assert client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=OP).status_code == 429
    abort = client.post("/api/v1/fleet/commands", json={"command": "abort_mission"}, headers=OP)
    assert abort.status_code == 202
    rov1 = client.get("/api/v1/vehicles/1/commands?history=true", headers=OP).json()
    assert rov1[0]["command"] == "abort_mission" and rov1[0]["status"] == "queued"
    assert {c["status"] for c in rov1[1:]} == {"superseded"} and len(rov1) == 21
    assert rov1[1]["history"][-1]["detail"] == "by an abort before it was sent"
