"""A fleet on one acoustic band through the MAC that ships: how many vehicles one shore, and two gateways
sharing the band in TDMA, carry before a vehicle's data misses its latency bound.

The parts that decide are the real ones: the shore's MAC and queue (``gateway.mac``, ``gateway.queue``:
SYNCs at their stamp, stops and commands first, ranging pings when due, polls by stride scheduling at the
rate ``tacit.link.choose_rate`` picks from the SNR heard, slot discipline), their timings
(``gateway.timing``) and the TDMA slots (``gateway.slots``), each vehicle's agent-side compressor
(``vehicle_agent.compressor``, the agent's default latency and silence bounds) fed a recorded ArduSub dive
(tests/data/ardusub: RAW_IMU and the Bar30, looped, at the demo's stream rates), and the channel's timing,
SNR and frame error rate at each range (``simulators.sea`` over ``simulators.acoustics``). What is
scripted: the modems (no NMEA, no ptys) and the vehicles' answers; time is virtual
(``simulators.virtual_loop``), so the figures measure the channel, not this machine's CPU.

Every vehicle gets a SYNC every ``sync_interval`` (60 s) through its own station, stamped for that
station's next slot opening, and a command every ``--command-every`` s; every station pings and polls
every vehicle (through two gateways, each gateway's polls of the other's vehicles are the scoring polls
the center routes by; a vehicle's own gateway polls it ``OWN_SHARE`` times as often, as the center's
schedule says). A poll at rate r is answered with as many queued packets as rate r carries, up to
``--window`` packets (1: one packet in flight, a vehicle of protocol 3; 0: a vehicle of protocol 4,
whose compressor keeps as many in flight as the last poll's rate carries, up to ``MAX_WINDOW``), each
coded on the chain the previous one leaves.

Per vehicle and run: polls, packets, command POST to modem ACK (median, p95) beside the channel's minimum,
the worst latency of unpredictable samples and the p95 of all, samples waiting at the end. Per station:
the band's airtime by exchange (SYNC, command, ping, poll) and the slots' idle share.

Run: .venv/bin/python bench/bench_fleet.py [--vehicles 1 2 4] [--capacity 8] [--minutes 30]
     [--window 0] [--slot 20] [--plot F]

It fails (exit status 1) if it did not measure what it claims: a vehicle that delivered no samples, more
samples delivered than measured, a delivered sample without its latency, or an exchange of a gateway
outside its own slot.
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import itertools
import math
import random
import statistics
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from gateway.mac import Mac
from gateway.queue import FrameKind, Held, Outcome, Queue, Report
from gateway.slots import Schedule, SlotPlan, guard_for
from gateway.timing import Timing
from server.backhaul.dispatch import OWN_SHARE
from server.backhaul.gateway import PING_INTERVAL
from simulators.acoustics import ChannelParameters, cycle_with_ack_s
from simulators.sea import Band, SeaModem, SeaVehicle
from simulators.virtual_loop import run as run_virtual
from tacit import modem as mm
from tacit import rates
from tacit.codec.format import MAX_WINDOW
from tacit.link import capacity, packets_per_frame
from tacit.packets import NEWEST, PACKET_SIZE, Priority, Stream
from tacit.streams import default_streams
from vehicle_agent.agent import AgentConfig
from vehicle_agent.compressor import Compressor

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "ardusub"
FIRST_RANGE_M = 300.0  # vehicle i sits at FIRST_RANGE_M + (i // stations) * RANGE_STEP_M from its station
RANGE_STEP_M = 250.0
OTHER_EXTRA_M = 1000.0  # through two gateways: a vehicle is this much further from the other one
SEA_PA_PER_M = 1025.0 * 9.80665
T0 = 1_700_000_000.0
SYNC_INTERVAL = 60.0  # s: the shore's default (server.core.config.Settings.sync_interval)


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
    seq: int | None = None  # a data packet's number (the compressor resolves it when heard)


@dataclass
class Tally:
    """What one vehicle got from the channel in a run."""

    polls: int = 0
    packets: int = 0
    samples_delivered: int = 0
    sample_latency: list[float] = field(default_factory=list)
    surprise_latency: list[float] = field(default_factory=list)  # the samples the shore could not predict
    to_ack: list[float] = field(default_factory=list)


class Craft:
    """One vehicle: its agent's compressor and outbox, what it answers a poll, its commands' times."""

    def __init__(self, index: int, station: str, range_m: float, plan: Plan, rng: random.Random) -> None:
        config = AgentConfig()
        self.address = index + 2
        self.station = station  # its own: its SYNCs and commands go through it
        self.range_m = range_m
        self.window = plan.window
        # version 3 keeps one packet in flight; version 4 as many as the last poll's rate carries
        self.compressor = Compressor(
            default_streams(),
            config.max_latency,
            config.max_silence,
            protocol=3 if plan.window == 1 else NEWEST,
        )
        self.seq = 0  # the vehicle's packet counter
        self.outbox: list[Outgoing] = []
        self.in_flight = 0  # compressed packets sent, not yet heard by a shore
        self.next_command = rng.uniform(0.0, plan.command_every)
        self.posted: dict[str, float] = {}  # command id -> when it was posted
        self.tally = Tally()
        self.answers: dict[bytes, list[Outgoing]] = {}  # a frame on the air -> its packets
        self._answer_ids = itertools.count()
        imu_rows, env_rows = recorded_dive()
        offset = rng.randrange(len(imu_rows))  # each vehicle at its own point of the dive
        self._imu = itertools.islice(itertools.cycle(imu_rows), offset, None)
        self._env = itertools.islice(itertools.cycle(env_rows), offset, None)
        self._clock = self._samples(plan.imu)
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
        """The vehicle's side up to ``now`` (s from the start): samples measured, packets queued."""
        while self._next[0] <= now:
            t, stream, values = self._next
            self.compressor.add(stream, t, values)
            self.samples += 1
            self._queue_ready(t)
            self._next = next(self._clock)
        self._queue_ready(now)

    def _queue_ready(self, now: float) -> None:
        """Packets coded while the compressor's window has room, each on the chain the previous one
        leaves (``vehicle_agent.compressor``); one not heard stays queued and goes again."""
        for _, encoded in self.compressor.ready(now, self.seq):
            urgent = encoded.packet.priority is Priority.TIME_SENSITIVE
            packet = Outgoing(urgent, now, encoded.sample_times, encoded.surprise_times, urgent, seq=self.seq)
            self.seq += 1
            self.in_flight += 1
            self.outbox.insert(sum(p.urgent for p in self.outbox) if urgent else len(self.outbox), packet)

    def answer(self, rate: int, nframes: int, now: float) -> list[bytes]:
        """A poll's answer at ``rate``: the first queued packets, as many as the rate carries."""
        self.compressor.follow(min(capacity(rate), self.window or MAX_WINDOW))  # as the agent does
        self.advance(now)
        self.tally.polls += 1
        taken = self.outbox[: capacity(rate)]
        per_frame = packets_per_frame(rate)
        frames = []
        for k in range(0, len(taken), per_frame):
            tag = f"{self.address}:{next(self._answer_ids)}".encode().ljust(
                rates.rate(rate).frame_bytes, b"\0"
            )
            self.answers[tag] = taken[k : k + per_frame]
            frames.append(tag)
        return frames[:nframes]

    def heard(self, tag: bytes, at: float) -> None:
        """A shore heard the frame ``tag`` (a second shore hearing it delivers nothing more)."""
        for packet in self.answers.pop(tag, []):
            if packet not in self.outbox:
                continue
            self.outbox.remove(packet)
            self.tally.packets += 1
            if packet.checkpoint:
                continue
            self.in_flight -= 1
            if packet.seq is not None:
                self.compressor.resolve(packet.seq, True)
            self.tally.samples_delivered += len(packet.sample_times)
            self.tally.sample_latency.extend(at - t for t in packet.sample_times)
            self.tally.surprise_latency.extend(at - t for t in packet.surprise_times)


@dataclass(frozen=True)
class Plan:
    """What every run of one invocation shares."""

    seconds: float
    command_every: float
    imu: bool
    seed: int
    window: int  # packets a poll's answer may carry beyond the rate's limit (0: none)
    slot: float  # s: each gateway's TDMA slot, through two gateways


@dataclass(frozen=True)
class StationResult:
    name: str
    airtime: dict[str, float]  # s, by exchange
    late: int


@dataclass(frozen=True)
class RunResult:
    vehicles: int
    gateways: int
    seconds: float
    tallies: list[Tally]
    samples: list[int]
    ranges: list[float]
    waiting: list[int]  # samples measured, not yet heard on the shore, at the end
    stations: list[StationResult]

    def kept_up(self, bound: float) -> bool:
        """Every vehicle's unpredictable samples reached the shore within ``bound`` (a channel that cannot
        carry the fleet shows as latencies growing with the run's length)."""
        return all(max(t.surprise_latency, default=math.inf) <= bound for t in self.tallies)


def run(vehicles: int, gateways: int, plan: Plan) -> RunResult:
    """One run: ``gateways`` 1 is the single shore (no slots), 2 two gateways sharing the band in TDMA."""
    rng = random.Random(plan.seed)
    names = ["shore"] if gateways == 1 else ["gw1", "gw2"]
    crafts = []
    for i in range(vehicles):
        own = names[i % len(names)]
        crafts.append(Craft(i, own, FIRST_RANGE_M + (i // len(names)) * RANGE_STEP_M, plan, rng))
    band = Band(ChannelParameters(seed=plan.seed))
    by_address = {c.address: c for c in crafts}
    for craft in crafts:
        ranges = {n: craft.range_m + (0.0 if n == craft.station else OTHER_EXTRA_M) for n in names}
        band.add(SeaVehicle(craft.address, ranges, answer=_answerer(craft)))
    schedule = Schedule()
    if gateways > 1:
        schedule.receive(SlotPlan(T0, plan.slot, guard_for(3000.0, 0.05), tuple(names)), T0)
    timing = Timing()
    macs: dict[str, Mac] = {}

    def reporter(report: Report) -> None:
        craft = by_address[report.frame.address]
        if report.final and report.outcome is Outcome.ACKED and report.frame.id in craft.posted:
            now = asyncio.get_running_loop().time() - T0
            craft.tally.to_ack.append(now - craft.posted.pop(report.frame.id))
            craft.outbox.insert(0, Outgoing(urgent=True, queued_at=now, checkpoint=True))  # its report

    for name in names:
        modem = SeaModem(band, name)
        modem.add_listener(_listener(by_address))
        queue = Queue(timing, reporter, PING_INTERVAL)  # as `tacit gateway` runs it
        queue.poll(c.address for c in crafts)  # every station polls every vehicle (scoring, routing)
        for craft in crafts:  # its own gateway more often, as the center's schedule says
            queue.share(craft.address, OWN_SHARE if gateways > 1 and craft.station == name else 1.0)
        macs[name] = Mac(
            name, modem, queue, schedule, timing, clock=lambda: asyncio.get_running_loop().time()
        )

    async def main() -> None:
        tasks = [asyncio.create_task(mac.run()) for mac in macs.values()]
        tasks += [asyncio.create_task(_vehicle(c, macs[c.station], schedule, plan)) for c in crafts]
        await asyncio.sleep(plan.seconds)
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    run_virtual(main(), start=T0)
    for name in names if gateways > 1 else ():
        current = schedule.current
        assert current is not None
        for start, end in macs[name].transmissions:
            if not current.owner(start) == name == current.owner(end - 1e-6):
                sys.exit(
                    f"measured wrongly: an exchange of {name} left its slot ({start - T0:.1f}-{end - T0:.1f} s)"
                )
    return RunResult(
        vehicles, gateways, plan.seconds, [c.tally for c in crafts], [c.samples for c in crafts],
        [c.range_m for c in crafts], [c.samples - c.tally.samples_delivered for c in crafts],
        [StationResult(n, dict(m.status.airtime), m.status.late) for n, m in macs.items()],
    )  # fmt: skip


def _answerer(craft: Craft) -> Callable[[int, int, int], list[bytes]]:
    def answer(address: int, rate: int, nframes: int) -> list[bytes]:
        return craft.answer(rate, nframes, asyncio.get_running_loop().time() - T0)

    return answer


def _listener(crafts: dict[int, Craft]) -> Callable[[mm.Event], None]:
    def heard(event: mm.Event) -> None:
        if isinstance(event, mm.ReceivedFrame) and event.src in crafts:
            crafts[event.src].heard(event.data, event.time - T0)

    return heard


async def _vehicle(craft: Craft, mac: Mac, schedule: Schedule, plan: Plan) -> None:
    """The vehicle's time passing, and what its own station is handed for it: a SYNC every
    ``SYNC_INTERVAL`` stamped for the station's next slot opening, a command every ``--command-every``."""
    loop = asyncio.get_running_loop()
    next_sync, syncs, commands = 0.0, itertools.count(1), itertools.count(1)
    while True:
        now = loop.time() - T0
        craft.advance(now)
        if now >= next_sync:
            next_sync += SYNC_INTERVAL
            stamp = schedule.opening(mac.name, loop.time() + 1.0)
            n = next(syncs)
            mac.queue.hold(
                Held(
                    f"sync-{craft.address}-{n}",
                    craft.address,
                    bytes(32),
                    FrameKind.SYNC,
                    stamp=stamp,
                    attempts=1,
                )
            )
        if now >= craft.next_command:
            craft.next_command += plan.command_every
            command_id = f"cmd-{craft.address}-{next(commands)}"
            craft.posted[command_id] = now
            mac.queue.hold(Held(command_id, craft.address, bytes(32), FrameKind.COMMAND, attempts=3))
            mac.wake()
        await asyncio.sleep(1.0)


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


def where(gateways: int, plan: Plan) -> str:
    return "one shore" if gateways == 1 else f"two gateways, {plan.slot:.0f} s slots"


def table(result: RunResult, plan: Plan) -> None:
    print(
        f"\n{result.vehicles} vehicle(s), {where(result.gateways, plan)}: {result.seconds / 60:.0f} simulated min"
    )
    print(f"{'vehicle':>8} {'range m':>8} {'polls':>6} {'packets':>8} {'POST->ACK s':>12} {'p95':>6} {'min':>5} "
          f"{'surprise worst s':>17} {'all p95 s':>10} {'bits/sample':>12} {'waiting':>8}")  # fmt: skip
    for i, tally in enumerate(result.tallies):
        bits = tally.packets * PACKET_SIZE * 8 / max(1, tally.samples_delivered)
        print(
            f"{'rov' + str(i + 1):>8} {result.ranges[i]:>8.0f} {tally.polls:>6} {tally.packets:>8} "
            f"{statistics.median(tally.to_ack) if tally.to_ack else math.nan:>12.1f} {p(tally.to_ack, 95):>6.1f} "
            f"{cycle_with_ack_s(result.ranges[i]):>5.1f} {max(tally.surprise_latency, default=math.nan):>17.1f} "
            f"{p(tally.sample_latency, 95):>10.1f} {bits:>12.2f} {result.waiting[i]:>8}"
        )  # fmt: skip
    for station in result.stations:
        busy = sum(station.airtime.values())
        parts = ", ".join(
            f"{kind} {100 * s / result.seconds:.1f} %" for kind, s in sorted(station.airtime.items())
        )
        print(
            f"  {station.name}: band held {100 * busy / result.seconds:.1f} % ({parts}); late turns {station.late}"
        )


def capacity_curve(up_to: int, gateways: int, plan: Plan, bound: float) -> list[RunResult]:
    results = []
    for n in range(1, up_to + 1):
        results.append(run(n, gateways, plan))
        check(results[-1])
    print(f"\ncapacity, {where(gateways, plan)} (unpredictable samples heard within {bound:.0f} s):")
    print(f"{'vehicles':>9} {'worst surprise s':>17} {'worst p95 all s':>16} {'kept up':>8}")
    for r in results:
        worst = max((max(t.surprise_latency, default=0.0) for t in r.tallies), default=0.0)
        p95 = max(p(t.sample_latency, 95) for t in r.tallies)
        print(f"{r.vehicles:>9} {worst:>17.1f} {p95:>16.1f} {'yes' if r.kept_up(bound) else 'NO':>8}")
    carried = max((r.vehicles for r in results if r.kept_up(bound)), default=0)
    print(f"{where(gateways, plan)} carries {carried} vehicle(s) at these sensor rates and bounds")
    return results


def plot(path: str, curves: dict[str, list[RunResult]], bound: float, imu: bool) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for label, results in curves.items():
        n = [r.vehicles for r in results]
        worst = [max(max(t.surprise_latency, default=0.0) for t in r.tallies) for r in results]
        ax.plot(n, worst, "o-", label=f"{label}: unpredictable samples, worst")
    ax.axhline(bound, color="grey", linestyle="--", label=f"bound {bound:.0f} s")
    ax.set_xlabel("vehicles on one band")
    ax.set_ylabel("latency, measured to heard (s)")
    ax.set_yscale("log")
    ax.set_title(("RAW_IMU 4 Hz + " if imu else "") + "Bar30 2 Hz per vehicle, the MAC that ships")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    print(f"plot: {path}")


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--vehicles", type=int, nargs="*", default=[1, 2, 4], help="fleet sizes for the tables"
    )
    parser.add_argument(
        "--capacity", type=int, default=6, help="the capacity curves go up to this many vehicles (0: none)"
    )
    parser.add_argument("--minutes", type=float, default=30.0, help="simulated minutes per run")
    parser.add_argument(
        "--command-every", type=float, default=300.0, help="s between each vehicle's commands"
    )
    parser.add_argument("--bound", type=float, default=60.0, help="latency bound of unpredictable samples, s")
    parser.add_argument(
        "--window",
        type=int,
        default=0,
        help="packets a poll's answer carries at most (0: what the rate carries; 1: one packet in flight)",
    )
    parser.add_argument(
        "--slot", type=float, default=20.0, help="each gateway's TDMA slot through two gateways, s"
    )
    parser.add_argument(
        "--gateways",
        type=int,
        nargs="+",
        default=[1, 2],
        choices=(1, 2),
        help="1: one shore; 2: two gateways sharing the band",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--no-imu", action="store_true", help="the vehicles send only the environmental stream (no RAW_IMU)"
    )
    parser.add_argument("--plot", help="save the capacity curves to this PNG")
    args = parser.parse_args()
    plan = Plan(args.minutes * 60.0, args.command_every, not args.no_imu, args.seed, args.window, args.slot)
    print("streams: " + ("RAW_IMU at 4 Hz and " if plan.imu else "") + "the Bar30 at 2 Hz, per vehicle; "
          + (f"at most {plan.window} packet(s) per poll" if plan.window else "a poll brings what its rate carries"))  # fmt: skip
    curves = {}
    for gateways in args.gateways:
        for n in args.vehicles:
            result = run(n, gateways, plan)
            check(result)
            table(result, plan)
        if args.capacity:
            curves[where(gateways, plan)] = capacity_curve(args.capacity, gateways, plan, args.bound)
    if args.plot and curves:
        plot(args.plot, curves, args.bound, plan.imu)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
