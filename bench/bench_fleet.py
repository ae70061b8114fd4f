"""A fleet on one acoustic channel, modelled slot by slot: what each vehicle costs the others, and how many
vehicles one channel carries before a vehicle's data misses its latency bound.

The parts that decide are the real ones: the shore's schedule (``server.link.schedule``: stride
scheduling, commands first, urgent vehicles sooner), its rate choice (``tacit.link.choose_rate``) and
slot windows (``server.link.timing``), the channel's timing, SNR and frame error rate at each vehicle's
range (``simulators.acoustics``, ``tacit.rates``), and each vehicle's agent-side compressor
(``vehicle_agent.compressor``, the agent's default latency and silence bounds) fed a recorded ArduSub dive
(tests/data/ardusub: RAW_IMU and the Bar30, looped, at the demo's stream rates). What is scripted: the
modems (no NMEA, no ptys) and the vehicle's motion; time is simulated, so the figures measure the
channel, not this machine's CPU.

Per vehicle and run: airtime share; polls; command POST to modem ACK and to the check-point that reports
it (one command per vehicle every ``--command-every`` s), beside the channel's minimum for each; the
worst latency of time-sensitive samples (measured to heard on the shore) and of all samples; bits on the
link per sample. Per run: the share of the channel left idle (polls nobody answered).

Run: .venv/bin/python bench/bench_fleet.py [--vehicles 1 2 3 4] [--capacity 8] [--minutes 30] [--plot F]

It fails (exit status 1) if it did not measure what it claims: a vehicle that delivered no samples, more
samples delivered than measured, or a delivered sample without its latency.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import math
import random
import statistics
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from server.core.config import Settings
from server.link.schedule import Schedule, SlotReason, Wants
from server.link.state import VehicleState
from server.link.timing import Timing
from simulators.acoustics import ChannelParameters, cycle_with_ack_s, frame_error_rate
from tacit import rates
from tacit.codec import PacketDecoder
from tacit.link import capacity, choose_rate, packets_per_frame
from tacit.packets import PACKET_SIZE, Priority, Stream
from tacit.streams import default_streams
from vehicle_agent.agent import AgentConfig
from vehicle_agent.compressor import Compressor

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "ardusub"
FIRST_RANGE_M = 300.0  # vehicle i sits at FIRST_RANGE_M + i * RANGE_STEP_M from the shore modem
RANGE_STEP_M = 250.0
SEA_PA_PER_M = 1025.0 * 9.80665


def recorded_dive() -> tuple[list[list[float | None]], list[list[float | None]]]:
    """The small dive's RAW_IMU rows and (temperature, depth, oxygen) rows, in recorded order."""
    with (DATA / "small_raw_imu.csv").open() as f:
        imu: list[list[float | None]] = [
            [
                float(row[c])
                for c in ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag")
            ]
            for row in csv.DictReader(f)
        ]
    with (DATA / "small_bar30.csv").open() as f:
        rows = list(csv.DictReader(f))
    surface = float(rows[0]["press_abs_hPa"])
    env: list[list[float | None]] = [
        [
            float(row["temperature_cdegC"]) / 100.0,
            max(0.0, (float(row["press_abs_hPa"]) - surface) * 100.0 / SEA_PA_PER_M),
            None,  # the dive had no oxygen sensor: coded as absent
        ]
        for row in rows
    ]
    return imu, env


@dataclass
class Outgoing:
    """A packet waiting on the vehicle for a poll: a check-point or a data packet (its samples' times)."""

    urgent: bool
    queued_at: float
    sample_times: list[float] = field(default_factory=list)
    surprise_times: list[float] = field(default_factory=list)
    time_sensitive: bool = False
    checkpoint: bool = False


@dataclass
class Tally:
    """What one vehicle got from the channel in a run."""

    airtime: float = 0.0
    polls: int = 0
    packets: int = 0
    samples_delivered: int = 0
    sample_latency: list[float] = field(default_factory=list)
    surprise_latency: list[float] = field(default_factory=list)  # the samples the shore could not predict
    urgent_latency: list[float] = field(default_factory=list)  # of those, in time-sensitive packets
    to_ack: list[float] = field(default_factory=list)
    to_report: list[float] = field(default_factory=list)


class Craft:
    """One vehicle as the channel sees it: its agent's compressor and outbox, the shore's record of it."""

    def __init__(
        self, index: int, config: AgentConfig, command_every: float, with_imu: bool, rng: random.Random
    ) -> None:
        self.range_m = FIRST_RANGE_M + index * RANGE_STEP_M
        self.record = VehicleState(
            id=index + 1, name=f"rov{index + 1}", address=index + 2,
            decoder=PacketDecoder(list(default_streams().values())), range_m=self.range_m,
        )  # fmt: skip
        # version 3: one packet in flight, as this model of the link sends them
        self.compressor = Compressor(default_streams(), config.max_latency, config.max_silence, protocol=3)
        self.seq = 0  # the vehicle's packet counter
        self.checkpoint_every = config.checkpoint_interval
        self.command_every = command_every
        self.outbox: list[Outgoing] = []
        self.in_flight: Outgoing | None = None  # the compressor's packet, until its delivery is known
        self.next_checkpoint = config.checkpoint_interval
        self.next_command = rng.uniform(0.0, command_every)
        self.command_posted: float | None = None  # waiting for its slot
        self.command_acked: float | None = None  # ACKed, waiting for the check-point that reports it
        self.tally = Tally()
        imu_rows, env_rows = recorded_dive()
        offset = rng.randrange(len(imu_rows))  # each vehicle at its own point of the dive
        self._imu = itertools.islice(itertools.cycle(imu_rows), offset, None)
        self._env = itertools.islice(itertools.cycle(env_rows), offset, None)
        self._clock = self._samples(with_imu)
        self._next = next(self._clock)
        self.samples = 0

    def _samples(self, imu: bool) -> Iterator[tuple[float, Stream, list[float | None]]]:
        """The dive's samples at the streams' periods, in time order (without the IMU's if not ``imu``)."""
        streams = default_streams()
        imu_period = streams[Stream.KINEMATIC].period
        env_period = streams[Stream.ENVIRONMENTAL].period
        for k in itertools.count():
            t = k * imu_period
            if imu:
                yield t, Stream.KINEMATIC, next(self._imu)
            if (t / env_period).is_integer():
                yield t, Stream.ENVIRONMENTAL, next(self._env)

    def advance(self, now: float) -> None:
        """The vehicle's side up to ``now``: samples measured, packets and check-points queued, commands
        posted on the shore."""
        while self._next[0] <= now:
            t, stream, values = self._next
            self.compressor.add(stream, t, values)
            self.samples += 1
            self._queue_ready(t)
            self._next = next(self._clock)
        self._queue_ready(now)
        if now >= self.next_checkpoint:
            self.next_checkpoint += self.checkpoint_every
            self.outbox.insert(0, Outgoing(urgent=True, queued_at=now, checkpoint=True))
        if now >= self.next_command and self.command_posted is None and self.command_acked is None:
            self.command_posted = self.next_command  # mid-slot: it waits for the slot under way to end
            self.next_command += self.command_every

    def _queue_ready(self, now: float) -> None:
        if self.in_flight is not None:
            return
        for _, encoded in self.compressor.ready(now, self.seq):
            self.seq += 1
            urgent = encoded.packet.priority is Priority.TIME_SENSITIVE
            packet = Outgoing(urgent, now, encoded.sample_times, encoded.surprise_times, urgent)
            self.in_flight = packet
            self.outbox.insert(sum(p.urgent for p in self.outbox) if urgent else len(self.outbox), packet)

    def wants(self) -> Wants:
        return Wants(command=self.command_posted is not None, in_flight=self.command_acked is not None)

    def delivered(self, packet: Outgoing, at: float) -> None:
        self.outbox.remove(packet)
        self.tally.packets += 1
        if packet.checkpoint:
            if self.command_acked is not None:  # the check-point reports the command it holds
                self.tally.to_report.append(at - self.command_acked)
                self.command_acked = None
            return
        self.compressor.resolve(self.seq - 1, True)
        self.in_flight = None
        self.tally.samples_delivered += len(packet.sample_times)
        self.tally.sample_latency.extend(at - t for t in packet.sample_times)
        self.tally.surprise_latency.extend(at - t for t in packet.surprise_times)
        if packet.time_sensitive:
            self.tally.urgent_latency.extend(at - t for t in packet.surprise_times)
        self.record.urgent = self.record.urgent or packet.time_sensitive


class Channel:
    """The shore's modem and the water between: slot after slot, the schedule's first vehicle."""

    def __init__(self, crafts: list[Craft], bulk: bool, rng: random.Random) -> None:
        self.crafts = {c.record.address: c for c in crafts}
        self.bulk = bulk
        self.rng = rng
        self.params = ChannelParameters()
        self.settings = Settings()
        self.timing = Timing(self.settings)
        self.schedule = Schedule(self.settings.command_share)
        self.now = 0.0
        self.idle = 0.0

    def run(self, seconds: float) -> None:
        """Slots until ``seconds``; a whole round in which nobody answered ends in the engine's idle pause."""
        quiet = 0
        while self.now < seconds:
            for craft in self.crafts.values():
                craft.advance(self.now)
            wants = {a: (c.record, c.wants()) for a, c in self.crafts.items()}
            record, reason = self.schedule.order(wants)[0]
            craft = self.crafts[record.address]
            start, idle = self.now, self.idle
            self.now += self._command(craft) if reason is SlotReason.COMMAND else self._poll(craft)
            self.schedule.used(record, reason)
            craft.tally.airtime += self.now - start
            quiet = quiet + 1 if self.idle > idle else 0
            if quiet >= len(self.crafts):
                quiet = 0
                self.now += self.timing.idle_wait()
                self.idle += self.timing.idle_wait()

    def _heard(self, craft: Craft, rate: int) -> bool:
        snr = self.params.mean_snr_db(craft.range_m) + self.rng.gauss(0.0, self.params.fading_sigma_db)
        return self.rng.random() >= frame_error_rate(snr, rate, self.params.fer_width_db)

    def _command(self, craft: Craft) -> float:
        """A rate-0 command with ACK: cycle-init, data and ACK must all be heard."""
        duration = cycle_with_ack_s(craft.range_m, self.params)
        if all(self._heard(craft, 0) for _ in range(3)):
            assert craft.command_posted is not None
            craft.tally.to_ack.append(self.now + duration - craft.command_posted)
            craft.command_posted, craft.command_acked = None, self.now + duration
            craft.outbox.insert(0, Outgoing(urgent=True, queued_at=self.now, checkpoint=True))  # its report
            return duration
        return self.timing.ack_timeout(craft.record)

    def _rate(self, craft: Craft) -> int:
        return choose_rate(self.params.mean_snr_db(craft.range_m), False, 4) if self.bulk else 0

    def _poll(self, craft: Craft) -> float:
        """A poll: the vehicle answers with what it has, urgent first, as many packets as the rate carries;
        each frame is heard (and ACKed) or not. Nobody answering costs the whole poll window."""
        craft.tally.polls += 1
        rate = self._rate(craft)
        window = self.timing.poll_window(craft.record, rate)
        answer = craft.outbox[: capacity(rate)]
        if not answer or not self._heard(craft, 0):  # nothing to send, or the poll's cycle-init was lost
            self.idle += window
            return window
        per_frame = packets_per_frame(rate)
        frames = math.ceil(len(answer) / per_frame)
        delay = craft.range_m / self.params.sound_speed
        init = rates.airtime_s(rates.CYCLE_INIT_BITS, 0)
        data = rates.data_airtime_s(rate, frames)
        acks = rates.airtime_s(rates.ACK_BITS, 0)
        duration = init + 2 * delay + rates.TURNAROUND_S + data + 2 * rates.TURNAROUND_S + acks + delay
        heard_at = self.now + init + 2 * delay + rates.TURNAROUND_S + data
        for k in range(frames):
            if self._heard(craft, rate):
                for packet in answer[k * per_frame : (k + 1) * per_frame]:
                    craft.delivered(packet, heard_at)
        return duration


@dataclass(frozen=True)
class RunResult:
    vehicles: int
    bulk: bool
    seconds: float
    idle_share: float
    tallies: list[Tally]
    samples: list[int]
    ranges: list[float]
    waiting: list[int]  # samples measured, not yet heard on the shore, at the end

    def kept_up(self, bound: float) -> bool:
        """Every vehicle's unpredictable samples reached the shore within ``bound`` (a channel that cannot
        carry the fleet shows as latencies growing with the run's length)."""
        return all(max(t.surprise_latency, default=0.0) <= bound for t in self.tallies)


@dataclass(frozen=True)
class Plan:
    """What every run of one invocation shares."""

    seconds: float
    command_every: float
    imu: bool
    seed: int


def run(vehicles: int, bulk: bool, plan: Plan) -> RunResult:
    rng = random.Random(plan.seed)
    config = AgentConfig()
    crafts = [Craft(i, config, plan.command_every, plan.imu, rng) for i in range(vehicles)]
    channel = Channel(crafts, bulk, rng)
    channel.run(plan.seconds)
    return RunResult(
        vehicles, bulk, channel.now, channel.idle / channel.now, [c.tally for c in crafts],
        [c.samples for c in crafts], [c.range_m for c in crafts],
        [c.samples - c.tally.samples_delivered for c in crafts],
    )  # fmt: skip


def check(result: RunResult) -> None:
    """The run measured what it claims: every vehicle delivered samples, never more than it measured, each
    with its latency."""
    for tally, measured in zip(result.tallies, result.samples, strict=True):
        if not tally.samples_delivered:
            sys.exit("measured nothing: a vehicle delivered no samples")
        if tally.samples_delivered > measured:
            sys.exit(f"measured wrongly: {tally.samples_delivered} samples delivered of {measured} measured")
        if len(tally.sample_latency) != tally.samples_delivered or min(tally.sample_latency, default=0) < 0:
            sys.exit("measured wrongly: a sample's latency is missing or negative")


def p(values: list[float], q: int) -> float:
    """The ``q``-th percentile (NaN for none)."""
    if not values:
        return float("nan")
    return statistics.quantiles(values, n=100, method="inclusive")[q - 1] if len(values) > 1 else values[0]


def table(result: RunResult) -> None:
    mode = "rates the SNR allows" if result.bulk else "rate 0 only"
    print(f"\n{result.vehicles} vehicle(s), {mode}: {result.seconds / 60:.0f} simulated min, "
          f"channel idle {100 * result.idle_share:.1f} %")  # fmt: skip
    print(f"{'vehicle':>8} {'range m':>8} {'airtime':>8} {'polls':>6} {'POST->ACK s':>12} {'min':>5} "
          f"{'->reported s':>13} {'surprise worst s':>17} {'urgent worst s':>15} {'all p95 s':>10} {'bits/sample':>12} {'waiting':>8}")  # fmt: skip
    for i, tally in enumerate(result.tallies):
        floor = cycle_with_ack_s(result.ranges[i])
        bits = tally.packets * PACKET_SIZE * 8 / max(1, tally.samples_delivered)
        print(
            f"{'rov' + str(i + 1):>8} {result.ranges[i]:>8.0f} {100 * tally.airtime / result.seconds:>7.1f}% "
            f"{tally.polls:>6} {statistics.median(tally.to_ack) if tally.to_ack else math.nan:>12.1f} "
            f"{floor:>5.1f} {statistics.median(tally.to_report) if tally.to_report else math.nan:>13.1f} "
            f"{max(tally.surprise_latency, default=math.nan):>17.1f} "
            f"{max(tally.urgent_latency, default=math.nan):>15.1f} {p(tally.sample_latency, 95):>10.1f} "
            f"{bits:>12.2f} {result.waiting[i]:>8}"
        )


def capacity_curve(up_to: int, plan: Plan, bound: float) -> list[RunResult]:
    results = []
    for n in tqdm(range(1, up_to + 1), desc="capacity", leave=False):
        results.append(run(n, True, plan))
        check(results[-1])
    print(f"\ncapacity (rates the SNR allows; unpredictable samples heard within {bound:.0f} s):")
    print(f"{'vehicles':>9} {'idle %':>7} {'worst surprise s':>17} {'worst p95 all s':>16} {'kept up':>8}")
    for r in results:
        worst = max((max(t.surprise_latency, default=0.0) for t in r.tallies), default=0.0)
        p95 = max(p(t.sample_latency, 95) for t in r.tallies)
        print(f"{r.vehicles:>9} {100 * r.idle_share:>7.1f} {worst:>17.1f} {p95:>16.1f} {'yes' if r.kept_up(bound) else 'NO':>8}")  # fmt: skip
    carried = max((r.vehicles for r in results if r.kept_up(bound)), default=0)
    print(f"one channel carries {carried} vehicle(s) at these sensor rates and bounds")
    return results


def plot(path: str, results: list[RunResult], bound: float, imu: bool) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r.vehicles for r in results]
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(
        n,
        [max(p(t.sample_latency, 95) for t in r.tallies) for r in results],
        "o-",
        label="all samples, worst p95",
    )
    ax.plot(n, [max(max(t.surprise_latency, default=0.0) for t in r.tallies) for r in results], "s-", label="unpredictable samples, worst")  # fmt: skip
    ax.axhline(bound, color="grey", linestyle="--", label=f"bound {bound:.0f} s")
    ax.set_xlabel("vehicles on one channel")
    ax.set_ylabel("latency, measured to heard (s)")
    ax.set_yscale("log")
    ax.set_title(("RAW_IMU 4 Hz + " if imu else "") + "Bar30 2 Hz per vehicle, rates the SNR allows")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    print(f"plot: {path}")


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--vehicles", type=int, nargs="+", default=[1, 2, 3, 4], help="fleet sizes for the tables"
    )
    parser.add_argument(
        "--capacity", type=int, default=8, help="the capacity curve goes up to this many vehicles (0: none)"
    )
    parser.add_argument("--minutes", type=float, default=30.0, help="simulated minutes per run")
    parser.add_argument(
        "--command-every", type=float, default=300.0, help="s between each vehicle's commands"
    )
    parser.add_argument("--bound", type=float, default=60.0, help="latency bound of unpredictable samples, s")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--no-imu", action="store_true", help="the vehicles send only the environmental stream (no RAW_IMU)"
    )
    parser.add_argument("--plot", help="save the capacity curve to this PNG")
    args = parser.parse_args()
    plan = Plan(args.minutes * 60.0, args.command_every, not args.no_imu, args.seed)
    print("streams: " + ("RAW_IMU at 4 Hz and " if plan.imu else "") + "the Bar30 at 2 Hz, per vehicle")
    for bulk in (False, True):
        for n in args.vehicles:
            result = run(n, bulk, plan)
            check(result)
            table(result)
    if args.capacity:
        results = capacity_curve(args.capacity, plan, args.bound)
        if args.plot:
            plot(args.plot, results, args.bound, plan.imu)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
