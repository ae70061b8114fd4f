"""The MAC's queue: what goes in this slot, and for whom; it hears each exchange's outcome.

What the shore holds for the vehicles (frames the center signed: SYNCs, stops, commands) and whom it polls,
in this order at each turn the MAC asks for (``Queue.next``), the first that fits the room left in the slot:

1. a **SYNC** in the slot it is stamped for: its time sets the vehicle's clock, so it goes only within
   ``SYNC_WINDOW`` of its stamp (a vehicle's newest replaces one still waiting; one past its window is
   reported expired: the center signs another);
2. **stops** (abort, hold), before any other command: the fewest attempts made first, so no vehicle's stop
   is tried again before every held stop has had its first attempt (a silent vehicle does not hold the
   fleet's stops back), then the center's rank, then arrival;
3. **commands**, likewise fewest attempts first; a vehicle's commands take at most ``command_share`` of its
   turns in a row while it is polled, so a long queue never stops its data;
4. a **ping** of the vehicle whose poll comes next, when its range is older than ``ping_interval`` (times
   the highest share over its own: a vehicle polled less often is ranged less often);
5. a **poll**, by stride scheduling: each polled vehicle has a ``share`` (changeable at run time) and a
   virtual time advancing by ``1 / share`` with each poll; the lowest, less a lead for a vehicle with a
   command held or urgent data, is polled, at the fastest rate ``tacit.link.choose_rate`` allows from the
   SNR this shore last heard from it that fits the room (down to rate 0). No vehicle starves: a lead only
   moves it ahead by one stride.

A frame leaves the queue when acknowledged, out of attempts, expired or withdrawn (``withdraw``: the
center took it back); each attempt and each end goes to the ``reporter``.

Standard library and the core.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from gateway.slots import SYNC_WINDOW
from gateway.timing import Timing
from tacit.link import choose_rate

URGENT_LEAD = 1.0  # strides a vehicle with a command held or urgent data is polled sooner
SNR_MEMORY = 4  # receptions whose SNR the rate choice remembers, per vehicle
PACKETS_PER_POLL = 4  # what a poll asks a vehicle's window for (rate choice: several packets, not one)


class FrameKind(enum.StrEnum):
    """What a held frame is: a stop goes before every other command, a SYNC at its stamp."""

    SYNC = "sync"
    STOP = "stop"
    COMMAND = "command"


class Exchange(enum.StrEnum):
    """What one turn of the MAC puts on the air."""

    SYNC = "sync"
    STOP = "stop"
    COMMAND = "command"
    PING = "ping"
    POLL = "poll"


class Outcome(enum.StrEnum):
    """What became of an exchange, or of a held frame."""

    ACKED = "acked"  # the vehicle's modem acknowledged the frame
    SENT = "sent"  # on the air, no ACK
    FAILED = "failed"  # not on the air (our modem refused), or no ACK after its attempts (final)
    EXPIRED = "expired"  # past its time: not sent
    WITHDRAWN = "withdrawn"  # the center took it back
    ANSWERED = "answered"  # a poll or ping the vehicle answered
    SILENT = "silent"  # a poll or ping nobody answered


@dataclass
class Held:
    """A frame the center signed, held for its attempts."""

    id: str
    address: int
    data: bytes
    kind: FrameKind = FrameKind.COMMAND
    rank: int = 0
    stamp: float = 0.0  # a SYNC: when it goes (0: at once)
    attempts: int = 3
    expires_at: float = 0.0  # 0: never
    made: int = 0  # attempts on the air
    order: int = 0  # arrival


@dataclass(frozen=True)
class Report:
    """An attempt of a held frame (``final``: its end) for the reporter."""

    frame: Held
    outcome: Outcome
    attempt: int
    final: bool


@dataclass(frozen=True)
class Turn:
    """The next exchange: what, for whom, at which rate, holding the band ``duration`` s."""

    exchange: Exchange
    address: int
    duration: float
    rate: int = 0
    frame: Held | None = None


@dataclass
class Vehicle:
    """The queue's record of one vehicle, as this shore hears it."""

    address: int
    share: float = 1.0
    virtual: float = 0.0
    urgent: bool = False
    range_m: float | None = None
    snr: deque[float] = field(default_factory=lambda: deque(maxlen=SNR_MEMORY))
    last_ping: float = -math.inf
    in_a_row: int = 0  # command turns since its last poll
    polls: int = 0
    answered: int = 0

    @property
    def recent_snr(self) -> float | None:
        return min(self.snr) if self.snr else None  # the worst of the last few: a fade costs one rate


class Queue:
    def __init__(
        self,
        timing: Timing,
        reporter: Callable[[Report], None],
        ping_interval: float = 120.0,
        command_share: int = 3,
    ) -> None:
        self.timing = timing
        self.reporter = reporter
        self.ping_interval = ping_interval
        self.command_share = command_share
        self.held: list[Held] = []
        self.vehicles: dict[int, Vehicle] = {}
        self.polled: tuple[int, ...] = ()  # the vehicles this shore polls
        self._withdrawn: set[str] = set()
        self._arrivals = 0

    # --- what the center hands down ---------------------------------------------------------------

    def hold(self, frame: Held) -> bool:
        """Hold a frame for its attempts (a SYNC replaces its vehicle's older one, reported expired);
        False if it was withdrawn before it came (reported withdrawn) or is held already."""
        if frame.id in self._withdrawn:
            self._end(frame, Outcome.WITHDRAWN)
            return False
        if any(h.id == frame.id for h in self.held):
            return False
        if frame.kind is FrameKind.SYNC:
            for older in [h for h in self.held if h.kind is FrameKind.SYNC and h.address == frame.address]:
                self._drop(older, Outcome.EXPIRED)
        self._arrivals += 1
        frame.order = self._arrivals
        self.held.append(frame)
        self.vehicle(frame.address)
        return True

    def withdraw(self, frame_id: str) -> bool:
        """The center took back a frame: it goes no more (reported withdrawn); whether it was held."""
        self._withdrawn.add(frame_id)
        for frame in self.held:
            if frame.id == frame_id:
                self._drop(frame, Outcome.WITHDRAWN)
                return True
        return False

    def poll(self, addresses: Iterable[int]) -> None:
        """The vehicles this shore polls (the center's plan); a newcomer starts level with the others."""
        self.polled = tuple(dict.fromkeys(addresses))
        for address in self.polled:
            self.vehicle(address)

    def share(self, address: int, share: float) -> None:
        """The vehicle's weight among the polls, from the next turn."""
        if not share > 0:
            raise ValueError(f"a share is a positive number: {share!r}")
        self.vehicle(address).share = share

    def vehicle(self, address: int) -> Vehicle:
        if address not in self.vehicles:
            start = min((v.virtual for v in self.vehicles.values()), default=0.0)
            self.vehicles[address] = Vehicle(address, virtual=start)
        return self.vehicles[address]

    # --- what the shore hears ---------------------------------------------------------------------

    def heard(self, address: int, snr: float | None, urgent: bool = False) -> None:
        """A frame from the vehicle: its SNR steers the rate; ``urgent``: it has time-sensitive data."""
        vehicle = self.vehicle(address)
        if snr is not None and math.isfinite(snr):
            vehicle.snr.append(snr)
        vehicle.urgent = vehicle.urgent or urgent

    def ranged(self, address: int, range_m: float) -> None:
        self.vehicle(address).range_m = range_m

    # --- the next turn ------------------------------------------------------------------------------

    def next(self, now: float, room: float) -> Turn | None:
        """The first exchange, in the module's order, that fits ``room`` s (None: nothing does)."""
        self._expire(now)
        for turn in self._candidates(now):
            if turn.duration <= room:
                return turn
            if turn.exchange is Exchange.POLL:
                slower = self._slower(turn, room)
                if slower is not None:
                    return slower
        return None

    def waiting(self) -> bool:
        """Whether anything waits: a held frame, or a vehicle to poll."""
        return bool(self.held or self.polled)

    def _candidates(self, now: float) -> Iterable[Turn]:
        syncs = [h for h in self.held if h.kind is FrameKind.SYNC and h.stamp - SYNC_WINDOW <= now]
        for frame in sorted(syncs, key=lambda h: (h.stamp, h.order)):
            yield self._frame_turn(Exchange.SYNC, frame)
        for kind, exchange in ((FrameKind.STOP, Exchange.STOP), (FrameKind.COMMAND, Exchange.COMMAND)):
            frames = [h for h in self.held if h.kind is kind and self._command_turn(h.address)]
            for frame in sorted(frames, key=lambda h: (h.made, h.rank, h.order)):
                yield self._frame_turn(exchange, frame)
        polled = self._poll_order()
        if polled:
            vehicle = polled[0]
            if now - vehicle.last_ping >= self._ping_interval(vehicle):
                yield Turn(Exchange.PING, vehicle.address, self.timing.ping(vehicle.range_m))
            rate = choose_rate(vehicle.recent_snr, loss_sensitive=False, packets=PACKETS_PER_POLL)
            yield Turn(Exchange.POLL, vehicle.address, self.timing.poll(vehicle.range_m, rate), rate)

    def _ping_interval(self, vehicle: Vehicle) -> float:
        """``ping_interval`` for the vehicles of the highest share, longer in proportion for the others (a
        vehicle polled a quarter as often is ranged a quarter as often)."""
        top = max(self.vehicles[a].share for a in self.polled)
        return self.ping_interval * top / vehicle.share

    def _frame_turn(self, exchange: Exchange, frame: Held) -> Turn:
        duration = self.timing.command(self.vehicle(frame.address).range_m)
        return Turn(exchange, frame.address, duration, 0, frame)

    def _slower(self, turn: Turn, room: float) -> Turn | None:
        """The poll at the fastest slower rate that fits ``room``."""
        range_m = self.vehicle(turn.address).range_m
        for rate in sorted((r for r in (0, 1) if r < turn.rate), reverse=True):
            duration = self.timing.poll(range_m, rate)
            if duration <= room:
                return Turn(Exchange.POLL, turn.address, duration, rate)
        return None

    def _command_turn(self, address: int) -> bool:
        """Whether the vehicle's commands may take this turn (not past their share in a row while it is
        polled)."""
        return address not in self.polled or self.vehicle(address).in_a_row < self.command_share

    def _poll_order(self) -> list[Vehicle]:
        """The polled vehicles, the next to poll first (stride scheduling, leads for what waits)."""
        holding = {h.address for h in self.held}

        def key(vehicle: Vehicle) -> tuple[float, int]:
            lead = URGENT_LEAD if vehicle.urgent or vehicle.address in holding else 0.0
            return vehicle.virtual - lead / vehicle.share, vehicle.address

        return sorted((self.vehicles[a] for a in self.polled), key=key)

    # --- what became of a turn ----------------------------------------------------------------------

    def done(self, turn: Turn, outcome: Outcome, now: float) -> None:
        """The MAC's word on ``turn``'s exchange."""
        vehicle = self.vehicle(turn.address)
        if turn.exchange is Exchange.PING:
            vehicle.last_ping = now
            return
        if turn.exchange is Exchange.POLL:
            vehicle.virtual += 1.0 / vehicle.share
            vehicle.in_a_row = 0
            vehicle.urgent = False
            vehicle.polls += 1
            vehicle.answered += outcome is Outcome.ANSWERED
            return
        frame = turn.frame
        if frame is None or frame not in self.held:
            return  # withdrawn while on the air: its end is reported
        if outcome is Outcome.FAILED:  # not on the air: it keeps its turn
            self.reporter(Report(frame, outcome, frame.made, False))
            if frame.kind is FrameKind.SYNC and now > frame.stamp + SYNC_WINDOW:
                self._drop(frame, Outcome.EXPIRED)
            return
        frame.made += 1
        vehicle.in_a_row += frame.kind is not FrameKind.SYNC
        self.reporter(Report(frame, outcome, frame.made, False))
        if outcome is Outcome.ACKED:
            self._drop(frame, Outcome.ACKED)
        elif frame.made >= frame.attempts or frame.kind is FrameKind.SYNC:
            self._drop(frame, Outcome.FAILED)

    def _expire(self, now: float) -> None:
        for frame in list(self.held):
            late = frame.kind is FrameKind.SYNC and frame.stamp and now > frame.stamp + SYNC_WINDOW
            if late or (frame.expires_at and now > frame.expires_at):
                self._drop(frame, Outcome.EXPIRED)

    def _drop(self, frame: Held, outcome: Outcome) -> None:
        self.held.remove(frame)
        self._end(frame, outcome)

    def _end(self, frame: Held, outcome: Outcome) -> None:
        self.reporter(Report(frame, outcome, frame.made, True))
