"""``tacit demo --gateways 2 --vehicles 3`` as a user runs it, on a broker with the demo deployment's
accounts and the machine's PostgreSQL: both gateways beat, every vehicle gets a gateway and its
check-points are verified; the broker is stopped and started again mid-run (every gateway's backhaul cut
at once); at exit the channel saw no collision and the audit names no frame heard but not stored. Killed
(SIGKILL) on a nats-server of its own, it leaves no process behind."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import psycopg
import pytest

from launch import split
from launch.stack import wait_for
from tests.support.nats import Secured, free_port

POSTGRES = "postgresql+psycopg://postgres@127.0.0.1:5432/test"


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Secured]:
    """A broker configured as `tacit broker-config --deployment demo --gateway gw1 --gateway gw2` does."""
    server = Secured(tmp_path / "broker", ["gw1", "gw2"], deployment=split.DEPLOYMENT)
    server.start()
    yield server
    server.stop()


def drop_database(data: Path) -> None:
    marker = data / split.MARKER
    if marker.exists():
        name = marker.read_text().strip().rsplit("/", 1)[1]
        with psycopg.connect(split._libpq(POSTGRES), autocommit=True) as c:
            c.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def demo(data: Path, broker: Secured | None) -> subprocess.Popen[str]:
    """The split demo, on ``broker`` (None: a nats-server of its own)."""
    on = ["--nats", broker.url, "--broker-dir", str(broker.folder)] if broker is not None else []
    return subprocess.Popen(
        [sys.executable, "-m", "tacit.cli", "demo", "--gateways", "2", "--vehicles", "3", "--time-scale", "4",
         "--headless", "--json", "--data-dir", str(data), *on, "--postgres", POSTGRES,
         "--port", str(free_port()), "--map-port", str(free_port())],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def children(pid: int) -> set[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # gone meanwhile
            continue
        if int(fields[1]) == pid:
            found.add(int(stat.parent.name))
    return found


def alive(pids: set[int]) -> set[int]:
    """Those of ``pids`` still running (not zombies)."""
    running = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            running.add(pid)
    return running


def verified_checkpoints(http: httpx.Client) -> dict[int, int]:
    """Verified check-points stored per vehicle id."""
    items = http.get("/packets", params={"limit": 1000, "type": "checkpoint"}).json()["items"]
    counts: dict[int, int] = {}
    for p in items:
        if p.get("auth") == "verified":
            counts[p["vehicle_id"]] = counts.get(p["vehicle_id"], 0) + 1
    return counts


def test_the_split_demo_survives_a_broker_restart_and_loses_no_frame(tmp_path: Path, broker: Secured) -> None:
    data = tmp_path / "demo"
    proc = demo(data, broker)
    try:
        info = json.loads(proc.stdout.readline())  # type: ignore[union-attr]
        http = httpx.Client(
            base_url=info["api_url"], headers={"Authorization": f"Bearer {info['token']}"}, timeout=10
        )
        wait_for(lambda: sum(g["state"] == "up" for g in http.get("/gateways").json()) == 2,
                 60, what="both gateways beating")  # fmt: skip
        wait_for(lambda: all(v["gateway"] for v in http.get("/fleet").json()["vehicles"]), 120,
                 what="every vehicle assigned a gateway")  # fmt: skip
        before = verified_checkpoints(http)
        broker.stop()  # every gateway's backhaul cut: they keep polling and storing
        time.sleep(15)
        broker.start()
        wait_for(lambda: len(verified_checkpoints(http)) == 3 and verified_checkpoints(http) != before, 180,
                 what="verified check-points of every vehicle, after the outage")  # fmt: skip
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
        drop_database(data)
    assert proc.returncode == 0, err[-3000:]
    collisions = re.search(r"were lost: (\d+) in collisions", out)
    assert collisions and collisions.group(1) == "0", out[-3000:]
    audit = [line for line in out.splitlines() if re.match(r"\s*gw\d: \d+ frames heard", line)]
    assert len(audit) == 2 and not any("NOT STORED" in line for line in audit), out[-3000:]


def test_a_killed_split_demo_leaves_no_process_behind(tmp_path: Path) -> None:
    """SIGKILL: no chance to stop anything. Its nats-server, simulator, gateways and agents end by
    themselves."""
    data = tmp_path / "demo"
    proc = demo(data, None)
    try:
        json.loads(proc.stdout.readline())  # type: ignore[union-attr]  # everything started
        started = children(proc.pid)
        assert len(started) == 10  # nats-server, the center, the simulator, 2 relays, 2 gateways, 3 agents
        proc.kill()
        proc.wait(timeout=10)
        wait_for(lambda: not alive(started), 60, what="every child of the killed demo gone")
    finally:
        if proc.poll() is None:
            proc.kill()
        drop_database(data)
