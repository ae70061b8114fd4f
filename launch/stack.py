"""The one launcher: simulated modems and BlueROV2, the shore server and the vehicle agent, wired together.

``tacit demo``, ``tacit replay``, the whole-system tests and the benchmarks all start the system
through a :class:`Stack`, so there is one place that knows how the parts are joined: which pty each
modem is on, which MAVLink port the agent reads, which settings the server gets. Everything lives in
one folder; configuration files are written with serializers (JSON, TOML), never by string pasting,
and files holding secrets are readable by their owner only.

The simulator and the agent always run as child processes (as on a boat: separate programs). The
server runs where the caller wants it: in the caller's process (``server_settings()`` for the demo's
uvicorn or a test's TestClient) or as a child (``start_server()``).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, TypeVar

from launch.processes import stop
from tacit.config import dump_toml

T = TypeVar("T")
SHORE_ADDRESS = 1
VEHICLE_ADDRESS = 2
ATTACKER_ADDRESS = 3


@dataclass
class StackConfig:
    """What the simulated world looks like."""

    data_dir: Path
    range_m: float = 300.0  # shore modem's distance from the vehicle's home (m)
    time_scale: float = 1.0  # simulated seconds per wall second
    extra_loss: float = 0.0  # extra frame loss probability 0..1
    noise_db: float | None = None  # ambient noise level; None: the simulator's default
    seed: int = 1
    environment: dict[str, Any] | None = None  # the simulated water (temperature field); None: default
    replay: str = ""  # a .tlog the simulated vehicle streams instead of simulating its own motion
    position_source: bool = False  # the simulated vehicle has a position fix (GPS at the surface, USBL)
    attacker: bool = False  # a third modem in the water, for tests of forged traffic
    key: str = ""  # the vehicle's key (hex)
    write_tokens: list[str] = field(default_factory=list)
    read_tokens: list[str] = field(default_factory=list)


class Stack:
    """The processes of one simulated deployment, stopped in reverse order by ``close()``."""

    def __init__(self, config: StackConfig) -> None:
        self.config = config
        self.dir = Path(config.data_dir).resolve()
        self.dir.mkdir(parents=True, exist_ok=True)
        self.procs: list[subprocess.Popen[str]] = []
        self.sim_info: dict[str, Any] = {}
        self.agent: subprocess.Popen[str] | None = None
        self.server: subprocess.Popen[str] | None = None
        self.agent_config = self.dir / "agent.toml"

    # the simulator -------------------------------------------------------------------------------
    def start_sim(self) -> dict[str, Any]:
        """Start ``tacit sim``; return what it announces (modem ptys, the vehicle's MAVLink URL)."""
        path = self.dir / "sim.json"
        path.write_text(json.dumps(self._sim_config()))
        sim = self.spawn(["sim", "--config", str(path), "--json"], "sim.log", capture=True)
        line = sim.stdout.readline() if sim.stdout else ""
        if not line:
            raise StackError(f"the simulator did not start; see {self.dir / 'sim.log'}")
        self.sim_info = json.loads(line)
        return self.sim_info

    def _sim_config(self) -> dict[str, Any]:
        c = self.config
        modems = [
            {"address": SHORE_ADDRESS, "name": "shore", "position": [-c.range_m, 0.0, 1.0],
             "link": str(self.pty("shore"))},
            {"address": VEHICLE_ADDRESS, "name": "vehicle", "attach": "rov1", "link": str(self.pty("vehicle"))},
        ]  # fmt: skip
        if c.attacker:
            modems.append({"address": ATTACKER_ADDRESS, "name": "attacker", "position": [-100.0, 30.0, 1.0],
                           "link": str(self.pty("attacker"))})  # fmt: skip
        vehicle: dict[str, Any] = {"name": "rov1", "tcp_port": 0, "seed": c.seed,
                                   "position_source": c.position_source}  # fmt: skip
        if c.replay:
            vehicle["replay"] = str(Path(c.replay).resolve())
        channel: dict[str, Any] = {"extra_loss": c.extra_loss}
        if c.noise_db is not None:
            channel["noise_level_db"] = c.noise_db
        sim: dict[str, Any] = {"seed": c.seed, "time_scale": c.time_scale, "channel": channel,
                               "modems": modems, "vehicles": [vehicle]}  # fmt: skip
        if c.environment is not None:
            env_file = self.dir / "environment.json"
            env_file.write_text(json.dumps(c.environment))
            sim["environment"] = {"file": str(env_file)}
        return sim

    def pty(self, name: str) -> Path:
        """Where the simulated modem ``name`` (shore, vehicle, attacker) has its serial port."""
        return self.dir / f"{name}.pty"

    @property
    def mavlink(self) -> str:
        """The simulated vehicle's MAVLink URL (the agent's ``mavlink_url``)."""
        return str(self.sim_info["vehicle"]["mavlink"][0])

    # the server ------------------------------------------------------------------------------------
    def server_settings(self, **overrides: Any) -> dict[str, Any]:
        """Keyword arguments of the server's ``Settings`` for this stack, with ``overrides``."""
        c = self.config
        values: dict[str, Any] = {
            "database_url": f"sqlite:///{self.dir / 'tacit.db'}", "modem_url": str(self.pty("shore")),
            "modem_log": str(self.dir / "shore-modem.log"), "write_tokens": list(c.write_tokens),
            "read_tokens": list(c.read_tokens), "time_scale": c.time_scale, "default_range": c.range_m,
        }  # fmt: skip
        values.update(overrides)
        return values

    def start_server(self, port: int, **overrides: Any) -> subprocess.Popen[str]:
        """``tacit serve`` as a child process, configured through its ``TACIT_*`` environment."""
        env = {f"TACIT_{k.upper()}": _env_value(v) for k, v in self.server_settings(**overrides).items()}
        self.server = self.spawn(["serve", "--port", str(port)], "serve.log", env=env)
        return self.server

    # the agent -------------------------------------------------------------------------------------
    def write_agent_config(self, **values: Any) -> Path:
        """The agent's TOML for this stack (``values`` add to or override the defaults); owner-only."""
        c = self.config
        config: dict[str, Any] = {
            "address": VEHICLE_ADDRESS, "key": c.key, "modem_url": str(self.pty("vehicle")),
            "mavlink_url": self.mavlink, "state_file": str(self.dir / "agent-state.json"),
            "tlog_dir": str(self.dir / "tlogs"), "time_scale": c.time_scale,
        }  # fmt: skip
        config.update(values)
        write_private(self.agent_config, dump_toml(config))
        return self.agent_config

    def start_agent(self) -> subprocess.Popen[str]:
        """``tacit agent`` on the config last written (``write_agent_config``)."""
        self.agent = self.spawn(["agent", "--config", str(self.agent_config)], "agent.log")
        return self.agent

    def kill(self, proc: subprocess.Popen[str] | None) -> None:
        """SIGKILL: no chance to close or save anything (a power cut, an OOM kill)."""
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)

    # processes -------------------------------------------------------------------------------------
    def spawn(self, args: list[str], log: str, capture: bool = False,
              env: dict[str, str] | None = None) -> subprocess.Popen[str]:  # fmt: skip
        """``tacit ARGS`` as a child; stderr (and stdout unless captured) appended to ``log``."""
        out: IO[str] | int = subprocess.PIPE if capture else open(self.dir / log, "a")
        proc = subprocess.Popen([sys.executable, "-m", "tacit.cli", "--log-level", "INFO", *args], stdout=out,
                                stderr=open(self.dir / log, "a"), text=True,
                                env={**os.environ, **(env or {}), "PYTHONUNBUFFERED": "1"})  # fmt: skip
        self.procs.append(proc)
        return proc

    def log(self, name: str) -> str:
        """The text of a child's log (``agent.log``, ``sim.log``, ``serve.log``)."""
        path = self.dir / name
        return path.read_text() if path.exists() else ""

    def close(self) -> None:
        """Children in reverse order of start: agent before simulator, politely then firmly."""
        for proc in reversed(self.procs):
            stop(proc)


class StackError(RuntimeError):
    """A part of the stack did not start; the message says which log to read."""


def write_private(path: Path, text: str) -> None:
    """Write ``text`` to a file only its owner can read (keys, tokens), created that way."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.chmod(path, 0o600)


def wait_for(
    predicate: Callable[[], T], timeout: float = 60.0, every: float = 0.25, what: str = "condition"
) -> T:
    """Poll ``predicate`` until it returns something true; return that, or fail after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(every)
    raise TimeoutError(f"{what} not reached within {timeout} s")


def _env_value(value: Any) -> str:
    if isinstance(value, list | tuple):
        return ",".join(str(v) for v in value)
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)
