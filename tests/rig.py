"""sim + serve + agent as separate processes in a temporary folder, driven through the REST API:
shared by the end-to-end test and the link benchmark."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

from launch.processes import stop
from tests.vehicle_side import VehicleSide

KEY = "3c" * 32
TOKEN = "bench"


class Rig:
    """sim + serve + agent, each its own process, in a temporary folder."""

    def __init__(self, distance: float, scale: float, extra_loss: float = 0.0, noise: float = 95.0,
                 mission: bool = False, attempts: int = 4, agent: bool = True,
                 environment: dict | None = None) -> None:  # fmt: skip
        self.dir = Path(tempfile.mkdtemp(prefix="tacit-bench-"))
        self.procs: list[subprocess.Popen] = []
        self.scale = scale
        sim = {"seed": 7, "time_scale": scale, "channel": {"noise_level_db": noise, "extra_loss": extra_loss},
               "modems": [{"address": 1, "name": "shore", "position": [-distance, 0, 1], "link": str(self.dir / "shore")},
                          {"address": 2, "name": "vehicle", "attach": "rov1", "link": str(self.dir / "vehicle")}],
               "vehicles": [{"name": "rov1", "tcp_port": 0}]}  # fmt: skip
        if environment is not None:
            (self.dir / "env.json").write_text(json.dumps(environment))
            sim["environment"] = {"file": str(self.dir / "env.json")}
        (self.dir / "sim.json").write_text(json.dumps(sim))
        proc = self._spawn(["sim", "--config", str(self.dir / "sim.json"), "--json"], "sim.log", capture=True)
        mavlink = json.loads(proc.stdout.readline())["vehicle"]["mavlink"][0]  # type: ignore[union-attr]
        self.mavlink = mavlink
        self.port = 18600 + int(time.time() * 10) % 300
        env = {"TACIT_DATABASE_URL": f"sqlite:///{self.dir}/tacit.db", "TACIT_MODEM_URL": str(self.dir / "shore"),
               "TACIT_WRITE_TOKENS": TOKEN, "TACIT_TIME_SCALE": str(scale), "TACIT_DEFAULT_RANGE": str(distance),
               "TACIT_MAP_ENABLED": "false", "TACIT_POLL_INTERVAL": "30" if not mission else "2",
               "TACIT_PING_INTERVAL": "100000", "TACIT_COMMAND_ATTEMPTS": str(attempts),
               "TACIT_CONFIRM_TIMEOUT": "60"}  # fmt: skip
        self.server_env = env
        self.server = self._spawn(["serve", "--port", str(self.port)], "serve.log", env=env)
        self.http = httpx.Client(base_url=f"http://127.0.0.1:{self.port}/api/v1",
                                 headers={"Authorization": f"Bearer {TOKEN}"}, timeout=10)  # fmt: skip
        self._wait(lambda: self._ok("/health"), 30)
        self.http.post("/vehicles", json={"name": "rov1", "address": 2, "key": KEY}).raise_for_status()
        missions = (
            'missions = [{builtin = "square", number = 1, side = 20.0, depth = 2.0}]' if mission else ""
        )
        (self.dir / "agent.toml").write_text(
            f'address = 2\nkey = "{KEY}"\nmodem_url = "{self.dir / "vehicle"}"\nmavlink_url = "{mavlink}"\n'
            f'state_file = "{self.dir / "agent.json"}"\ntime_scale = {scale}\ntlog_dir = "{self.dir / "tlogs"}"\n'
            f"checkpoint_interval = 60\n{missions}\n")  # fmt: skip
        self.quiet = None
        self.agent = self.start_agent() if agent else None
        if (
            not agent
        ):  # a vehicle with nothing to say: the paper's silence, so the link is idle between commands
            self.quiet = VehicleSide(str(self.dir / "vehicle"), 2, bytes.fromhex(KEY))
        self._wait(lambda: self._ok("/link") and self.http.get("/link").json()["modem"] == "ready", 30)
        time.sleep(3.0)

    def _spawn(
        self, args: list[str], log: str, capture: bool = False, env: dict | None = None
    ) -> subprocess.Popen:
        proc = subprocess.Popen([sys.executable, "-m", "tacit.cli", "--log-level", "INFO", *args],
                                stdout=subprocess.PIPE if capture else open(self.dir / log, "ab"),  # noqa: SIM115
                                stderr=open(self.dir / log, "ab"), text=True,  # noqa: SIM115
                                env={**os.environ, **(env or {}), "PYTHONUNBUFFERED": "1"})  # fmt: skip
        self.procs.append(proc)
        return proc

    def start_agent(self) -> subprocess.Popen:
        self.agent = self._spawn(["agent", "--config", str(self.dir / "agent.toml")], "agent.log")
        return self.agent

    def kill_agent(self) -> None:
        self.agent.send_signal(signal.SIGKILL)  # type: ignore[union-attr]
        self.agent.wait(timeout=10)  # type: ignore[union-attr]

    def kill_server(self) -> None:
        """SIGKILL: no chance to close anything."""
        self.server.send_signal(signal.SIGKILL)
        self.server.wait(timeout=10)

    def start_server(self) -> None:
        self.server = self._spawn(["serve", "--port", str(self.port)], "serve.log", env=self.server_env)
        self._wait(lambda: self._ok("/link") and self.http.get("/link").json()["modem"] == "ready", 30)

    def _ok(self, path: str) -> bool:
        try:
            return self.http.get(path).status_code == 200
        except httpx.HTTPError:
            return False

    @staticmethod
    def _wait(predicate, timeout: float) -> None:  # noqa: ANN001
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                raise RuntimeError("the rig did not come up")
            time.sleep(0.2)

    def command(self, body: dict, timeout: float) -> tuple[str, float]:
        """POST a command; (final status, seconds to acknowledgement in *simulated* time)."""
        start = time.monotonic()
        command = self.http.post("/vehicles/1/commands", json=body).json()
        acked = None
        status = "queued"
        while time.monotonic() - start < timeout:
            status = self.http.get(f"/commands/{command['id']}").json()["status"]
            if status in ("acknowledged", "executing", "executed", "refused"):
                acked = time.monotonic() - start
                break
            if status == "failed":
                break
            time.sleep(0.005)
        return status, (acked * self.scale if acked is not None else float("nan"))

    def executed_per_seq(self) -> dict[int, int]:
        counts: dict[int, int] = {}
        for seq in re.findall(r"control seq (\d+) accepted", (self.dir / "agent.log").read_text()):
            counts[int(seq)] = counts.get(int(seq), 0) + 1
        return counts

    def close(self) -> None:
        if self.quiet is not None:
            self.quiet.close()
        self.http.close()
        for proc in reversed(self.procs):
            stop(proc)
