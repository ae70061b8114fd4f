"""The whole system for end-to-end tests: simulator and agent as processes, the server in-process.

Ground truth comes from the simulated BlueROV2 itself (GLOBAL_POSITION_INT, ATTITUDE), read by a second
ground station with a system id that ArduSub's MANUAL_CONTROL rule ignores.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from fastapi.testclient import TestClient
from pymavlink import mavutil

from launch.processes import stop
from server.app import create_app
from server.settings import Settings
from tacit.navigation import Origin

OP = {"Authorization": "Bearer operator"}
KEY = "5a" * 32
SCALE = 5.0


def wait_for(predicate, timeout: float = 60.0, every: float = 0.25, what: str = "condition"):  # noqa: ANN001, ANN201
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(every)
    raise AssertionError(f"{what} not reached within {timeout} s")


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
    def __init__(self, tmp: Path, position_source: bool = False, environment: dict | None = None,
                 agent_extra: str = "", attacker: bool = False, replay: str = "") -> None:  # fmt: skip
        self.tmp = tmp
        self.procs: list[subprocess.Popen] = []
        modems = [{"address": 1, "name": "shore", "position": [-150, 0, 1], "link": str(tmp / "shore")},
                  {"address": 2, "name": "vehicle", "attach": "rov1", "link": str(tmp / "vehicle")}]  # fmt: skip
        if attacker:
            modems.append(
                {"address": 3, "name": "attacker", "position": [-100, 30, 1], "link": str(tmp / "attacker")}
            )
        vehicle = {"name": "rov1", "tcp_port": 0, "position_source": position_source, "replay": replay}
        sim = {"seed": 5, "time_scale": SCALE, "channel": {"noise_level_db": 95.0}, "modems": modems,
               "vehicles": [vehicle]}  # fmt: skip
        if environment is not None:
            (tmp / "env.json").write_text(json.dumps(environment))
            sim["environment"] = {"file": str(tmp / "env.json")}
        (tmp / "sim.json").write_text(json.dumps(sim))
        self.sim = self._spawn("sim", "--config", str(tmp / "sim.json"), "--json", log="sim.log")
        self.sim_info = json.loads(self.sim.stdout.readline())  # type: ignore[union-attr]
        self.mavlink = self.sim_info["vehicle"]["mavlink"][0]
        settings = Settings(database_url=f"sqlite:///{tmp}/tacit.db", modem_url=str(tmp / "shore"), map_enabled=False,
                            write_tokens=["operator"], time_scale=SCALE, poll_interval=2.0, default_range=150.0,
                            ping_interval=3600, modem_log=str(tmp / "shore-modem.log"))  # fmt: skip
        self.client = TestClient(create_app(settings))
        self.client.__enter__()
        created = self.client.post(
            "/api/v1/vehicles", json={"name": "rov1", "address": 2, "key": KEY}, headers=OP
        )
        assert created.status_code == 201, created.text
        self.agent_config = tmp / "agent.toml"
        self.agent_config.write_text(
            f'address = 2\nkey = "{KEY}"\nmodem_url = "{tmp / "vehicle"}"\nmavlink_url = "{self.mavlink}"\n'
            f'state_file = "{tmp / "agent-state.json"}"\ntime_scale = {SCALE}\ncheckpoint_interval = 20\n'
            f'tlog_dir = "{tmp / "tlogs"}"\n{agent_extra}\n')  # fmt: skip
        self.agent = self.start_agent()
        self.truth = TruthWatcher(self.mavlink) if not replay else None

    def _spawn(self, *args: str, log: str) -> subprocess.Popen:
        out = subprocess.PIPE if "--json" in args else open(self.tmp / log, "ab")  # noqa: SIM115
        proc = subprocess.Popen([sys.executable, "-m", "tacit.cli", *args], stdout=out,
                                stderr=open(self.tmp / log, "ab"), text=True,  # noqa: SIM115
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip
        self.procs.append(proc)
        return proc

    def start_agent(self) -> subprocess.Popen:
        return self._spawn("agent", "--config", str(self.agent_config), log="agent.log")

    def kill_agent(self) -> None:
        self.agent.send_signal(signal.SIGKILL)
        self.agent.wait(timeout=10)

    def agent_log(self) -> str:
        return (self.tmp / "agent.log").read_text()

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
        for proc in reversed(self.procs):
            stop(proc)


def angle_between(a: float, b: float) -> float:
    return abs((a - b + 180) % 360 - 180)


def distance(a: Truth, north: float, east: float) -> float:
    return math.hypot(a.north - north, a.east - east)
