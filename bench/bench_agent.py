"""The vehicle agent's cost on its computer: CPU (share of one core) and resident memory of the
``tacit agent`` process while it flies the square mission at its default rates (RAW_IMU at 4 Hz, as in
the paper), in real time, with the simulator and the server beside it as processes.

Read from the kernel (``/proc/PID/stat`` and ``/proc/PID/status``), not sampled by ``ps``. The run
checks it measured a working agent: MAVLink connected, and the shore stored its packets during the
window (else it exits 1).

Run: .venv/bin/python bench/bench_agent.py [--seconds 120]   (Linux)
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from tqdm import tqdm

from launch.rig import Rig


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of ``pid`` so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def resident_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for process {pid}")


def measure(rig: Rig, seconds: int) -> tuple[float, float, int]:
    """(CPU share of one core, peak resident MB, packets the shore stored) over ``seconds``."""
    agent = rig.stack.agent
    assert agent is not None
    before = rig.http.get("/link").json()["ingest"]["packets"]
    cpu0, t0 = cpu_seconds(agent.pid), time.monotonic()
    peak = 0.0
    for _ in tqdm(range(seconds), desc="agent", unit="s"):
        time.sleep(1.0)
        peak = max(peak, resident_mb(agent.pid))
    share = (cpu_seconds(agent.pid) - cpu0) / (time.monotonic() - t0)
    packets = rig.http.get("/link").json()["ingest"]["packets"] - before
    return share, peak, packets


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=int, default=120, help="the measured window (default 120)")
    args = parser.parse_args()
    rig = Rig(300.0, scale=1.0, mission=True)
    try:
        rig.start_square()
        share, peak, packets = measure(rig, args.seconds)
        connected = "MAVLink connected" in rig.stack.log("agent.log")
    finally:
        rig.close()
    print(f"\nagent over {args.seconds} s of the square mission, real time, IMU at 4 Hz")
    print(f"  CPU {100 * share:.1f} % of one core, resident memory {peak:.0f} MB at most")
    print(f"  packets the shore stored meanwhile: {packets}")
    if not connected or packets == 0:
        print("NOT MEASURED: the agent was not connected or sent nothing", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
