"""The shore's one MAC (``gateway.mac`` with ``gateway.queue``) on virtual time over a scripted sea: its
slots, its order of exchanges and what it makes of their outcomes."""

from __future__ import annotations

import asyncio
import contextlib
import random
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from gateway.mac import Mac
from gateway.queue import Exchange, FrameKind, Held, Outcome, Queue, Report
from gateway.slots import Schedule, SlotPlan, guard_for
from gateway.timing import Timing
from simulators.sea import Band, SeaModem, SeaVehicle
from simulators.virtual_loop import run
from tacit import modem as mm

T0 = 1_700_000_000.0
TIMING = Timing()


@dataclass
class Station:
    """One shore station: its modem on the band, its queue, its MAC and what it reported."""

    name: str
    band: Band
    schedule: Schedule
    reports: list[Report] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.modem = SeaModem(self.band, self.name)
        self.queue = Queue(TIMING, self.reports.append)
        self.mac = Mac(self.name, self.modem, self.queue, self.schedule, TIMING, clock=_clock)

    def ends(self, outcome: Outcome) -> dict[str, float]:
        """The frames that ended so, by id (when: the report's order only)."""
        return {r.frame.id: i for i, r in enumerate(self.reports) if r.final and r.outcome is outcome}


def _clock() -> float:
    return asyncio.get_running_loop().time()


def sea(*vehicles: SeaVehicle) -> Band:
    band = Band()
    for vehicle in vehicles:
        band.add(vehicle)
    return band


def plan(*order: str, slot: float = 20.0, guard: float = 1.0) -> Schedule:
    schedule = Schedule()
    schedule.receive(SlotPlan(T0, slot, guard, order), T0)
    return schedule


def frame(id: str, address: int, kind: FrameKind = FrameKind.COMMAND, **extra: float) -> Held:
    return Held(id, address, id.encode().ljust(32, b"\0"), kind, **extra)  # type: ignore[arg-type]


def running(
    stations: list[Station], seconds: float, then: Callable[[], Awaitable[None]] | None = None
) -> None:
    """Run ``then``, then the stations' MACs for ``seconds`` of virtual time."""

    async def main() -> None:
        if then is not None:
            await then()
        tasks = [asyncio.create_task(s.mac.run()) for s in stations]
        await asyncio.sleep(seconds)
        for task in tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    run(main(), start=T0)


def test_two_stations_on_one_band_keep_their_slots() -> None:
    """Commands, polls at the fastest rates and pings from two stations for half an hour: no exchange of
    one overlaps the other's, each starts and ends inside its own slot before the guard."""
    band = sea(
        SeaVehicle(2, {"ship": 300.0, "buoy": 1500.0}),
        SeaVehicle(3, {"ship": 1500.0, "buoy": 550.0}),
        SeaVehicle(4, {"ship": 900.0, "buoy": 900.0}, silent=True),
    )
    schedule = plan("ship", "buoy")
    ship, buoy = Station("ship", band, schedule), Station("buoy", band, schedule)
    ship.queue.poll([2, 4])
    buoy.queue.poll([3])
    for n in range(20):
        ship.queue.hold(frame(f"cmd-{n}", 2))
        buoy.queue.hold(frame(f"cmd-{n}", 3, FrameKind.STOP if n % 3 == 0 else FrameKind.COMMAND))
    running([ship, buoy], 1800.0)
    current = schedule.current
    assert current is not None
    assert band.overlaps() == 0
    for station in (ship, buoy):
        assert len(station.mac.transmissions) > 50
        for start, end in station.mac.transmissions:
            assert current.owner(start) == station.name == current.owner(end)
            assert current.room(station.name, start) >= end - start
        assert len(station.ends(Outcome.ACKED)) == 20
    assert ship.mac.status.exchanges[Exchange.PING] >= 2 and ship.queue.vehicle(2).range_m == 300.0
    seen = ship.mac.detail()["vehicles"]  # what its heartbeat says, per vehicle at this gateway
    assert seen["2"]["range_m"] == 300.0 and seen["2"]["rate"] == 5 and seen["4"]["range_m"] is None


def test_a_late_turn_waits_for_the_next_slot() -> None:
    """A station that wakes with less of its slot left than the exchange takes sends nothing then, and
    the frame goes at the next slot."""
    band = sea(SeaVehicle(2, {"ship": 500.0}))
    station = Station("ship", band, plan("ship", "buoy"))
    station.queue.hold(frame("cmd-1", 2))

    async def late() -> None:
        turn = station.queue.next(T0 + 1.0, 18.0)
        assert turn is not None and turn.exchange is Exchange.COMMAND
        await asyncio.sleep(18.0 - turn.duration / 2)  # stalled: half the exchange would cross the guard
        await station.mac.turn(turn)
        assert station.mac.status.late == 1 and not station.mac.transmissions
        assert not band.vehicles[2].received

    running([station], 60.0, then=late)
    assert station.mac.transmissions and station.mac.transmissions[0][0] >= T0 + 40.0
    assert station.ends(Outcome.ACKED) == {"cmd-1": 1}


def test_a_slot_too_short_for_one_exchange_is_refused() -> None:
    band = sea(SeaVehicle(2, {"ship": 500.0}))
    station = Station("ship", band, plan("ship", "buoy", slot=6.0, guard=1.0))
    station.queue.hold(frame("cmd-1", 2))
    station.queue.poll([2])
    running([station], 120.0)
    assert not station.mac.transmissions and not band.busy
    assert "one exchange at rate 0 needs" in station.mac.status.refused


def test_fleet_stops_first_a_silent_vehicle_holds_no_other_stop_back() -> None:
    """Five vehicles' aborts, the first to a silent vehicle, with commands and polls waiting too: no stop
    is tried again before every stop's first attempt, and the k-th vehicle's abort is acknowledged within
    k of the station's slots."""
    vehicles = [SeaVehicle(a, {"ship": 400.0 + 100 * a}, silent=a == 1) for a in range(1, 6)]
    station = Station("ship", sea(*vehicles), plan("ship", "buoy", slot=10.0, guard=1.0))
    acked_in: dict[str, int] = {}  # abort -> the station's own slot (1: its first) that carried its ACK

    def note(report: Report) -> None:
        station.reports.append(report)
        if report.outcome is Outcome.ACKED and not report.final:
            acked_in[report.frame.id] = int((_clock() - T0) // 10.0) // 2 + 1

    station.queue.reporter = note
    station.queue.poll(range(1, 6))
    for a in range(1, 6):
        station.queue.hold(frame(f"move-{a}", a))
    for a in range(1, 6):
        station.queue.hold(frame(f"abort-{a}", a, FrameKind.STOP))
    running([station], 300.0)
    stops = [r for r in station.reports if not r.final and r.frame.kind is FrameKind.STOP]
    assert [(r.frame.id, r.attempt) for r in stops[:5]] == [(f"abort-{a}", 1) for a in range(1, 6)]
    for k in range(2, 6):
        assert acked_in[f"abort-{k}"] <= k
    assert "abort-1" in station.ends(Outcome.FAILED) and "abort-1" not in acked_in
    assert set(station.ends(Outcome.ACKED)) >= {f"move-{a}" for a in range(2, 6)}


def test_a_sync_goes_in_the_slot_it_is_stamped_for_and_an_old_one_expires() -> None:
    band = sea(SeaVehicle(2, {"ship": 500.0}))
    station = Station("ship", band, plan("ship"))
    station.queue.poll([2])
    station.queue.hold(frame("sync-2-1", 2, FrameKind.SYNC, stamp=T0 + 61.0))
    station.queue.hold(frame("sync-3-1", 3, FrameKind.SYNC, stamp=T0 - 10.0))
    running([station], 120.0)
    received = band.vehicles[2].received
    sent = [at for at, data in received if data.startswith(b"sync-2-1")]
    assert len(sent) == 1 and T0 + 59.0 <= sent[0] - TIMING.command(500.0) <= T0 + 63.0
    assert "sync-3-1" in station.ends(Outcome.EXPIRED)


def test_a_poll_goes_at_the_rate_the_snr_allows_and_brings_every_frame_of_it() -> None:
    """A vehicle at 300 m: once heard at rate 0, it is polled at rate 5 and one poll brings eight frames."""
    heard: list[int] = []
    band = sea(SeaVehicle(2, {"ship": 300.0}))
    station = Station("ship", band, plan("ship"))
    station.modem.add_listener(lambda event: heard.append(getattr(event, "frame", 0)))
    station.queue.poll([2])
    running([station], 60.0)
    snr = station.queue.vehicle(2).recent_snr
    assert snr is not None and snr > 20.0
    assert heard.count(8) >= 2  # the eighth frame of several rate-5 answers


def test_a_withdrawn_frame_goes_no_more_and_one_withdrawn_before_it_came_is_refused() -> None:
    band = sea(SeaVehicle(2, {"ship": 500.0}, silent=True))
    station = Station("ship", band, plan("ship", "buoy", slot=10.0))
    station.queue.hold(frame("cmd-1", 2))
    station.queue.withdraw("cmd-2")

    async def withdraw() -> None:
        await asyncio.sleep(15.0)  # one attempt made (the vehicle is silent: no ACK)
        assert station.queue.withdraw("cmd-1")

    async def both() -> None:
        asyncio.get_running_loop().create_task(withdraw())

    running([station], 120.0, then=both)
    assert len(station.mac.transmissions) == 1
    assert station.ends(Outcome.WITHDRAWN) == {"cmd-1": 1}
    assert not station.queue.hold(frame("cmd-2", 2))
    assert "cmd-2" in station.ends(Outcome.WITHDRAWN)


def test_shares_weigh_the_polls_and_commands_never_starve_a_vehicle_of_them() -> None:
    band = sea(SeaVehicle(2, {"ship": 600.0}), SeaVehicle(3, {"ship": 600.0}, silent=True))
    station = Station("ship", band, plan("ship"))
    station.queue.poll([2, 3])
    station.queue.share(2, 2.0)
    for n in range(200):
        station.queue.hold(frame(f"cmd-{n}", 3, attempts=100))
    running([station], 900.0)
    polls = {a: station.queue.vehicle(a).polls for a in (2, 3)}
    assert polls[3] > 10  # its endless commands leave it polled
    assert 1.6 <= polls[2] / polls[3] <= 2.4
    assert 10 <= station.mac.status.exchanges[Exchange.PING] <= 8 + 4  # every 120 s, every 240 s (not 16)


def test_a_turn_is_the_first_in_order_that_fits_the_room() -> None:
    """Commands before polls; a poll too long at its rate for the room left goes slower if that fits,
    and nothing goes when nothing fits."""
    queue = Queue(TIMING, lambda report: None)
    queue.poll([2])
    queue.heard(2, 16.0)  # rate 1's SNR
    queue.vehicle(2).last_ping = T0  # its range is fresh: no ping due
    queue.hold(frame("cmd-1", 2))
    first = queue.next(T0, 100.0)
    assert first is not None and first.exchange is Exchange.COMMAND
    assert queue.next(T0, TIMING.command(None) - 0.01) is None  # neither the command nor a poll fits
    queue.withdraw("cmd-1")
    poll = queue.next(T0, 100.0)
    assert poll is not None and poll.exchange is Exchange.POLL and poll.rate == 1
    slower = queue.next(T0, TIMING.poll(None, 1) - 0.01)
    assert slower is not None and slower.rate == 0 and slower.duration == TIMING.poll(None, 0)


class Stalling:
    """A station's process that stalls (as under SIGSTOP or a CPU hog) for up to ``most`` s at random
    points: between its MAC's last look at the clock and its modem getting the command."""

    def __init__(self, modem: SeaModem, rng: random.Random, most: float) -> None:
        self.modem, self.rng, self.most = modem, rng, most

    @property
    def state(self) -> mm.LinkState:
        return self.modem.state

    def add_listener(self, listener: Callable[[mm.Event], None]) -> None:
        self.modem.add_listener(listener)

    async def _stall(self) -> None:
        if self.rng.random() < 0.5:
            await asyncio.sleep(self.rng.uniform(0.0, self.most))

    async def send(
        self,
        dest: int,
        frames: list[bytes],
        rate: int = 0,
        ack: bool = True,
        ack_timeout: float | None = None,
    ) -> mm.TransmitResult:
        await self._stall()
        return await self.modem.send(dest, frames, rate, ack, ack_timeout)

    async def poll(self, remote: int, rate: int = 0, ack: bool = False) -> None:
        await self._stall()
        await self.modem.poll(remote, rate, ack)

    async def ping(self, dest: int, timeout: float = 10.0) -> float | None:
        await self._stall()
        return await self.modem.ping(dest, timeout)


def stalled_runs(guard: float, runs: int, most: float = 1.0) -> list[str]:
    """Two stations on one band, each stalling up to ``most`` s at random, for ten minutes per run: every
    exchange on the band that left its station's own slot."""
    crossed = []
    for seed in range(runs):
        band = sea(
            SeaVehicle(2, {"ship": 400.0, "buoy": 1400.0}), SeaVehicle(3, {"ship": 1400.0, "buoy": 700.0})
        )
        schedule = plan("ship", "buoy", slot=20.0, guard=guard)
        stations = []
        for name, near in (("ship", 2), ("buoy", 3)):
            queue = Queue(TIMING, lambda report: None)
            modem = Stalling(SeaModem(band, name), random.Random(seed * 2 + near), most)
            stations.append(Mac(name, modem, queue, schedule, TIMING, clock=_clock))
            queue.poll([2, 3])
            for n in range(10):
                queue.hold(frame(f"cmd-{n}", near))

        run(_for(600.0, stations), start=T0)
        current = schedule.current
        assert current is not None and len(band.busy) > 40
        crossed += [
            f"run {seed}: {who} {start - T0:.2f}-{end - T0:.2f} s"
            for who, start, end in band.busy
            if not current.owner(start) == who == current.owner(end)
        ]
    return crossed


def test_two_stations_stalling_up_to_a_second_never_cross_a_slot_boundary() -> None:
    """20 runs; the guard covers the travel across 3 km and the stall. The control, stalls far longer
    than the guard, crosses (the check works)."""
    assert stalled_runs(guard_for(3000.0, 0.05) + 1.0, runs=20) == []
    assert stalled_runs(0.05, runs=3, most=4.0)


async def _for(seconds: float, macs: list[Mac]) -> None:
    tasks = [asyncio.create_task(mac.run()) for mac in macs]
    await asyncio.sleep(seconds)
    for task in tasks:
        task.cancel()
