"""`tacit replay`: a real dive through the agent and the simulated link into the server, summarised."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

KEYS = {"samples", "packets", "link_bits", "bits_per_sample", "max_error_ratio", "rms_error_ratio", "max_latency_s",
        "packets_by_type"}  # fmt: skip


def test_replay_of_a_real_dive(shared_data: Path, tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, "-m", "tacit.cli", "replay", str(shared_data / "ardusub" / "small.tlog"),
                             "--time-scale", "8", "--settle", "15", "--data-dir", str(tmp_path), "--port", "18577",
                             "--json"], capture_output=True, text=True, timeout=240)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert KEYS <= set(summary)
    assert summary["packets_by_type"].get("priority/kinematic", 0) >= 3 and summary["packets_by_type"].get(
        "checkpoint"
    )
    assert summary["samples"] > 500 and summary["link_bits"] == summary["packets"] * 256
    assert summary["max_error_ratio"] <= 1.0  # the shore's reconstruction of the real IMU, within eps
