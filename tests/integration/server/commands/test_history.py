"""A command's full history through the API: the time of each state, each attempt, the vehicle's reason,
and, for what the vehicle reported, the check-point's time and pose (where and when)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.commands.models import CommandRecord as Command
from server.commands.models import CommandState as Status
from server.commands.service import MODEM, advance
from server.core.config import Settings
from server.link.state import IncomingFrame
from server.shore import Shore
from tacit import auth
from tacit.packets import CheckpointPacket, CommandStatus, MissionState, Reason

OP = {"Authorization": "Bearer operator-token"}
OBS = {"Authorization": "Bearer observer-token"}


KEY = "7e" * 32


@pytest.fixture
def client(tmp_path: Path, database_url: str):
    settings = Settings(
        database_url=database_url,
        modem_url="",
        map_enabled=False,
        write_tokens=["operator-token"],
        read_tokens=["observer-token"],
        ping_interval=3600,
    )
    with TestClient(create_app(settings)) as c:
        assert (
            c.post(
                "/api/v1/vehicles", json={"name": "rov1", "address": 2, "key": KEY}, headers=OP
            ).status_code
            == 201
        )
        yield c


def shore(client: TestClient) -> Shore:
    return client.app.state.shore  # type: ignore[attr-defined]


def attempt(client: TestClient, command_id: int, status: Status, detail: str = "", **extra: object) -> None:
    """What the link engine does on a transmission or an ACK."""
    from server.core.db import writing

    with writing(shore(client).db) as s:
        assert advance(s, s.get(Command, command_id), status, detail, origin=MODEM, **extra)  # type: ignore[arg-type]
        s.commit()


def checkpoint(
    client: TestClient, seq: int, status: CommandStatus, reason: Reason = Reason.OK, **pose: float
) -> int:
    """A check-point from the vehicle, through the shore's ingest as the modem would deliver it."""
    stamp = int(time.time()) - 3
    packet = CheckpointPacket(
        seq=seq,
        time=stamp,
        state=MissionState.COMMANDED,
        last_command=seq,
        command_status=status,
        reason=reason,
        **pose,
    )
    frame = auth.sign_checkpoint(
        packet, bytes.fromhex(KEY), 1, 2, []
    )  # signed by the vehicle (key version 1)
    shore(client).ingest.handle(IncomingFrame(src=2, dest=1, data=frame))
    return stamp


def test_history_has_every_step_attempt_reason_and_where_and_when(client: TestClient) -> None:
    move = client.post(
        "/api/v1/vehicles/1/commands", json={"command": "move", "distance": 10, "angle": 45}, headers=OP
    ).json()
    attempt(client, move["id"], Status.SENT, "attempt 1", attempts=1)
    attempt(client, move["id"], Status.SENT, "attempt 2", attempts=2)
    attempt(client, move["id"], Status.ACKNOWLEDGED)
    checkpoint(client, move["seq"], CommandStatus.EXECUTING, north=0.0, east=0.0, depth=1.0, heading=10.0)
    stamp = checkpoint(
        client, move["seq"], CommandStatus.EXECUTED, north=7.1, east=7.0, depth=1.0, heading=45.0
    )

    detail = client.get(f"/api/v1/commands/{move['id']}", headers=OBS).json()
    assert detail["status"] == "executed" and detail["attempts"] == 2
    steps = detail["history"]
    assert [e["status"] for e in steps] == ["queued", "sent", "sent", "acknowledged", "executing", "executed"]
    assert [e["detail"] for e in steps[1:3]] == ["attempt 1", "attempt 2"]
    assert all(a["at"] <= b["at"] for a, b in zip(steps, steps[1:], strict=False))
    assert all(e["report"] is None for e in steps[:4])  # the shore's own steps
    executed = dict(steps[-1]["report"])
    # on the shore's clock: never before the command left, never after the shore heard it
    assert steps[2]["at"] <= executed.pop("shore_time") <= steps[-1]["at"]
    assert executed == {
        "time": stamp,
        "state": "commanded",
        "north": 7.1,
        "east": 7.0,
        "depth": 1.0,
        "heading": 45.0,
    }

    deep = client.post(
        "/api/v1/vehicles/1/commands", json={"command": "goto_depth", "depth": 90}, headers=OP
    ).json()
    checkpoint(client, deep["seq"], CommandStatus.REFUSED, Reason.OUT_OF_LIMITS, depth=1.0)
    refused = client.get(f"/api/v1/commands/{deep['id']}", headers=OBS).json()
    assert refused["status"] == "refused" and refused["reason"] == "out_of_limits"
    assert (
        refused["history"][-1]["detail"] == "out_of_limits"
        and refused["history"][-1]["report"]["depth"] == 1.0
    )

    listed = client.get("/api/v1/vehicles/1/commands", headers=OBS).json()
    assert [c["id"] for c in listed] == [deep["id"], move["id"]] and all(c["history"] is None for c in listed)
    listed = client.get("/api/v1/vehicles/1/commands?history=true", headers=OBS).json()
    assert listed[1]["history"] == steps and listed[0]["history"] == refused["history"]

    schema = client.get("/openapi.json").json()["components"]["schemas"]
    assert "vehicle time" in schema["CommandReport"]["properties"]["time"]["description"]


def test_a_move_abandoned_for_a_newer_one_is_superseded(client: TestClient) -> None:
    """The vehicle reports only its latest command: when it takes on a new course, the older move that was
    still executing will never be reported executed; the shore marks it superseded, naming the newer."""
    post = lambda body: client.post("/api/v1/vehicles/1/commands", json=body, headers=OP).json()  # noqa: E731
    first, probe = post({"command": "move", "distance": 10}), post({"command": "request_checkpoint"})
    checkpoint(client, first["seq"], CommandStatus.EXECUTING)
    checkpoint(client, probe["seq"], CommandStatus.EXECUTED)  # no new course: the move goes on
    assert client.get(f"/api/v1/commands/{first['id']}", headers=OBS).json()["status"] == "executing"
    second = post({"command": "goto_depth", "depth": 2})
    checkpoint(client, second["seq"], CommandStatus.EXECUTING)
    detail = client.get(f"/api/v1/commands/{first['id']}", headers=OBS).json()
    assert (
        detail["status"] == "superseded"
        and detail["history"][-1]["detail"] == f"by command {second['seq']} (goto_depth)"
    )
    checkpoint(
        client, first["seq"], CommandStatus.EXECUTED
    )  # a late copy of an old check-point changes nothing
    assert client.get(f"/api/v1/commands/{first['id']}", headers=OBS).json()["status"] == "superseded"


def test_a_shore_behind_the_vehicle_issues_after_what_the_vehicle_accepted(client: TestClient) -> None:
    """The shore's database restored from an older backup (here: new) while the vehicle accepted commands
    up to seq 41: its verified check-point says so, and the next command takes seq 42, where seq 1 would
    have been refused by the vehicle as a replay."""
    checkpoint(client, 41, CommandStatus.EXECUTED, north=0.0, east=0.0, depth=1.0)
    command = client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=OP).json()
    assert command["seq"] == 42
    checkpoint(client, 42, CommandStatus.EXECUTED, north=0.0, east=0.0, depth=1.0)
    assert client.get(f"/api/v1/commands/{command['id']}", headers=OBS).json()["status"] == "executed"
