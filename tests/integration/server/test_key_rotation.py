"""Key rotation, the shore half: SYNCs stay signed with the confirmed key while a rotation waits, with
a probe signed with the new key every ``probe_every``-th; a waiting rotation shows on the API and can be
cancelled."""

from __future__ import annotations

import asyncio
import itertools
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.core.config import Settings
from server.link.heartbeat import Heartbeat
from server.link.state import VehicleState
from server.link.store import LinkStore
from server.link.timing import Timing
from server.shore import Shore
from tacit import auth
from tacit import modem as mm
from tacit.packets import Command

OP = {"Authorization": "Bearer operator-token"}


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
        settings, LinkStore(shore.db), Timing(settings), shore.vehicles, lambda v: next(counter)
    )
    modem, vehicle = AckingModem(), VehicleState(1, "rov1", 2, None)  # type: ignore[arg-type]

    async def send() -> None:
        for _ in range(n):
            await heartbeat.sync(modem, vehicle)  # type: ignore[arg-type]

    asyncio.run(send())
    return modem.sent


@pytest.fixture
def client(tmp_path: Path):
    settings = Settings(
        database_url=f"sqlite:///{tmp_path}/tacit.db",
        modem_url="",
        map_enabled=False,
        write_tokens=["operator-token"],
        read_tokens=["observer-token"],
    )
    with TestClient(create_app(settings)) as client:
        yield client


def test_syncs_stay_signed_with_the_confirmed_key_and_every_third_probes_with_the_new(client) -> None:
    shore: Shore = client.app.state.shore
    old = bytes.fromhex(
        client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP).json()["key"]
    )
    new = bytes.fromhex(client.post("/api/v1/vehicles/1/key", json={}, headers=OP).json()["key"])
    frames = syncs(shore, 6)
    for number, frame in enumerate(frames, start=1):
        probe = number % 3 == 0  # probe_every's default
        packet = auth.verify(frame, new if probe else old, 2)
        assert packet.command is Command.SYNC and packet.key_epoch == (2 if probe else 1)
        with pytest.raises(auth.BadMac):
            auth.verify(frame, old if probe else new, 2)
    rotation = client.get("/api/v1/vehicles/1", headers=OP).json()["key_rotation"]
    assert rotation["pending_version"] == 2 and rotation["probes"] == 2 and rotation["since"] > 0


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
