"""``tacit demo --gateways N``: what it needs is named in one line when it is missing; the stack's layout
of a split shore (the gateways' modems, addresses and the agents' shore addresses)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from launch import split
from launch.stack import Stack, StackConfig, StackError
from tests.support.nats import free_port


def test_a_missing_broker_and_database_are_named_in_one_line(tmp_path: Path) -> None:
    closed = free_port()
    result = subprocess.run(
        [sys.executable, "-m", "tacit.cli", "demo", "--gateways", "2", "--vehicles", "3", "--headless",
         "--data-dir", str(tmp_path), "--nats", f"nats://127.0.0.1:{closed}", "--broker-dir", str(tmp_path / "broker"),
         "--postgres", f"postgresql+psycopg://postgres@127.0.0.1:{closed}/test"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert f"NATS with JetStream at 127.0.0.1:{closed}" in lines[0]
    assert f"PostgreSQL at 127.0.0.1:{closed}" in lines[0]
    assert list(tmp_path.iterdir()) == []  # nothing started, nothing written


def test_a_split_stack_puts_one_modem_per_gateway_and_tells_the_agents(tmp_path: Path) -> None:
    stack = Stack(StackConfig(tmp_path, range_m=300.0, vehicles=3, gateways=2))
    sim = stack._sim_config()
    shore = [m for m in sim["modems"] if "attach" not in m]
    assert [(m["name"], m["address"], m["position"]) for m in shore] == [
        ("gw1", 1, [0.0, -300.0, 1.0]),
        ("gw2", 101, [0.0, 600.0, 1.0]),
    ]
    assert [m["address"] for m in sim["modems"] if "attach" in m] == [2, 3, 4]
    with pytest.raises(StackError, match="101"):
        StackConfig(tmp_path, vehicles=1, gateways=2, addresses=[101]).members()


def test_the_demos_center_settings_are_kept_for_running_the_center_alone(tmp_path: Path) -> None:
    """What `tacit center --config center.toml` reads back is the demo's own center's settings (its
    slots, time scale, tokens, database and broker), in a file only its owner reads."""
    from server.core.config import Settings

    stack = Stack(StackConfig(tmp_path, vehicles=3, gateways=2, write_tokens=["op"], read_tokens=["obs"]))
    url = "postgresql+psycopg://postgres@127.0.0.1:5432/tacit_demo_0123abcd"
    values = {**split.center_settings(stack, url, 4.0), "port": 8123, "nats_url": "nats://127.0.0.1:4299"}
    path = split.write_center_config(stack, values)
    assert path.stat().st_mode & 0o777 == 0o600
    assert Settings.load(path, env={}) == Settings(**values)
    assert Settings.load(path, env={}).tdma_slot == split.SLOT_S / 4.0
