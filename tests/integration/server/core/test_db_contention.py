"""The database under contention: a write lock held elsewhere never stalls the modem or loses a frame,
and parallel writers through the API are serialised, never answered with a 500."""

from __future__ import annotations

import sqlite3
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from fastapi.testclient import TestClient

from launch.stack import wait_for
from launch.vehicle_host import VehicleSide
from server.app import create_app
from tacit.packets import CheckpointPacket, MissionState
from tests.conftest import tacit_process
from tests.integration.server.test_app import OBS, OP, app_settings, sim_config

HOLD_S = 8.0  # longer than the busy timeout of any one write


def polls(client: TestClient) -> int:
    return client.get("/api/v1/link", headers=OBS).json()["counters"]["polls"]


def test_a_held_write_lock_neither_stalls_the_modem_nor_loses_a_frame(tmp_path: Path) -> None:
    with tacit_process("sim", "--config", str(sim_config(tmp_path))):
        with TestClient(create_app(app_settings(tmp_path, str(tmp_path / "shore")))) as client:
            created = client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP).json()
            vehicle = VehicleSide(str(tmp_path / "vehicle"), 2, bytes.fromhex(created["key"]))
            try:
                wait_for(lambda: polls(client) >= 1, what="the first poll")
                lock = sqlite3.connect(tmp_path / "tacit.db", isolation_level=None)
                lock.execute("BEGIN IMMEDIATE")  # e.g. an operator's sqlite3 shell, a backup
                held = time.monotonic()
                before = polls(client)
                for seq in range(3):
                    report = CheckpointPacket(seq=seq, time=int(time.time()), state=MissionState.HOLDING)
                    vehicle.send(report.encode())
                wait_for(lambda: polls(client) >= before + 3, timeout=HOLD_S, what="polls while locked")
                assert client.get("/api/v1/packets", headers=OBS).json()["total"] == 0  # not stored yet
                time.sleep(max(0.0, HOLD_S - (time.monotonic() - held)))
                lock.execute("ROLLBACK")
                lock.close()
                wait_for(
                    lambda: client.get("/api/v1/packets", headers=OBS).json()["total"] == 3,
                    timeout=30,
                    what="every frame stored once the lock is gone",
                )
            finally:
                vehicle.close()


def test_parallel_command_posts_are_all_accepted(tmp_path: Path) -> None:
    settings = app_settings(tmp_path).model_copy(update={"max_queued_commands": 100})  # writers, not the cap
    with TestClient(create_app(settings)) as client:
        client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP)

        def post(i: int) -> int:
            body = {"command": "goto_depth", "depth": 1 + i % 10}
            return client.post("/api/v1/vehicles/1/commands", json=body, headers=OP).status_code

        with ThreadPoolExecutor(20) as pool:
            codes = list(pool.map(post, range(40)))
        assert codes == [202] * 40
        seqs = [c["seq"] for c in client.get("/api/v1/vehicles/1/commands?limit=100", headers=OBS).json()]
        assert len(set(seqs)) == 40  # each its own sequence number
