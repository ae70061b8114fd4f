"""The shore's one MAC: the slot loop every shore modem's process runs (``tacit gateway``, and the
gateway inside ``tacit serve``).

Turn after turn it asks its queue (``gateway.queue``) what goes next that fits the room left in its slot
(``gateway.slots.Schedule.room``: the end of its own TDMA slot less the guard; the whole time when no plan
holds it, alone on its band), then runs that exchange on the modem driver (``tacit.modem``) and tells the
queue what became of it. Several exchanges share a slot while they fit: a SYNC and a poll, a command and
a poll at rate 5.

**Slot discipline.** Right before it hands a frame to the modem it reads the clock again: the whole
exchange (the frames at the chosen rate, the reply or ACK, the propagation at the vehicle's last known
range: ``gateway.timing``) must end inside its own slot before the guard, or nothing goes and it waits
for its next slot. A process that wakes late (a busy machine, a stalled Pi) therefore never runs into
another station's slot; the late turns are counted (``MacStatus.late``). A plan whose slots are too
short for one exchange at rate 0 is refused with one log line, shown in ``MacStatus.refused``, and
nothing is sent while it is in force.

Every exchange's time on the band is kept (``transmissions``: start and end, on its clock), so tests and
benchmarks check the discipline against what happened.

Standard library and the core.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections import Counter, defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from gateway.queue import PACKETS_PER_POLL, Exchange, Outcome, Queue, Turn
from gateway.slots import Schedule
from gateway.timing import Timing
from tacit import modem as mm
from tacit.link import choose_rate

log = logging.getLogger("tacit.gateway.mac")

IDLE_WAIT = 1.0  # s (of the modem's time) between looks at an empty queue: work wakes it at once


class Driver(Protocol):
    """What the MAC needs of a modem: ``tacit.modem.ModemDriver``, or a simulated sea's."""

    @property
    def state(self) -> mm.LinkState: ...

    def add_listener(self, listener: Callable[[mm.Event], None]) -> None: ...

    async def send(
        self,
        dest: int,
        frames: list[bytes],
        rate: int = 0,
        ack: bool = True,
        ack_timeout: float | None = None,
    ) -> mm.TransmitResult: ...

    async def poll(self, remote: int, rate: int = 0, ack: bool = False) -> None: ...

    async def ping(self, dest: int, timeout: float = 10.0) -> float | None: ...


@dataclass
class MacStatus:
    """What the MAC says of itself (the gateway's heartbeat carries it)."""

    exchanges: Counter[str] = field(default_factory=Counter)  # by ``Exchange``, on the air
    airtime: defaultdict[str, float] = field(
        default_factory=lambda: defaultdict(float)
    )  # s held, by ``Exchange``
    outcomes: Counter[str] = field(default_factory=Counter)  # by ``Outcome``
    late: int = 0  # turns that no longer fitted their slot when their time came: waited for the next
    refused: str = ""  # why the plan in force is refused ("" none)

    def detail(self) -> dict[str, Any]:
        return {
            "exchanges": dict(self.exchanges),
            "outcomes": dict(self.outcomes),
            "airtime": {kind: round(seconds, 1) for kind, seconds in self.airtime.items()},
            "late": self.late,
            "refused": self.refused,
        }


class Mac:
    def __init__(
        self,
        name: str,
        driver: Driver,
        queue: Queue,
        schedule: Schedule,
        timing: Timing,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.name = name
        self.driver = driver
        self.queue = queue
        self.schedule = schedule
        self.timing = timing
        self.clock = clock
        self.status = MacStatus()
        self.transmissions: list[tuple[float, float]] = []  # each exchange's (start, end), clock s
        self._work = asyncio.Event()
        self._heard: dict[int, asyncio.Event] = {}
        driver.add_listener(self._on_modem)

    def detail(self) -> dict[str, Any]:
        """Its status and, per vehicle it polls or holds frames for, what this station knows of it: the
        range it measured, the rate its next poll would take, the SNR it heard, its polls (what the
        gateway's heartbeat carries: ranges and rates per vehicle and gateway)."""
        vehicles = {
            str(v.address): {
                "range_m": None if v.range_m is None else round(v.range_m, 1),
                "rate": choose_rate(v.recent_snr, loss_sensitive=False, packets=PACKETS_PER_POLL),
                "snr": v.recent_snr,
                "share": v.share,
                "polls": v.polls,
                "answered": v.answered,
            }
            for v in self.queue.vehicles.values()
        }
        return {**self.status.detail(), "vehicles": vehicles}

    def wake(self) -> None:
        """Something was queued or the plan changed: look again at once."""
        self._work.set()

    def _on_modem(self, event: mm.Event) -> None:
        if isinstance(event, mm.ReceivedFrame):
            self.queue.heard(event.src, event.reception()[1])
            heard = self._heard.get(event.src)
            if heard is not None:
                heard.set()

    # --- the loop -----------------------------------------------------------------------------------

    async def run(self) -> None:
        while True:
            now = self.clock()
            if self._refused(now):
                await self._idle(IDLE_WAIT)
                continue
            room = self.schedule.room(self.name, now)
            if room <= 0:  # not its slot: sleep to the next one's opening (a new plan wakes it)
                opening = self.schedule.opening(self.name, now)
                await self._idle(max(opening - now, 0.01 / self.timing.time_scale))
                continue
            turn = self.queue.next(now, room) if self.driver.state is mm.LinkState.READY else None
            if turn is None:
                await self._idle(min(room, IDLE_WAIT / self.timing.time_scale))
                continue
            try:
                await self.turn(turn)
            except Exception:  # not the modem's refusal (that is an outcome): the MAC goes on all the same
                log.exception("%s: %s to %d failed", self.name, turn.exchange, turn.address)
                self.queue.done(turn, Outcome.FAILED, self.clock())
                await self._idle(IDLE_WAIT / self.timing.time_scale)

    async def turn(self, turn: Turn) -> None:
        """One exchange, if it still ends inside the slot now (the discipline check, the last thing before
        the modem), and its outcome to the queue."""
        now = self.clock()
        room = self.schedule.room(self.name, now)
        if turn.duration > room:
            self.status.late += 1
            log.info(
                "%s: %s to %d late (%.2f s left of %.2f s): next slot",
                *(self.name, turn.exchange, turn.address, room, turn.duration),
            )
            return
        started = self.clock()
        outcome = await self._exchange(turn, min(room - turn.duration, turn.duration / 4))
        self.transmissions.append((started, self.clock()))
        self.status.airtime[turn.exchange] += self.clock() - started
        self.status.exchanges[turn.exchange] += outcome is not Outcome.FAILED
        self.status.outcomes[outcome] += 1
        self.queue.done(turn, outcome, self.clock())

    async def _idle(self, timeout: float) -> None:
        self._work.clear()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._work.wait(), timeout)

    def _refused(self, now: float) -> bool:
        """Whether the plan in force has slots too short for one exchange at rate 0 (said once)."""
        plan = self.schedule.plan(now)
        shortest = self.timing.shortest()
        if plan is None or self.name not in plan.order or plan.usable >= shortest:
            self.status.refused = ""
            return False
        reason = f"slot {plan.slot:.2f} s less its guards holds {plan.usable:.2f} s; one exchange at rate 0 needs {shortest:.2f} s"
        if reason != self.status.refused:
            log.error("%s: plan refused, nothing sent in it: %s", self.name, reason)
        self.status.refused = reason
        return True

    # --- the exchanges ------------------------------------------------------------------------------

    async def _exchange(self, turn: Turn, spare: float) -> Outcome:
        """``spare``: s of its slot the exchange may wait beyond its timing for a late answer (a late ACK
        costs nothing inside the slot; up to a quarter of the exchange's length)."""
        try:
            if turn.exchange is Exchange.POLL:
                return await self._poll(turn, spare)
            if turn.exchange is Exchange.PING:
                return await self._ping(turn)
            return await self._send(turn, spare)
        except mm.ModemError as exc:
            log.info("%s: %s to %d not sent: %s", self.name, turn.exchange, turn.address, exc)
            return Outcome.FAILED

    async def _send(self, turn: Turn, spare: float) -> Outcome:
        assert turn.frame is not None
        range_m = self.queue.vehicle(turn.address).range_m
        result = await self.driver.send(
            turn.address,
            [turn.frame.data],
            rate=0,
            ack=True,
            ack_timeout=self.timing.ack_wait(range_m) + spare,
        )
        if result.all_acked:
            return Outcome.ACKED
        return Outcome.SENT if result.transmitted else Outcome.FAILED

    async def _poll(self, turn: Turn, spare: float) -> Outcome:
        """Ask the vehicle for its data at the turn's rate; the answer's frames arrive as modem events.
        Answered once one came (the rest of one transmission come with it) and the modem has ACKed them."""
        heard = self._heard.setdefault(turn.address, asyncio.Event())
        heard.clear()
        range_m = self.queue.vehicle(turn.address).range_m
        await self.driver.poll(turn.address, rate=turn.rate, ack=True)
        try:
            await asyncio.wait_for(heard.wait(), self.timing.poll_window(range_m, turn.rate) + spare)
        except TimeoutError:
            return Outcome.SILENT
        await asyncio.sleep(self.timing.ack_tail())  # the modem's ACK of the answer leaves
        return Outcome.ANSWERED

    async def _ping(self, turn: Turn) -> Outcome:
        travel = await self.driver.ping(
            turn.address, self.timing.ping_timeout(self.queue.vehicle(turn.address).range_m)
        )
        if travel is None or not math.isfinite(travel):
            return Outcome.SILENT
        range_m = travel * self.timing.sound_speed
        self.queue.ranged(turn.address, range_m)
        log.info("%s: vehicle %d at %.0f m", self.name, turn.address, range_m)
        return Outcome.ANSWERED
