"""bench/bench_fleet.py's model of a fleet on one channel: the real schedule shares the channel among the
vehicles, a command never beats the channel's own minimum, and what a vehicle waits grows with the fleet."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

from simulators.acoustics import cycle_with_ack_s

BENCH = Path(__file__).resolve().parents[3] / "bench" / "bench_fleet.py"


def load_bench():
    spec = importlib.util.spec_from_file_location("bench_fleet", BENCH)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules["bench_fleet"] = module
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def test_the_channel_is_shared_and_a_larger_fleet_waits_longer() -> None:
    bench = load_bench()
    plan = bench.Plan(seconds=480.0, command_every=120.0, imu=False, seed=3)
    one, three = bench.run(1, False, plan), bench.run(3, False, plan)
    for result in (one, three):
        bench.check(result)
        for tally, range_m in zip(result.tallies, result.ranges, strict=True):
            assert tally.to_ack and min(tally.to_ack) >= cycle_with_ack_s(range_m) - 1e-9
            assert tally.samples_delivered > 0 and tally.polls > 0
    shares = [t.airtime / three.seconds for t in three.tallies]
    assert sum(shares) <= 1.0 + 1e-9 and max(shares) < 1.5 * min(shares)  # one channel, shared fairly
    worst = [max(t.surprise_latency) for t in three.tallies]
    assert min(worst) > max(one.tallies[0].surprise_latency)  # each waits for the others' slots
    assert three.idle_share < one.idle_share  # more vehicles answer more of the polls
