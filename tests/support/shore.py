"""A shore in one process on a database file, its link engine driven slot by slot by a scripted modem (the
tests of the MAC): simulated time runs 1000x and no SYNC falls due unless a test asks."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from sqlalchemy import Engine
from sqlmodel import SQLModel

from server.core.config import Settings
from server.core.db import make_engine, migrate, writing
from server.link.state import IncomingFrame
from server.shore import Shore
from server.vehicles.models import Vehicle
from tacit import auth
from tacit import modem as mm
from tacit.packets import CheckpointPacket, MissionState
from tests.support.sqlite import migrated


def store_with(tmp_path: Path, *rows: SQLModel) -> Engine:
    """A migrated SQLite store of the test's own (``tacit.db``), holding ``rows`` (a vehicle first)."""
    db = make_engine(migrated(tmp_path / "tacit.db"))
    with writing(db) as s:
        for row in rows:
            s.add(row)
            s.flush()
        s.commit()
    return db


def scripted_shore(tmp_path: Path, keys: list[str], **overrides: Any) -> Shore:
    """The shore with one vehicle per key (``rov1`` at modem address 2, ``rov2`` at 3, ...), loaded, each
    heard: a synced check-point of each has come (the shore commands no vehicle before it heard it)."""
    defaults: dict[str, Any] = {
        "database_url": migrated(tmp_path / "tacit.db"),
        "modem_url": "",
        "time_scale": 1000.0,
        "sync_interval": 1e6,
    }
    settings = Settings(**{**defaults, **overrides})
    migrate(settings.database_url)  # current unless overridden
    db = make_engine(settings.database_url)
    with writing(db) as s:
        for i, key in enumerate(keys):
            s.add(Vehicle(name=f"rov{i + 1}", address=2 + i, key_hex=key))
        s.commit()
    shore = Shore.build(settings, db)
    shore.ingest.load_vehicles()
    for i, key in enumerate(keys):
        packet = CheckpointPacket(seq=1, time=int(time.time()), state=MissionState.WAITING)
        frame = auth.sign_checkpoint(packet, bytes.fromhex(key), 1, 2 + i, [])
        shore.ingest.handle(IncomingFrame(src=2 + i, dest=settings.modem_address, data=frame))
    return shore


class AckingModem:
    """A shore modem whose every transmission is acknowledged at once; it counts what it was asked."""

    state = mm.LinkState.READY

    def __init__(self) -> None:
        self.sent: list[bytes] = []
        self.polls = 0

    async def send(self, dest: int, frames: list[bytes], **_: object) -> mm.TransmitResult:
        self.sent += frames
        return mm.TransmitResult(dest, len(frames), True, frozenset(range(len(frames))))

    async def poll(self, dest: int, **_: object) -> None:
        self.polls += 1

    async def ping(self, dest: int, **_: object) -> None:
        return None  # no range measured
