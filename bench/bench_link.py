"""The link, end to end: simulator, server and agent as separate processes, driven through the REST API.

1. Command latency: time from POSTing a command to its acknowledgement, divided by the channel's own
   minimum for that exchange (cycle-init + data + propagation + turnaround + ACK + propagation, all at
   rate 0), at 100 m, 1 km and 3 km. 1.00 would mean the software adds nothing.
2. Delivery under extra frame loss (0, 10, 30, 50 %): commands acknowledged, commands the vehicle
   executed, duplicates executed (must be 0), mean time to acknowledgement.
3. The square mission: packets per hour the protocol sends versus sending every sample at rate 0, and
   the largest reconstruction error of the environmental stream against what the vehicle measured (its
   own tlog), in units of eps.

Run: .venv/bin/python bench/bench_link.py [--quick]   (about 8 minutes; --quick: about 3)
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from analysis.series import error_ratios, measured_samples
from launch.rig import Rig  # the same process rig the end-to-end test uses
from simulators.acoustics import ChannelParameters, cycle_with_ack_s
from tacit.packets import Stream
from tacit.streams import default_streams


def latency(repeats: int) -> None:
    print("\n1. command latency (POST -> acknowledged), rate 0, quiet channel, real time")
    print("   a) the vehicle silent (nothing to report: the link idle when the command is posted)")
    print(f"{'range':>8} {'channel minimum s':>18} {'measured s (median)':>20} {'ratio':>7}")
    for distance in tqdm((100.0, 1000.0, 3000.0), desc="ranges", leave=False):
        rig = Rig(distance, scale=1.0, agent=False, server={"sync_interval": QUIET})
        times = []
        try:
            for _ in range(repeats):
                time.sleep(idle_after_poll(distance))
                times.append(rig.command({"command": "hold"}, timeout=60)[1])
        finally:
            rig.close()
        floor = cycle_with_ack_s(distance, ChannelParameters())
        median = statistics.median(times)
        print(f"{distance:>7.0f}m {floor:>18.3f} {median:>20.3f} {median / floor:>7.3f}")
    print(
        "   b) the vehicle streaming (the agent answers every poll): a command waits for the exchange under way"
    )
    rig = Rig(1000.0, scale=1.0)
    try:
        times = [rig.command({"command": "hold"}, timeout=60)[1] for _ in range(repeats)]
    finally:
        rig.close()
    floor = cycle_with_ack_s(1000.0, ChannelParameters())
    print(
        f"{1000:>7.0f}m {floor:>18.3f} {statistics.median(times):>20.3f} {statistics.median(times) / floor:>7.3f}"
    )


QUIET = 1e6  # s: no SYNC heartbeat in part a), an exchange a command would wait behind (part b waits)


def idle_after_poll(distance: float) -> float:
    """Long enough for the engine's unanswered poll to time out, so the next POST finds the link idle."""
    return 2 * cycle_with_ack_s(distance, ChannelParameters()) + 3.0


def delivery(commands: int) -> None:
    print(
        "\n2. delivery under extra frame loss (every frame: cycle-init, data, ACK), 300 m, up to 8 attempts"
    )
    print(
        f"{'extra loss':>10} {'acknowledged':>13} {'executed':>9} {'duplicates':>11} {'mean time to ACK s':>19}"
    )
    for loss in tqdm((0.0, 0.1, 0.3, 0.5), desc="loss", leave=False):
        rig = Rig(300.0, scale=10.0, extra_loss=loss, attempts=8)
        try:
            results = [rig.command({"command": "hold"}, timeout=120) for _ in range(commands)]
            time.sleep(3)
            executed = rig.executed_per_seq()
        finally:
            rig.close()
        acked = [t for s, t in results if s != "failed" and not np.isnan(t)]
        duplicates = sum(n - 1 for n in executed.values())
        mean = f"{statistics.mean(acked):.1f}" if acked else "-"
        print(
            f"{loss:>9.0%} {len(acked):>7}/{commands:<5} {len(executed):>5}/{commands:<3} {duplicates:>11} {mean:>19}"
        )


def square_mission(minutes: float) -> None:
    print("\n3. the square mission (20 m, 2 m deep), real time (the codec samples on the wall clock)")
    rig = Rig(300.0, scale=1.0, mission=True)
    try:
        rig.start_square()
        start = time.monotonic()
        for _ in tqdm(range(int(minutes * 60)), desc="mission", unit="s", leave=False):
            time.sleep(1)
        simulated_hours = (time.monotonic() - start) / 3600
        packets = rig.http.get("/packets", params={"limit": 1}).json()["total"]
        env = rig.http.get("/telemetry", params={"stream": "env", "limit": 5000}).json()["items"]
        error = env_error(rig.dir, env)
    finally:
        rig.close()
    streams = default_streams()
    samples_per_s = sum(len(s.channels) / s.period for s in streams.values())  # in simulated time
    every_sample = samples_per_s * 16 / 256 * 3600
    print(f"protocol: {packets / simulated_hours:,.0f} packets/hour (priority + check-point, all streams)")
    print(
        f"sending every sample (16 bits, rate 0): {every_sample:,.0f} packets/hour -> "
        f"{every_sample * 256 / 3600:,.0f} bit/s, {every_sample * 256 / 3600 / 80:.1f}x rate 0's 80 bit/s"
    )
    print(f"environmental stream, largest |reconstruction - measured| / eps where certain: {error:.3f}")


def env_error(folder: Path, rows: list[dict]) -> float:
    """Compare the shore's reconstruction with the vehicle's own tlog, sample by sample."""
    spec = default_streams()[Stream.ENVIRONMENTAL]
    measured = measured_samples(folder / "tlogs", "SCALED_PRESSURE2", ["temperature"], scale=0.01)
    errors = [
        ratio
        for r in rows
        if r["certain"] and (near := measured.near(r["time"], spec.time_precision))
        for ratio in error_ratios(r["values"][:1], near, spec.eps[:1])
    ]
    return max(errors) if errors else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="fewer repeats and a shorter mission")
    parser.add_argument("--only", choices=("latency", "delivery", "mission"), help="run one part")
    options = parser.parse_args()
    quick = options.quick
    if options.only in (None, "latency"):
        latency(2 if quick else 4)
    if options.only in (None, "delivery"):
        delivery(5 if quick else 10)
    if options.only in (None, "mission"):
        square_mission(0.75 if quick else 2.0)


if __name__ == "__main__":
    main()
