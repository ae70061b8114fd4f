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
from urllib.parse import urlsplit

from launch.broker import free_port
from launch.processes import stop
from tacit.cli import PARENT
from tacit.config import dump_toml
from tacit.navigation import Origin
from tacit.private import open_private, private_dir

T = TypeVar("T")
SHORE_ADDRESS = 1
VEHICLE_ADDRESS = 2  # the first vehicle's; the others follow (3, 4, ...)
SIM_ORIGIN = Origin()  # where the simulator's GPS puts the fleet's origin (simulators.mavlink_vehicle)
SPACING_M = 30.0  # the fleet's homes, east of each other: the demo's 20 m squares do not overlap
GATEWAY_SPACING_M = 900.0  # a split shore's modems, east of each other: each hears its end of the water


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
    attacker: bool = False  # one more modem in the water, for tests of forged traffic
    recorder: bool = False  # one more that reports every data frame it hears (a recorder on the channel)
    stepped_clocks: bool = False  # the server's and agents' wall clocks can be stepped (``step_clock``)
    vehicles: int = 1  # simulated BlueROV2s on the one channel, each with its own agent
    gateways: int = 0  # a split shore's modems (a `tacit gateway` each), ``range_m`` west of home and
    # then every GATEWAY_SPACING_M east; 0: the one shore modem of `tacit serve`
    keys: list[str] = field(default_factory=list)  # one per vehicle (hex); none: agents without keys
    addresses: list[int] = field(default_factory=list)  # one per vehicle; none: 2, 3, ...
    write_tokens: list[str] = field(default_factory=list)
    read_tokens: list[str] = field(default_factory=list)

    def members(self) -> list[Member]:
        """The fleet, checked: one clear ``StackError`` if two vehicles would share an address or a key."""
        if self.vehicles < 1:
            raise StackError("a stack has at least one vehicle")
        addresses = self.addresses or [VEHICLE_ADDRESS + i for i in range(self.vehicles)]
        keys = self.keys or [""] * self.vehicles
        if len(addresses) != self.vehicles or len(keys) != self.vehicles:
            raise StackError(f"{self.vehicles} vehicle(s) need as many addresses and keys")
        shore = {SHORE_ADDRESS, *(gateway_address(i) for i in range(self.gateways))}
        if taken := sorted(shore & set(addresses)):
            what = f"address {taken[0]} is" if len(taken) == 1 else f"addresses {taken} are"
            raise StackError(f"modem {what} the shore's (its modems use {sorted(shore)}), not a vehicle's")
        _unique("modem address", addresses)
        _unique("key", [k.lower() for k in keys if k])
        return [Member(i, a, k) for i, (a, k) in enumerate(zip(addresses, keys, strict=True))]


@dataclass(frozen=True)
class Member:
    """One simulated vehicle of the stack: its name, modem address, key, home and files. The first keeps
    the names a one-vehicle stack always had (``agent.toml``, ``agent-state.json``, ``vehicle.pty``);
    the others' carry their name (``agent-rov2.toml``, ...)."""

    index: int
    address: int
    key: str

    @property
    def name(self) -> str:
        return f"rov{self.index + 1}"

    @property
    def home(self) -> tuple[float, float]:
        """Where it starts, north and east in the fleet's one frame (the simulator puts it there)."""
        return 0.0, SPACING_M * self.index

    def file(self, name: str) -> str:
        """``name`` (``agent.log``) as this vehicle's (``agent-rov2.log``)."""
        if self.index == 0:
            return name
        stem, dot, suffix = name.partition(".")
        return f"{stem}-{self.name}{dot}{suffix}"

    def registration(self) -> dict[str, Any]:
        """The body of ``POST /api/v1/vehicles`` for it."""
        return {
            "name": self.name,
            "address": self.address,
            "home": list(self.home),
            **({"key": self.key} if self.key else {}),
        }


def gateway_address(index: int) -> int:
    """The modem address of a split shore's gateway ``index`` (0: the shore's own, 1)."""
    return SHORE_ADDRESS if index == 0 else 100 + index


def gateway_name(index: int) -> str:
    return f"gw{index + 1}"


def _unique(what: str, values: list[Any]) -> None:
    repeated = sorted({str(v) for v in values if values.count(v) > 1})
    if repeated:
        raise StackError(f"two vehicles with the same {what}: {', '.join(repeated)}")


class Stack:
    """The processes of one simulated deployment, stopped in reverse order by ``close()``."""

    def __init__(self, config: StackConfig) -> None:
        self.config = config
        self.members = config.members()
        self.dir = private_dir(Path(config.data_dir).resolve(), narrow=True)
        self.procs: list[subprocess.Popen[str]] = []
        self.parts: dict[str, subprocess.Popen[str]] = {}  # by name: its log's, without ".log"
        self.sim_info: dict[str, Any] = {}
        self.agents: dict[int, subprocess.Popen[str]] = {}  # by vehicle index
        self.server: subprocess.Popen[str] | None = None
        self.sim: subprocess.Popen[str] | None = None

    # the simulator -------------------------------------------------------------------------------
    def start_sim(self) -> dict[str, Any]:
        """Start ``tacit sim``; return what it announces (modem ptys, the vehicle's MAVLink URL)."""
        path = self.dir / "sim.json"
        path.write_text(json.dumps(self._sim_config()))
        sim = self.sim = self.spawn(["sim", "--config", str(path), "--json"], "sim.log", capture=True)
        line = sim.stdout.readline() if sim.stdout else ""
        if not line:
            raise StackError(f"the simulator did not start; see {self.dir / 'sim.log'}")
        self.sim_info = json.loads(line)
        return self.sim_info

    def sim_report(self) -> dict[str, Any]:
        """What the simulator reported when it stopped (after ``close``): the channel's transmissions,
        losses and collisions, each modem's counters; empty if it said nothing."""
        out = self.sim.stdout.read() if self.sim is not None and self.sim.stdout else ""
        last = next((line for line in reversed(out.splitlines()) if line.startswith("{")), "{}")
        return dict(json.loads(last).get("report", {}))

    def _shore_modems(self) -> list[dict[str, Any]]:
        c = self.config
        if not c.gateways:
            return [{"address": SHORE_ADDRESS, "name": "shore", "position": [-c.range_m, 0.0, 1.0],
                     "link": str(self.pty("shore"))}]  # fmt: skip
        return [
            {"address": gateway_address(i), "name": gateway_name(i), "position": list(self.gateway_place(i)),
             "link": str(self.pty(gateway_name(i)))}
            for i in range(c.gateways)
        ]  # fmt: skip

    def gateway_place(self, index: int) -> tuple[float, float, float]:
        """Where gateway ``index``'s simulated modem is: (north, east, depth) m in the fleet's frame, the
        first ``range_m`` west of home, the others every ``GATEWAY_SPACING_M`` east of it."""
        return 0.0, -self.config.range_m + GATEWAY_SPACING_M * index, 1.0

    def _sim_config(self) -> dict[str, Any]:
        c = self.config
        modems = self._shore_modems()
        modems += [
            {
                "address": m.address,
                "name": m.file("vehicle"),
                "attach": m.name,
                "link": str(self.pty(m.file("vehicle"))),
            }
            for m in self.members
        ]
        last = max(m.address for m in self.members)
        if c.attacker:  # the first address after the fleet's
            modems.append(
                {
                    "address": last + 1,
                    "name": "attacker",
                    "position": [-100.0, 30.0, 1.0],
                    "link": str(self.pty("attacker")),
                }
            )
        if c.recorder:
            modems.append(
                {
                    "address": last + 2,
                    "name": "recorder",
                    "position": [-150.0, -30.0, 1.0],
                    "link": str(self.pty("recorder")),
                    "recorder": True,
                }
            )
        channel: dict[str, Any] = {"extra_loss": c.extra_loss}
        if c.noise_db is not None:
            channel["noise_level_db"] = c.noise_db
        sim: dict[str, Any] = {
            "seed": c.seed,
            "time_scale": c.time_scale,
            "channel": channel,
            "modems": modems,
            "vehicles": [self._sim_vehicle(m) for m in self.members],
        }
        if c.environment is not None:
            env_file = self.dir / "environment.json"
            env_file.write_text(json.dumps(c.environment))
            sim["environment"] = {"file": str(env_file)}
        return sim

    def _sim_vehicle(self, member: Member) -> dict[str, Any]:
        c = self.config
        vehicle: dict[str, Any] = {
            "name": member.name,
            "tcp_port": 0,
            "seed": c.seed + member.index,
            "position_source": c.position_source,
            "start": [*member.home, 0.0],
        }
        if c.replay:
            vehicle["replay"] = str(Path(c.replay).resolve())
        return vehicle

    def pty(self, name: str) -> Path:
        """Where the simulated modem ``name`` (shore, vehicle, vehicle-rov2, attacker, recorder) has its
        serial port."""
        return self.dir / f"{name}.pty"

    def mavlink_of(self, vehicle: int = 0) -> str:
        """A simulated vehicle's MAVLink URL (its agent's ``mavlink_url``), by index."""
        return str(self.sim_info["vehicles"][vehicle]["mavlink"][0])

    @property
    def mavlink(self) -> str:
        """The first simulated vehicle's MAVLink URL."""
        return self.mavlink_of(0)

    # the server ------------------------------------------------------------------------------------
    def server_settings(self, **overrides: Any) -> dict[str, Any]:
        """Keyword arguments of the server's ``Settings`` for this stack, with ``overrides``."""
        c = self.config
        values: dict[str, Any] = {
            "database_url": f"sqlite:///{self.dir / 'tacit.db'}", "modem_url": str(self.pty("shore")),
            "modem_log": str(self.dir / "shore-modem.log"), "write_tokens": list(c.write_tokens),
            "read_tokens": list(c.read_tokens), "time_scale": c.time_scale, "default_range": c.range_m,
            "origin": (SIM_ORIGIN.lat, SIM_ORIGIN.lon),
            "metrics_port": 0,  # stacks run side by side: /metrics only where asked for (the demo)
        }  # fmt: skip
        values.update(overrides)
        return values

    def start_server(self, port: int, **overrides: Any) -> subprocess.Popen[str]:
        """``tacit serve`` as a child process, configured through its ``TACIT_*`` environment."""
        env = {f"TACIT_{k.upper()}": _env_value(v) for k, v in self.server_settings(**overrides).items()}
        self.server = self.spawn(["serve", "--port", str(port)], "serve.log", env=env, clock="shore")
        return self.server

    # a split shore's gateways -----------------------------------------------------------------------
    def start_gateway(
        self, index: int, nats_url: str, credentials: Path, deployment: str
    ) -> subprocess.Popen[str]:
        """``tacit gateway`` on the simulated modem of gateway ``index`` (told where it is, for the screens),
        its outbox in the stack's folder, with its broker ``credentials`` in ``deployment``; its backhaul
        through a relay of its own (``relay-<name>``: stop that process and this gateway's link alone
        goes silent)."""
        name = gateway_name(index)
        port = urlsplit(nats_url).port or 4222
        relay = free_port()
        upstream = f"{urlsplit(nats_url).hostname or '127.0.0.1'}:{port}"
        self.spawn(["--listen", str(relay), "--to", upstream], f"relay-{name}.log", module="launch.relay")
        nats_url = urlsplit(nats_url)._replace(netloc=f"127.0.0.1:{relay}").geturl()
        return self.spawn(
            ["gateway", "--nats", nats_url, "--nats-credentials", str(credentials), "--deployment", deployment,
             "--name", name, "--outbox", str(self.dir / f"gateway-{name}.db"),
             "--modem-url", str(self.pty(name)), "--modem-address", str(gateway_address(index)),
             "--modem-log", str(self.dir / f"gateway-{name}-modem.log"),
             "--time-scale", str(self.config.time_scale),
             "--position=" + ",".join(f"{x:g}" for x in self.gateway_place(index))],
            f"gateway-{name}.log",
        )  # fmt: skip

    # the agent -------------------------------------------------------------------------------------
    def agent_config(self, vehicle: int = 0) -> Path:
        """Where a vehicle's agent configuration is written."""
        return self.dir / self.members[vehicle].file("agent.toml")

    def write_agent_config(self, vehicle: int = 0, **values: Any) -> Path:
        """A vehicle's agent TOML for this stack (``values`` add to or override the defaults; ``nav`` is
        merged with its home); owner-only."""
        m = self.members[vehicle]
        config: dict[str, Any] = {
            "address": m.address, "key": m.key, "modem_url": str(self.pty(m.file("vehicle"))),
            "mavlink_url": self.mavlink_of(vehicle), "state_file": str(self.dir / m.file("agent-state.json")),
            "tlog_dir": str(self.dir / m.file("tlogs")), "time_scale": self.config.time_scale,
            "gateways": [gateway_address(i) for i in range(1, self.config.gateways)],
        }  # fmt: skip
        config.update(values)
        config["nav"] = {"home": list(m.home), **values.get("nav", {})}
        path = self.agent_config(vehicle)
        write_private(path, dump_toml(config))
        return path

    def start_agent(self, vehicle: int = 0) -> subprocess.Popen[str]:
        """``tacit agent`` on the vehicle's config last written (``write_agent_config``)."""
        log = self.members[vehicle].file("agent.log")
        clock = self.members[vehicle].file("agent")
        self.agents[vehicle] = self.spawn(
            ["agent", "--config", str(self.agent_config(vehicle))], log, clock=clock
        )
        return self.agents[vehicle]

    @property
    def agent(self) -> subprocess.Popen[str] | None:
        """The first vehicle's agent process, if started."""
        return self.agents.get(0)

    def kill(self, proc: subprocess.Popen[str] | None) -> None:
        """SIGKILL: no chance to close or save anything (a power cut, an OOM kill)."""
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)

    # clocks ----------------------------------------------------------------------------------------
    def step_clock(self, name: str, seconds: float) -> None:
        """Set the wall clock of ``name`` (``shore``, ``agent``, ``agent-rov2``) ``seconds`` off the true
        time, at once, while it runs (``stepped_clocks`` stacks only; ``launch.stepped_clock``)."""
        if not self.config.stepped_clocks:
            raise StackError("this stack's clocks cannot be stepped (StackConfig.stepped_clocks)")
        write_private(self.dir / f"{name}.clock", repr(float(seconds)))

    # processes -------------------------------------------------------------------------------------
    def spawn(
        self,
        args: list[str],
        log: str,
        capture: bool = False,
        env: dict[str, str] | None = None,
        clock: str = "",
        module: str = "tacit.cli",
    ) -> subprocess.Popen[str]:
        """``tacit ARGS`` as a child; stderr (and stdout unless captured) appended to ``log``. What the child
        creates (its database, tlogs, modem logs) is owner-only as well (umask 077). It ends when this
        process does, however this one ends (``tacit.cli``: ``TACIT_PARENT_PID``). ``clock``: the name
        its wall clock is stepped by (``step_clock``), in a stack with ``stepped_clocks``."""
        out: IO[str] | int = subprocess.PIPE if capture else open_private(self.dir / log)
        entry = ["-m", module, *(["--log-level", "INFO"] if module == "tacit.cli" else [])]
        if clock and self.config.stepped_clocks:
            entry = ["-m", "launch.stepped_clock", str(self.dir / f"{clock}.clock"), "--log-level", "INFO"]
        proc = subprocess.Popen(
            [sys.executable, *entry, *args],
            stdout=out,
            stderr=open_private(self.dir / log),
            text=True,
            umask=0o077,
            env={**os.environ, **(env or {}), "PYTHONUNBUFFERED": "1", PARENT: str(os.getpid())},
        )
        self.procs.append(proc)
        self.parts[log.removesuffix(".log")] = proc
        return proc

    def log(self, name: str) -> str:
        """The text of a child's log (``agent.log``, ``agent-rov2.log``, ``sim.log``, ``serve.log``)."""
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
    with open_private(path, "w") as f:
        f.write(text)


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
