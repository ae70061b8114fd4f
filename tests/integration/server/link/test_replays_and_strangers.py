"""Hygiene (issue 21.7): replayed check-points, strangers' frames, owner-only files, sign-in throttling."""

from __future__ import annotations

import os
import stat
import time
from functools import partial
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine
from sqlmodel import Session, select

from launch.stack import Stack, StackConfig
from server.app import create_app
from server.core.config import Settings
from server.core.db import make_engine, migrate
from server.core.errors import TooMany
from server.core.events import Bus
from server.core.security import Actor, Role, Throttle, configured
from server.link.ingest import Ingest
from server.link.models import LinkEvent
from server.link.state import IncomingFrame
from server.shore import Shore
from server.telemetry.models import Frame, Packet
from server.vehicles.models import Vehicle
from tacit import auth
from tacit.link import SeenWindow
from tacit.modemlog import ModemLog
from tacit.packets import CheckpointPacket, MissionState
from tacit.streams import default_streams
from tests.support.api import OBSERVER, offline_settings
from vehicle_agent.mavlink_io import MavlinkLink

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


def test_wrong_tokens_from_one_address_are_throttled_and_others_still_sign_in(tmp_path: Path) -> None:
    settings = offline_settings(tmp_path)
    app = create_app(settings)
    other = TestClient(app, client=("10.0.0.2", 4000))  # the app's lifespan runs in the one below
    with TestClient(app, client=("10.0.0.9", 4000)) as guesser:
        for n in range(settings.sign_in_failures):
            assert (
                guesser.get("/api/v1/vehicles", headers={"Authorization": f"Bearer guess-{n}"}).status_code
                == 401
            )
        for token in ("guess-again", "operator-token"):  # refused whatever it is, the right one too
            throttled = guesser.get("/api/v1/vehicles", headers={"Authorization": f"Bearer {token}"})
            assert throttled.status_code == 429
            assert 1 <= int(throttled.headers["Retry-After"]) <= settings.sign_in_window
        assert (
            other.get("/api/v1/vehicles", headers={"Authorization": "Bearer observer-token"}).status_code
            == 200
        )
        assert (
            other.post(
                "/api/v1/vehicles",
                json={"name": "rov1", "address": 2},
                headers={"Authorization": "Bearer operator-token"},
            ).status_code
            == 201
        )


def test_the_throttle_forgets_failures_older_than_its_window() -> None:
    settings = Settings(write_tokens=["operator-token"], sign_in_failures=2, sign_in_window=60.0)
    now = [0.0]
    throttle = Throttle(settings, partial(configured, settings), clock=lambda: now[0])
    assert throttle.actor("wrong", "a") is None and throttle.actor("wrong", "a") is None
    with pytest.raises(TooMany):
        throttle.actor("operator-token", "a")
    operator = Actor("config-operator-1", Role.WRITE)
    assert throttle.actor("operator-token", "b") == operator
    now[0] = 60.5
    assert throttle.actor("operator-token", "a") == operator


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_the_demo_folder_its_logs_and_tlogs_are_owner_only(tmp_path: Path) -> None:
    old = os.umask(0o022)  # the usual umask: what is not created narrow is readable by everyone
    try:
        data = tmp_path / "demo"
        data.mkdir(mode=0o755)  # left by an older run
        stack = Stack(StackConfig(data))
        assert mode(data) == 0o700
        stack.spawn(["--help"], "serve.log").wait(timeout=60)
        assert mode(data / "serve.log") == 0o600 and "usage" in stack.log("serve.log")
        modem_log = ModemLog(tmp_path / "logs" / "shore-modem.log")
        modem_log.write(">", "$CCCFG,SRC,1")
        modem_log.close()
        assert mode(tmp_path / "logs") == 0o700 and mode(tmp_path / "logs" / "shore-modem.log") == 0o600
        tlog = MavlinkLink("udpin:127.0.0.1:0", tmp_path / "agent.tlog")
        tlog.stop()
        assert mode(tmp_path / "agent.tlog") == 0o600
    finally:
        os.umask(old)
