"""The stack with the server as its own process, driven over the REST API as a script would drive it:
for the end-to-end and fault tests and the link benchmark."""

from __future__ import annotations

import re
import tempfile
import time
from pathlib import Path

import httpx

from launch.stack import VEHICLE_ADDRESS, Stack, StackConfig, wait_for
from launch.vehicle_host import VehicleSide

KEY = "3c" * 32
TOKEN = "bench"


class Rig:
    """sim + serve + agent, each its own process, in a temporary folder."""

    def __init__(
        self,
        distance: float,
        scale: float,
        extra_loss: float = 0.0,
        noise: float = 95.0,
        mission: bool = False,
        attempts: int = 4,
        agent: bool = True,
        environment: dict | None = None,
        agent_config: dict | None = None,
        settle: float = 3.0,
        attacker: bool = False,
        recorder: bool = False,
        stepped_clocks: bool = False,
        server: dict | None = None,
    ) -> None:
        """``settle``: wall seconds to wait once the agent is up and connected (benchmarks time their first
        command from there; tests need none). ``attacker``, ``recorder``, ``stepped_clocks``: as in
        ``StackConfig``; ``server``: settings overriding the rig's."""
        self.dir = Path(tempfile.mkdtemp(prefix="tacit-bench-"))
        self.scale = scale
        self.stack = Stack(
            StackConfig(
                self.dir,
                range_m=distance,
                time_scale=scale,
                extra_loss=extra_loss,
                noise_db=noise,
                seed=7,
                environment=environment,
                keys=[KEY],
                write_tokens=[TOKEN],
                attacker=attacker,
                recorder=recorder,
                stepped_clocks=stepped_clocks,
            )
        )
        self.stack.start_sim()
        self.mavlink = self.stack.mavlink
        self.port = 18600 + int(time.time() * 10) % 300
        self.server_overrides = {
            "map_enabled": False,
            "poll_interval": 2 if mission else 30,
            "ping_interval": 100000,
            "command_attempts": attempts,
            "confirm_timeout": 60,
            **(server or {}),
        }
        self.stack.start_server(self.port, **self.server_overrides)
        self.http = httpx.Client(
            base_url=f"http://127.0.0.1:{self.port}/api/v1",
            headers={"Authorization": f"Bearer {TOKEN}"},
            timeout=10,
        )
        wait_for(lambda: self._ok("/health"), 30, what="the server")
        self.http.post(
            "/vehicles", json={"name": "rov1", "address": VEHICLE_ADDRESS, "key": KEY}
        ).raise_for_status()
        missions = [{"builtin": "square", "number": 1, "side": 20.0, "depth": 2.0}] if mission else None
        self.agent_values = {"checkpoint_interval": 60, "missions": missions, **(agent_config or {})}
        self.stack.write_agent_config(**self.agent_values)
        self.quiet = None
        if agent:
            self.stack.start_agent()
        else:  # a vehicle with nothing to say: the paper's silence, so the link is idle between commands
            self.quiet = VehicleSide(str(self.stack.pty("vehicle")), VEHICLE_ADDRESS, bytes.fromhex(KEY))
        wait_for(self._modem_ready, 30, what="the shore modem")
        if agent:
            wait_for(self._agent_up, 30, what="the agent on its modem and MAVLink")
        time.sleep(settle)

    def start_agent(self) -> None:
        self.stack.start_agent()

    def start_square(self) -> None:
        """Record the agent's built-in square (``mission=True``) as mission 1 and start it."""
        self.http.post("/vehicles/1/missions", json={"name": "square", "number": 1, "waypoints": []})
        self.http.post("/missions/1/start").raise_for_status()

    def restart_agent(self, **changes: object) -> None:
        """SIGKILL the agent and start it again on its configuration with ``changes``."""
        self.kill_agent()
        self.stack.write_agent_config(**{**self.agent_values, **changes})
        self.start_agent()

    def kill_agent(self) -> None:
        self.stack.kill(self.stack.agent)

    def kill_server(self) -> None:
        """SIGKILL: no chance to close anything."""
        self.stack.kill(self.stack.server)

    def start_server(self) -> None:
        self.stack.start_server(self.port, **self.server_overrides)
        wait_for(self._modem_ready, 30, what="the shore modem")

    def _agent_up(self) -> bool:
        log = self.stack.log("agent.log")
        return " up: modem " in log and "MAVLink connected" in log

    def _modem_ready(self) -> bool:
        return self._ok("/link") and self.http.get("/link").json()["modem"] == "ready"

    def _ok(self, path: str) -> bool:
        try:
            return self.http.get(path).status_code == 200
        except httpx.HTTPError:
            return False

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
        for seq in re.findall(r"control seq (\d+) accepted", self.stack.log("agent.log")):
            counts[int(seq)] = counts.get(int(seq), 0) + 1
        return counts

    def close(self) -> None:
        if self.quiet is not None:
            self.quiet.close()
        self.http.close()
        self.stack.close()
