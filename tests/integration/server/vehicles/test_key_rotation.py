"""Key rotation, the shore half: SYNCs and commands stay signed with the confirmed key while a rotation
waits, until a check-point says the vehicle holds the new key; a waiting rotation shows on the API and
can be cancelled."""

from __future__ import annotations

import asyncio
import itertools
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.link.heartbeat import Heartbeat
from server.link.state import IncomingFrame, VehicleState
from server.link.store import LinkStore
from server.link.timing import Timing
from server.shore import Shore
from tacit import auth
from tacit import modem as mm
from tacit.packets import CheckpointPacket, MissionState
from tests.support.api import OP, offline_settings

STAMPS = itertools.count()


class AckingModem:
    state = mm.LinkState.READY

    def __init__(self) -> None:
        self.sent: list[bytes] = []

    async def send(self, dest: int, frames: list[bytes], **_: object) -> mm.TransmitResult:
        self.sent += frames
        return mm.TransmitResult(dest, len(frames), True, frozenset(range(len(frames))))


def syncs(shore: Shore, n: int) -> list[bytes]:
    """``n`` SYNCs to vehicle 1 as the link's heartbeat sends them; their frames."""
    settings = shore.settings
    counter = itertools.count(1)
    heartbeat = Heartbeat(
        settings, LinkStore(shore.db), Timing(settings), shore.vehicles, lambda v, floor: next(counter)
    )
    modem, vehicle = AckingModem(), VehicleState(1, "rov1", 2, None)  # type: ignore[arg-type]

    async def send() -> None:
        for _ in range(n):
            await heartbeat.sync(modem, vehicle)  # type: ignore[arg-type]

    asyncio.run(send())
    return modem.sent


@pytest.fixture
def client(tmp_path: Path):
    settings = offline_settings(tmp_path)
    with TestClient(create_app(settings)) as client:
        yield client


def checkpoint(shore: Shore, key: bytes, version: int, holds_next_key: bool) -> None:
    """A check-point from vehicle 1, signed with ``key``, through the shore's ingest."""
    stamp = int(time.time()) + next(STAMPS)  # each above the last: none is a replay
    packet = CheckpointPacket(
        seq=stamp % 256, time=stamp, state=MissionState.WAITING, holds_next_key=holds_next_key
    )
    shore.ingest.handle(IncomingFrame(2, 1, auth.sign_checkpoint(packet, key, version, 2, [])))


def signed_with(shore: Shore, client: TestClient, key: bytes, version: int) -> bool:
    """Whether the next SYNCs and a command's frame are all signed with ``key`` (and name ``version``)."""
    client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=OP).raise_for_status()
    command = shore.commands.next_to_send(1, time.time())
    assert command is not None
    frames = [*syncs(shore, 4), shore.commands.frame(command)]
    try:
        return all(auth.verify(frame, key, 2).key_epoch == version for frame in frames)
    except auth.BadMac:
        return False


def test_the_new_key_is_used_once_a_checkpoint_says_the_vehicle_holds_it_and_never_before(client) -> None:
    shore: Shore = client.app.state.shore
    old = bytes.fromhex(
        client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP).json()["key"]
    )
    shore.ingest.load_vehicles()
    new = bytes.fromhex(client.post("/api/v1/vehicles/1/key", json={}, headers=OP).json()["key"])
    rotation = lambda: client.get("/api/v1/vehicles/1", headers=OP).json()["key_rotation"]  # noqa: E731
    checkpoint(shore, old, 1, holds_next_key=False)
    assert signed_with(shore, client, old, 1) and not signed_with(shore, client, new, 2)
    assert rotation()["pending_version"] == 2 and rotation()["held"] is False and rotation()["since"] > 0
    checkpoint(shore, old, 1, holds_next_key=True)  # the vehicle has it as its next_key
    assert rotation()["held"] is True and signed_with(shore, client, new, 2)
    checkpoint(shore, old, 1, holds_next_key=False)  # restarted without it: back to the confirmed key
    assert rotation()["held"] is False and signed_with(shore, client, old, 1)
    checkpoint(shore, old, 1, holds_next_key=True)
    checkpoint(shore, new, 2, holds_next_key=False)  # it switched: confirmed, the rotation is over
    assert rotation() is None and signed_with(shore, client, new, 2)


def test_a_waiting_rotation_can_be_cancelled(client) -> None:
    created = client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP).json()
    assert created["key_rotation"] is None
    assert client.delete("/api/v1/vehicles/1/key/pending", headers=OP).status_code == 409  # nothing waits
    client.post("/api/v1/vehicles/1/key", json={}, headers=OP)
    assert (
        client.delete(
            "/api/v1/vehicles/1/key/pending", headers={"Authorization": "Bearer observer-token"}
        ).status_code
        == 403
    )
    cancelled = client.delete("/api/v1/vehicles/1/key/pending", headers=OP)
    assert cancelled.status_code == 200
    assert cancelled.json()["key_version"] == 1 and cancelled.json()["key_rotation"] is None
    assert auth.verify(syncs(client.app.state.shore, 1)[0], bytes.fromhex(created["key"]), 2).key_epoch == 1
    again = client.post("/api/v1/vehicles/1/key", json={}, headers=OP)  # a new rotation may be staged now
    assert again.status_code == 200 and again.json()["key_version"] == 2
