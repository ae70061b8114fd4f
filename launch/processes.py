"""Child processes (the demo's simulator and agent; test rigs): stopped politely, then firmly."""

from __future__ import annotations

import signal
import subprocess


def stop(proc: subprocess.Popen, grace: float = 10.0) -> None:
    """SIGTERM, wait ``grace`` seconds for a clean exit, then SIGKILL."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=grace)
