"""The whole system for end-to-end tests: simulator and agent as processes, the server in-process.

Ground truth comes from the simulated BlueROV2 itself (GLOBAL_POSITION_INT, ATTITUDE), read by a second
ground station with a system id that ArduSub's MANUAL_CONTROL rule ignores.
"""

from __future__ import annotations

import math
import subprocess
import threading
from dataclasses import dataclass
from pathlib import Path

from fastapi.testclient import TestClient
from pymavlink import mavutil

from launch.stack import VEHICLE_ADDRESS, Stack, StackConfig
from server.app import create_app
from server.core.config import Settings
from tacit.navigation import Origin

OP = {"Authorization": "Bearer operator"}
KEY = "5a" * 32
SCALE = 8.0  # simulated seconds per wall second (tacit replay runs a real dive at 8x too)


@dataclass
class Truth:
    north: float
    east: float
    depth: float
    heading: float


class TruthWatcher:
    """Follows the simulated vehicle's true pose over MAVLink (system id 200: no control authority)."""

    def __init__(self, url: str) -> None:
        self.conn = mavutil.mavlink_connection(url, source_system=200)
        self.conn.wait_heartbeat(timeout=10)
        self.origin = Origin()
        self.latest = Truth(0.0, 0.0, 0.0, 0.0)
        self.track: list[Truth] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=0.5)
            if msg is None:
                continue
            north, east = self.origin.to_local(msg.lat / 1e7, msg.lon / 1e7)
            self.latest = Truth(north, east, -msg.relative_alt / 1000.0, msg.hdg / 100.0)
            self.track.append(self.latest)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.conn.close()


class System:
    """The stack with the server in this process (a TestClient), so tests can read its database."""

    def __init__(
        self,
        tmp: Path,
        position_source: bool = False,
        environment: dict | None = None,
        agent: dict | None = None,
        attacker: bool = False,
        replay: str = "",
    ) -> None:
        self.tmp = tmp
        self.stack = Stack(
            StackConfig(
                tmp,
                range_m=150.0,
                time_scale=SCALE,
                noise_db=95.0,
                seed=5,
                environment=environment,
                replay=replay,
                position_source=position_source,
                attacker=attacker,
                keys=[KEY],
                write_tokens=["operator"],
            )
        )
        self.stack.start_sim()
        self.mavlink = self.stack.mavlink
        settings = Settings(
            **self.stack.server_settings(map_enabled=False, poll_interval=2.0, ping_interval=3600)
        )
        self.client = TestClient(create_app(settings))
        self.client.__enter__()
        created = self.client.post(
            "/api/v1/vehicles", json={"name": "rov1", "address": VEHICLE_ADDRESS, "key": KEY}, headers=OP
        )
        assert created.status_code == 201, created.text
        self.stack.write_agent_config(checkpoint_interval=20, **(agent or {}))
        self.agent = self.start_agent()
        self.truth = TruthWatcher(self.mavlink) if not replay else None

    def start_agent(self) -> subprocess.Popen[str]:
        return self.stack.start_agent()

    def kill_agent(self) -> None:
        self.stack.kill(self.agent)

    def agent_log(self) -> str:
        return self.stack.log("agent.log")

    def command(self, **body: object) -> int:
        response = self.client.post("/api/v1/vehicles/1/commands", json=body, headers=OP)
        assert response.status_code == 202, response.text
        return response.json()["id"]

    def status(self, command_id: int) -> str:
        return self.client.get(f"/api/v1/commands/{command_id}", headers=OP).json()["status"]

    def checkpoint(self) -> dict | None:
        return self.client.get("/api/v1/link", headers=OP).json()["vehicles"]["rov1"]["checkpoint"]

    def packets(self, **filters: object) -> list[dict]:
        return self.client.get("/api/v1/packets", params={"limit": 1000, **filters}, headers=OP).json()[
            "items"
        ]

    def close(self) -> None:
        if self.truth:
            self.truth.close()
        self.client.__exit__(None, None, None)
        self.stack.close()


def angle_between(a: float, b: float) -> float:
    return abs((a - b + 180) % 360 - 180)


def distance(a: Truth, north: float, east: float) -> float:
    return math.hypot(a.north - north, a.east - east)
