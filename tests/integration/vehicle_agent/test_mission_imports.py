"""Algorithm 2 is plain logic: importing the mission state machine in a fresh interpreter imports no pymavlink."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def test_the_mission_state_machine_needs_no_mavlink() -> None:
    """Algorithm 2 is plain logic: importing it must not import pymavlink (tested without I/O)."""
    code = "import sys, vehicle_agent.mission; print('pymavlink' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.strip() == "False"
