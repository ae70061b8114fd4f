"""The real app against simulated Micro-Modems on ptys: commands cross the channel, packets are stored,
a vanished shore modem loses nothing; bad requests get the right 4xx and change nothing."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from launch.stack import wait_for
from launch.vehicle_host import VehicleSide
from server.app import create_app
from server.core.config import Settings
from tacit.packets import CheckpointPacket, CommandStatus, MissionState
from tests.conftest import tacit_process

OP = {"Authorization": "Bearer operator-token"}
OBS = {"Authorization": "Bearer observer-token"}
SCALE = 8.0


def sim_config(tmp_path: Path) -> Path:
    config = {
        "seed": 2,
        "time_scale": SCALE,
        "channel": {"noise_level_db": 95.0},
        "modems": [
            {"address": 1, "name": "shore", "position": [0, 0, 1], "link": str(tmp_path / "shore")},
            {"address": 2, "name": "vehicle", "position": [300, 0, 5], "link": str(tmp_path / "vehicle")},
        ],
    }
    path = tmp_path / "sim.json"
    path.write_text(json.dumps(config))
    return path


def app_settings(tmp_path: Path, modem_url: str = "", database_url: str | None = None) -> Settings:
    return Settings(
        database_url=database_url or f"sqlite:///{tmp_path}/tacit.db",
        modem_url=modem_url,
        map_enabled=False,
        modem_log=str(tmp_path / "shore-modem.log"),
        write_tokens=["operator-token"],
        read_tokens=["observer-token"],
        time_scale=SCALE,
        poll_interval=2.0,
        default_range=300.0,
        ping_interval=3600,
    )


def status_of(client: TestClient, command_id: int) -> str:
    return client.get(f"/api/v1/commands/{command_id}", headers=OBS).json()["status"]


def heard(client: TestClient, vehicle: VehicleSide, seq: int) -> None:
    """The vehicle's first check-point (synced) reaches the shore: commands may go to it from now."""
    vehicle.send(vehicle.signed(CheckpointPacket(seq=seq, time=int(time.time()), state=MissionState.WAITING)))
    wait_for(lambda: client.get("/api/v1/link", headers=OBS).json()["vehicles"]["rov1"]["checkpoint"])


def test_command_crosses_the_channel_and_a_priority_packet_is_stored(
    tmp_path: Path, database_url: str
) -> None:
    with tacit_process("sim", "--config", str(sim_config(tmp_path))) as (_, _info):
        with TestClient(create_app(app_settings(tmp_path, str(tmp_path / "shore"), database_url))) as client:
            created = client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP).json()
            vehicle = VehicleSide(str(tmp_path / "vehicle"), 2, bytes.fromhex(created["key"]))
            try:
                heard(client, vehicle, 1)
                command = client.post(
                    f"/api/v1/vehicles/{created['id']}/commands",
                    json={"command": "move", "distance": 12.5, "angle": -30, "depth": 1.5},
                    headers=OP,
                ).json()
                wait_for(lambda: status_of(client, command["id"]) == "acknowledged")
                assert [(c.seq, c.distance, c.angle, c.depth) for c in vehicle.controls] == [
                    (1, 12.5, -30.0, 1.5)
                ]
                history = [
                    e["status"]
                    for e in client.get(f"/api/v1/commands/{command['id']}", headers=OBS).json()["history"]
                ]
                assert history[0] == "queued" and "sent" in history and history[-1] == "acknowledged"

                report = CheckpointPacket(
                    seq=2,
                    time=int(time.time()),
                    state=MissionState.COMMANDED,
                    depth=6.5,
                    last_command=1,
                    command_status=CommandStatus.EXECUTED,
                )
                vehicle.send(vehicle.signed(report))
                wait_for(lambda: client.get("/api/v1/packets", headers=OBS).json()["total"] >= 2)
                listed = client.get("/api/v1/packets?type=checkpoint", headers=OBS).json()["items"]
                assert any(p["body"]["depth"] == 6.5 and p["seq"] == 2 for p in listed)
                wait_for(lambda: status_of(client, command["id"]) == "executed")
                # the shore modem's ACKs of both check-points' frames reached the vehicle
                wait_for(lambda: vehicle.results == [True, True])
                link = client.get("/api/v1/link", headers=OBS).json()
                assert link["modem"] == "ready" and link["vehicles"]["rov1"]["snr_in"] is not None
            finally:
                vehicle.close()


def test_stopping_the_shore_modem_loses_nothing(tmp_path: Path, database_url: str) -> None:
    config = sim_config(tmp_path)
    with TestClient(create_app(app_settings(tmp_path, str(tmp_path / "shore"), database_url))) as client:
        with tacit_process("sim", "--config", str(config)):
            created = client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP).json()
            key = bytes.fromhex(created["key"])
            vehicle = VehicleSide(str(tmp_path / "vehicle"), 2, key)
            heard(client, vehicle, 4)
            first = client.post(
                f"/api/v1/vehicles/{created['id']}/commands", json={"command": "hold"}, headers=OP
            ).json()
            wait_for(lambda: status_of(client, first["id"]) == "acknowledged")
            vehicle.send(
                vehicle.signed(CheckpointPacket(seq=5, time=int(time.time()), state=MissionState.HOLDING))
            )
            wait_for(lambda: client.get("/api/v1/packets", headers=OBS).json()["total"] == 2)
        # the simulator (both modems) is gone: the server keeps serving and queues
        wait_for(lambda: client.get("/api/v1/link", headers=OBS).json()["modem"] != "ready", timeout=30)
        second = client.post(
            f"/api/v1/vehicles/{created['id']}/commands",
            json={"command": "goto_depth", "depth": 3},
            headers=OP,
        ).json()
        assert status_of(client, second["id"]) in ("queued", "sent")
        assert client.get("/api/v1/packets", headers=OBS).json()["total"] == 2
        with tacit_process("sim", "--config", str(config)):
            wait_for(lambda: client.get("/api/v1/link", headers=OBS).json()["modem"] == "ready", timeout=30)
            wait_for(lambda: status_of(client, second["id"]) in ("acknowledged",), timeout=90)
            assert [c.seq for c in vehicle.controls] == [1, 2]  # each command exactly once
        vehicle.close()
    with TestClient(
        create_app(app_settings(tmp_path, database_url=database_url))
    ) as client:  # a restart keeps all
        assert client.get("/api/v1/packets", headers=OBS).json()["total"] == 2
        assert [c["status"] for c in client.get("/api/v1/vehicles/1/commands", headers=OBS).json()] == [
            "acknowledged",
            "acknowledged",
        ]


@pytest.fixture
def client(tmp_path: Path, database_url: str):
    with TestClient(create_app(app_settings(tmp_path, database_url=database_url))) as c:
        c.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP)
        yield c


@pytest.mark.parametrize(
    "request_kwargs, status, field",
    [
        ({"content": b"{not json", "headers": {**OP, "Content-Type": "application/json"}}, 422, "body"),
        ({"json": {"command": "move", "angle": 181}, "headers": OP}, 422, "angle"),
        ({"json": {"command": "move", "distance": -1}, "headers": OP}, 422, "distance"),
        ({"json": {"command": "move", "distance": 600}, "headers": OP}, 422, "distance"),
        ({"json": {"command": "goto_depth", "depth": 150}, "headers": OP}, 422, "depth"),
        ({"json": {"command": "fly"}, "headers": OP}, 422, "command"),
        ({"json": {"command": "hold", "extra": 1}, "headers": OP}, 422, "extra"),
        ({"json": {"command": "hold"}}, 401, None),
        ({"json": {"command": "hold"}, "headers": {"Authorization": "Bearer wrong"}}, 401, None),
        ({"json": {"command": "hold"}, "headers": OBS}, 403, None),
    ],
)
def test_bad_command_requests_are_refused_and_change_nothing(
    client: TestClient, request_kwargs: dict, status: int, field: str | None
) -> None:
    response = client.post("/api/v1/vehicles/1/commands", **request_kwargs)
    assert response.status_code == status
    assert response.json()["field"] == field
    assert client.get("/api/v1/vehicles/1/commands", headers=OBS).json() == []


def test_unknown_vehicle_duplicates_and_reads(client: TestClient) -> None:
    assert client.post("/api/v1/vehicles/9/commands", json={"command": "hold"}, headers=OP).status_code == 404
    again = client.post("/api/v1/vehicles", json={"name": "rov2", "address": 2}, headers=OP)
    assert again.status_code == 409 and again.json()["field"] == "address"
    assert (
        client.post("/api/v1/vehicles", json={"name": "x", "address": 200}, headers=OP).json()["field"]
        == "address"
    )
    assert client.get("/api/v1/vehicles", headers=OBS).status_code == 200
    assert client.get("/api/v1/vehicles").status_code == 401
    assert len(client.get("/api/v1/vehicles", headers=OBS).json()) == 1


def test_key_rotation(client: TestClient) -> None:
    before = client.get("/api/v1/vehicles/1", headers=OBS).json()
    rotated = client.post("/api/v1/vehicles/1/key", json={}, headers=OP).json()
    assert rotated["key_version"] == before["key_version"] + 1 and len(rotated["key"]) == 64
    assert "key" not in client.get("/api/v1/vehicles/1", headers=OBS).json()
    assert client.post("/api/v1/vehicles/1/key", json={"key": "00"}, headers=OP).json()["field"] == "key"
    assert client.post("/api/v1/vehicles/1/key", json={}, headers=OBS).status_code == 403
    same = client.post("/api/v1/vehicles/1/key", json={"key": rotated["key"]}, headers=OP).json()
    assert same["key_version"] == rotated["key_version"]  # the key it has: nothing new (a demo re-run)
    waiting = client.post("/api/v1/vehicles/1/key", json={}, headers=OP)  # the vehicle has not confirmed yet
    assert waiting.status_code == 409 and waiting.json()["field"] == "key"


def test_missions_queue_start_and_abort(client: TestClient) -> None:
    square = {
        "name": "square",
        "number": 1,
        "waypoints": [{"north": 0, "east": 0, "depth": 2}, {"north": 10, "east": 0, "depth": 2}],
    }
    mission = client.post("/api/v1/vehicles/1/missions", json=square, headers=OP).json()
    start = client.post(f"/api/v1/missions/{mission['id']}/start", headers=OP).json()
    abort = client.post(f"/api/v1/missions/{mission['id']}/abort", headers=OP).json()
    assert (start["command"], start["param_id"], abort["command"]) == ("start_mission", 1, "abort_mission")
    assert client.get("/api/v1/vehicles/1/missions", headers=OBS).json()[0]["status"] == "aborted"
    assert client.post("/api/v1/missions/77/start", headers=OP).status_code == 404
