"""`tacit demo` stops cleanly: SIGTERM ends the agent and the simulator, the database stays consistent."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

from launch.stack import wait_for


def children_using(folder: Path) -> list[int]:
    """Processes whose command line names a file in ``folder`` (the demo's simulator and agent)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            if str(folder) in cmdline and "tacit.cli" in cmdline and int(entry.name) != os.getpid():
                pids.append(int(entry.name))
    return pids


def commands(db_path: Path) -> int:
    """The command rows in the demo's database (0 while it does not exist yet)."""
    if not db_path.exists():
        return 0
    try:
        with sqlite3.connect(db_path) as db:
            return db.execute("SELECT count(*) FROM command").fetchone()[0]
    except sqlite3.OperationalError:  # the tables are not created yet
        return 0


def test_demo_starts_and_stops_cleanly(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tacit.cli",
            "demo",
            "--headless",
            "--json",
            "--data-dir",
            str(tmp_path),
            "--port",
            "18655",
            "--map-port",
            "18695",
            "--time-scale",
            "4",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    info = json.loads(proc.stdout.readline())  # type: ignore[union-attr]
    assert {"api_url", "dashboard_url", "map_url", "token", "modems", "vehicle"} <= set(info)
    deadline = time.monotonic() + 30
    while len(children_using(tmp_path)) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    assert len(children_using(tmp_path)) >= 2  # the simulator and the agent
    wait_for(
        lambda: commands(tmp_path / "tacit.db") >= 1, timeout=30, what="the mission's start command stored"
    )
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=30) == 0, proc.stderr.read()[-2000:]  # type: ignore[union-attr]
    time.sleep(0.5)
    assert children_using(tmp_path) == []
    with sqlite3.connect(tmp_path / "tacit.db") as db:
        assert db.execute("PRAGMA integrity_check").fetchone() == ("ok",)
        assert db.execute("SELECT count(*) FROM command").fetchone()[0] >= 1  # the mission's start
    assert (tmp_path / "secrets.json").stat().st_mode & 0o077 == 0  # the token and key are private
