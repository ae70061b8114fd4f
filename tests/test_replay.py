"""`tacit replay`: a real dive through the agent and the simulated link into the server, summarised; the
live view's URL and token at once, a progress bar, and one-line errors (missing file, busy port)."""

from __future__ import annotations

import asyncio
import io
import json
import socket
import subprocess
import sys
from pathlib import Path

import httpx

from launch.replay import wait_with_progress
from launch.stack import wait_for

KEYS = {"samples", "packets", "link_bits", "bits_per_sample", "max_error_ratio", "rms_error_ratio", "max_latency_s",
        "packets_by_type"}  # fmt: skip


def tacit(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tacit.cli", *args], capture_output=True, text=True, timeout=timeout
    )


def test_replay_of_a_real_dive(shared_data: Path, tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "tacit.cli", "replay", str(shared_data / "ardusub" / "small.tlog"),
                             "--time-scale", "8", "--settle", "15", "--data-dir", str(tmp_path), "--port", "18577",
                             "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        live = json.loads(proc.stdout.readline())  # type: ignore[union-attr]  # at once, not after the dive
        assert live["dashboard_url"] == "http://127.0.0.1:18577/" and live["seconds"] > 20
        headers = {"Authorization": f"Bearer {live['token']}"}
        assert httpx.get(live["api_url"] + "/whoami", headers=headers).json() == {"role": "write"}
        assert httpx.get(live["dashboard_url"]).status_code == 200
        wait_for(lambda: httpx.get(live["api_url"] + "/packets", headers=headers).json()["total"] > 0, timeout=90,
                 what="packets stored during the replay")  # fmt: skip
        out, err = proc.communicate(timeout=240)
    finally:
        proc.kill()
    assert proc.returncode == 0, err[-2000:]
    summary = json.loads(out.strip().splitlines()[-1])
    assert KEYS <= set(summary)
    assert summary["packets_by_type"].get("priority/kinematic", 0) >= 3 and summary["packets_by_type"].get(
        "checkpoint"
    )
    assert summary["samples"] > 500 and summary["link_bits"] == summary["packets"] * 256
    assert summary["max_error_ratio"] <= 1.0  # the shore's reconstruction of the real IMU, within eps


def test_progress_bar_shows_time_and_packets() -> None:
    out = io.StringIO()
    count = iter(range(100))
    asyncio.run(wait_with_progress(1.2, lambda: next(count), file=out, disable=False, step=0.2))
    text = out.getvalue()
    assert "replay: 100%" in text and "1/1 s" in text and "packets stored" in text


def test_a_missing_log_is_named_as_such(tmp_path: Path) -> None:
    missing = str(tmp_path / "dive.tlog")
    for args in (
        ("replay", missing),
        ("sim", "--replay", missing),
        ("eval-compression", missing, "--eps", "1"),
    ):
        result = tacit(*args)
        assert result.returncode == 2 and result.stderr.strip().endswith(
            "no such file" if args[0] != "sim" else "no such file (the .tlog to replay)"
        ), result.stderr
        assert "port" not in result.stderr and "Traceback" not in result.stderr


def test_a_busy_port_is_one_line(tmp_path: Path, shared_data: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = str(busy.getsockname()[1])
        runs = {
            "replay": tacit(
                "replay",
                str(shared_data / "ardusub" / "small.tlog"),
                "--port",
                port,
                "--data-dir",
                str(tmp_path / "r"),
            ),  # fmt: skip
            "demo": tacit("demo", "--headless", "--port", port, "--data-dir", str(tmp_path / "d")),
            "serve": tacit(
                "serve", "--port", port, "--no-map", "--database-url", f"sqlite:///{tmp_path}/s.db"
            ),
        }
    for name, result in runs.items():
        assert result.returncode == 1, (name, result.stderr)
        assert result.stderr.strip() == (
            f"tacit {name}: cannot listen on 127.0.0.1:{port} (Address already in use); choose another with --port"
        ), result.stderr
    assert not (tmp_path / "d").exists()  # nothing was started
