"""``python -m launch.stepped_clock FILE ARGS``: ``tacit ARGS`` on a wall clock that can be stepped from
outside, as a system clock steps (an NTP jump, an operator setting the date): ``time.time()`` returns the
true time plus the seconds written in FILE (none or unreadable: 0), re-read at most every 50 ms while
the process runs. Monotonic time, and so every timeout and interval, does not move. The robustness
benchmark steps the shore's and the agent's clocks with it (``Stack.step_clock``).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

REREAD_S = 0.05


def stepped(path: Path, true_time: Callable[[], float] = time.time) -> Callable[[], float]:
    """A ``time.time`` that adds the step written in ``path``."""
    last = {"read": -1.0, "step": 0.0}

    def now() -> float:
        if time.monotonic() - last["read"] > REREAD_S:
            last["read"] = time.monotonic()
            try:
                last["step"] = float(path.read_text() or 0.0)
            except (OSError, ValueError):
                last["step"] = 0.0
        return true_time() + last["step"]

    return now


def main() -> int:
    time.time = stepped(Path(sys.argv[1]))  # before tacit is imported: every module reads time.time
    from tacit.cli import main as tacit

    return tacit(sys.argv[2:])


if __name__ == "__main__":
    sys.exit(main())
