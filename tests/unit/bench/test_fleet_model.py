"""bench/bench_fleet.py drives the MAC that ships over a scripted sea: the queue shares the band among the
vehicles, a command never beats the channel's own minimum, what a vehicle waits grows with the fleet, and
two gateways keep their slots (the run checks every exchange)."""

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


def test_the_band_is_shared_and_a_larger_fleet_waits_longer() -> None:
    bench = load_bench()
    plan = bench.Plan(seconds=480.0, command_every=120.0, imu=False, seed=3, window=0, slot=20.0)
    one, three = bench.run(1, 1, plan), bench.run(3, 1, plan)
    for result in (one, three, bench.run(2, 2, plan)):
        bench.check(result)
        for tally, range_m in zip(result.tallies, result.ranges, strict=True):
            assert tally.to_ack and min(tally.to_ack) >= cycle_with_ack_s(range_m) - 1e-9
            assert tally.samples_delivered > 0 and tally.polls > 0
    polls = [t.polls for t in three.tallies]
    assert max(polls) < 1.5 * min(polls)  # one band, shared fairly
    worst = [max(t.surprise_latency) for t in three.tallies]
    assert min(worst) > max(one.tallies[0].surprise_latency)  # each waits for the others' turns
    airtime = three.stations[0].airtime
    assert {"sync", "ping", "poll", "command"} <= set(airtime)  # the MAC's whole traffic, measured
