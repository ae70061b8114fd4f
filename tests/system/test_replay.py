"""`tacit replay`: a real dive through the agent and the simulated link into the server, summarised; the
live view's URL and token at once. Its progress bar: tests/unit/launch; its one-line errors: tests/integration/launch."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import httpx

from launch.stack import wait_for

KEYS = {
    "samples",
    "packets",
    "link_bits",
    "bits_per_sample",
    "max_error_ratio",
    "rms_error_ratio",
    "max_latency_s",
    "packets_by_type",
}


def tacit(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tacit.cli", *args], capture_output=True, text=True, timeout=timeout
    )


def test_replay_of_a_real_dive(real_data: Path, tmp_path: Path) -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        map_port = probe.getsockname()[1]
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tacit.cli",
            "replay",
            str(real_data / "ardusub" / "small.tlog"),
            "--time-scale",
            "8",
            "--settle",
            "15",
            "--data-dir",
            str(tmp_path),
            "--port",
            "18577",
            "--map-port",
            str(map_port),
            "--json",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        live = json.loads(proc.stdout.readline())  # type: ignore[union-attr]  # at once, not after the dive
        assert live["dashboard_url"] == "http://127.0.0.1:18577/" and live["seconds"] > 20
        headers = {"Authorization": f"Bearer {live['token']}"}
        assert httpx.get(live["api_url"] + "/whoami", headers=headers).json()["role"] == "write"
        assert httpx.get(live["dashboard_url"]).status_code == 200
        assert live["sign_in_url"] == f"http://127.0.0.1:18577/#token={live['token']}"
        assert live["map_url"] == f"http://127.0.0.1:{map_port}"
        assert httpx.get(live["map_url"]).status_code == 200
        wait_for(
            lambda: httpx.get(live["api_url"] + "/packets", headers=headers).json()["total"] > 0,
            timeout=90,
            what="packets stored during the replay",
        )
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
