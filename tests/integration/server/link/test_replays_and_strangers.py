"""The link's memory of what it heard: a check-point replayed after the duplicate window forgot it is still
refused (by its MAC, also after a restart), and frames from unknown addresses are kept to the newest few."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine
from sqlmodel import Session, select

from server.app import create_app
from server.core.config import Settings
from server.core.db import make_engine, migrate
from server.core.events import Bus
from server.link.ingest import Ingest
from server.link.models import LinkEvent
from server.link.state import IncomingFrame
from server.shore import Shore
from server.telemetry.models import Frame, Packet
from server.vehicles.models import Vehicle
from tacit import auth
from tacit.link import SeenWindow
from tacit.packets import CheckpointPacket, MissionState
from tacit.streams import default_streams
from tests.support.api import OBSERVER, offline_settings

KEY = bytes(range(32))
ADDRESS = 2


@pytest.fixture
def db(tmp_path: Path) -> Engine:
    url = f"sqlite:///{tmp_path}/tacit.db"
    migrate(url)
    engine = make_engine(url)
    with Session(engine) as s:
        s.add(Vehicle(name="rov1", address=ADDRESS, key_hex=KEY.hex()))
        s.commit()
    return engine


def ingest_of(db: Engine) -> Ingest:
    ingest = Ingest(db, Bus(), default_streams(), Settings())
    ingest.load_vehicles()
    return ingest


def test_a_checkpoint_replayed_after_the_duplicate_window_forgot_it_is_refused(db: Engine) -> None:
    frame = auth.sign_checkpoint(
        CheckpointPacket(seq=0, time=int(time.time()), state=MissionState.PREPROGRAMMED), KEY, 1, ADDRESS, []
    )
    ingest = ingest_of(db)
    ingest.handle(IncomingFrame(ADDRESS, 1, frame))
    assert ingest.stats["verified"] == 1
    for replay in range(2):  # in the same run, and after a restart (the MACs are saved with the link state)
        ingest = ingest if replay == 0 else ingest_of(db)
        ingest.vehicles[ADDRESS].link.seen = SeenWindow()  # flushed by 64 newer packets, say
        ingest.handle(IncomingFrame(ADDRESS, 1, frame))
        assert ingest.stats["replayed"] == 1 and ingest.stats["verified"] == int(replay == 0)
    with Session(db) as s:
        assert [p.auth for p in s.exec(select(Packet).order_by(Packet.id))] == [
            "verified",
            "replayed",
            "replayed",
        ]


def test_frames_from_unknown_addresses_are_kept_to_the_newest_few(tmp_path: Path) -> None:
    settings = offline_settings(tmp_path, stranger_frames_kept=20)
    with TestClient(create_app(settings)) as client:
        shore: Shore = client.app.state.shore
        for n in range(settings.stranger_frames_kept + 10):
            shore.ingest.handle(IncomingFrame(99, 1, bytes([n]) * 32))
        with Session(shore.db) as s:
            kept = s.exec(select(Frame).order_by(Frame.id)).all()
            events = s.exec(select(LinkEvent).where(LinkEvent.kind == "unknown_vehicle")).all()
        assert [f.data[0] for f in kept] == list(range(10, 30))  # the newest
        assert len(events) == 20
        assert client.get("/api/v1/link", headers=OBSERVER).json()["strangers"] == {"kept": 20, "dropped": 10}
