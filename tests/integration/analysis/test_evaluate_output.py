"""`tacit eval-compression` says what it read and which error bound it used, and leaves no half-drawn
progress line in a log."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROWS = 400


def evaluate(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tacit.cli", "eval-compression", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.fixture
def csv_file(tmp_path: Path) -> Path:
    """Two channels at 2 Hz; the conductivity cell is blank in every tenth row."""
    path = tmp_path / "ctd.csv"
    lines = ["time,temp_c,cond"]
    for i in range(ROWS):
        cond = "" if i % 10 == 0 else f"{40 + math.cos(i / 30):.4f}"
        lines.append(f"{1700000000 + i / 2:.1f},{12 + math.sin(i / 40):.4f},{cond}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_progress_is_real_counts_on_whole_lines(csv_file: Path) -> None:
    result = evaluate(str(csv_file), "--eps", "0.05", "--json")
    assert result.returncode == 0, result.stderr
    assert (
        "\r" not in result.stderr and ": 0 rows" not in result.stderr
    )  # stderr is a log here, not a terminal
    absent = ROWS // 10
    assert f"read {ROWS} rows of 2 channels: {2 * ROWS - absent} samples, {absent} absent\n" in result.stderr
    report = json.loads(result.stdout)
    assert report["rows"] == ROWS and report["samples"] == 2 * ROWS - absent


def test_the_eps_used_is_in_the_table_and_the_json(csv_file: Path) -> None:
    table = evaluate(str(csv_file), "--eps", "temp_c=0.05,cond=0.2")
    assert table.returncode == 0, table.stderr
    assert "eps (error bound): temp_c=0.05, cond=0.2\n" in table.stdout
    report = json.loads(evaluate(str(csv_file), "--eps", "temp_c=0.05,cond=0.2", "--json").stdout)
    assert report["eps"] == [0.05, 0.2] and report["eps_relative"] is False


def test_relative_eps_is_shown_per_channel(csv_file: Path) -> None:
    report = json.loads(evaluate(str(csv_file), "--eps", "0.5", "--relative", "--json").stdout)
    temp_eps, cond_eps = report["eps"]
    assert report["eps_relative"] is True and temp_eps != cond_eps and 0.2 < temp_eps < 0.5
    table = evaluate(str(csv_file), "--eps", "0.5", "--relative").stdout
    assert f"temp_c={temp_eps:.4g}, cond={cond_eps:.4g} (--eps x each channel's std)" in table
