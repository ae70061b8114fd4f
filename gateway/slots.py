"""TDMA across the gateways that share one acoustic band: a frame of slots, each gateway transmitting
only in its own (goby's TDMA MAC, across shore modems instead of vehicles).

Slot ``k`` begins at ``epoch + k * slot`` on the gateways' clocks and belongs to ``order[k % n]``. A
gateway starts a transmission no earlier than ``guard`` s into its slot and has it over (its ACK back)
``guard`` s before the slot ends. Why that is enough: with every clock within ``e`` of true time and
every receiver within ``R`` of both gateways, the last sound of a slot (sent by its ends' ``slot - guard``,
``e`` late at worst) has reached every receiver ``R / c`` later, and the next gateway starts no sooner
than ``guard - e`` after the slot's end: nothing overlaps at any receiver while
``2 * guard >= R / c + 2 * e``, that is ``guard >= R / (2c) + e`` (``guard_for``). Gateways at sea have
GPS (a PPS-disciplined clock is within a microsecond) or NTP over the backhaul (tens of milliseconds);
the acoustic term dominates: 1 s for 3 km.

The gateway's MAC (``gateway.mac``) asks ``Schedule.room`` how long its slot still holds before each
exchange; the center stamps SYNCs for ``Schedule.opening``.

Standard library and the core.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from tacit.rates import CYCLE_INIT_BITS, airtime_s, data_airtime_s

#: A command attempt's time on the air before its ACK wait: the cycle-init and one rate-0 frame.
ATTEMPT_AIRTIME = airtime_s(CYCLE_INIT_BITS, 0) + data_airtime_s(0, 1)
#: s either side of its stamp in which a gateway sends the center's SYNC: the center stamps it for the
#: start of a slot of its gateway, and its time sets the vehicle's clock (within the agent's dead band).
SYNC_WINDOW = 2.0


def guard_for(max_range: float, clock_error: float, sound_speed: float = 1500.0) -> float:
    """The guard time (s) that keeps slots apart at every receiver within ``max_range`` m of the
    gateways, their clocks within ``clock_error`` s of true time."""
    return max_range / (2.0 * sound_speed) + clock_error


@dataclass(frozen=True)
class SlotPlan:
    epoch: float  # UNIX s: slot 0 begins
    slot: float  # s
    guard: float  # s at each end of a slot
    order: tuple[str, ...]  # the gateways, one slot each per frame

    def __post_init__(self) -> None:
        if not self.order or self.slot <= 2 * self.guard or self.guard < 0:
            raise ValueError("a slot plan needs gateways and slots longer than their two guards")

    @property
    def usable(self) -> float:
        """The longest transmission (with its ACK) a slot holds."""
        return self.slot - 2 * self.guard

    def owner(self, t: float) -> str:
        """The gateway whose slot ``t`` falls in."""
        k = math.floor((t - self.epoch) / self.slot)
        return self.order[k % len(self.order)]

    def next_start(self, gateway: str, now: float, duration: float) -> float:
        """The earliest time from ``now`` at which ``gateway`` may start a transmission that is over
        (ACK included) ``duration`` s later, inside its own slot and guards."""
        if gateway not in self.order:
            raise ValueError(f"{gateway} has no slot in this plan")
        if duration > self.usable:
            raise ValueError(f"{duration:.1f} s does not fit a {self.slot:.1f} s slot and its guards")
        n, mine = len(self.order), self.order.index(gateway)
        k = math.floor((now - self.epoch) / self.slot)
        for j in range(k, k + n + 1):
            if j % n != mine:
                continue
            begins = self.epoch + j * self.slot
            if now <= begins + self.slot - self.guard - duration:
                return max(now, begins + self.guard)
        raise AssertionError("unreachable: every frame holds one slot of each gateway")

    def room(self, gateway: str, now: float) -> float:
        """Seconds from ``now`` to the end of ``gateway``'s transmissions in the slot ``now`` falls in (its
        end less the guard); 0 outside its own slot or in its opening guard."""
        k = math.floor((now - self.epoch) / self.slot)
        begins = self.epoch + k * self.slot
        if self.order[k % len(self.order)] != gateway or now < begins + self.guard:
            return 0.0
        return max(0.0, begins + self.slot - self.guard - now)

    def next_slot(self, gateway: str, after: float) -> float:
        """When ``gateway``'s first slot whose transmissions start at ``after`` or later opens (its
        beginning plus the guard)."""
        if gateway not in self.order:
            raise ValueError(f"{gateway} has no slot in this plan")
        k = math.ceil((after - self.epoch - self.guard) / self.slot)
        k += (self.order.index(gateway) - k) % len(self.order)
        return self.epoch + k * self.slot + self.guard


class Schedule:
    """A gateway's plans: the one in force, and the one the center handed out for a later epoch (every
    gateway changes plan at that same instant of its clock, none while another still follows the old).
    A gateway that has only a plan to come (it started after the center handed it out) transmits nothing
    before its epoch: the others follow another plan until then, whose slots it does not know."""

    def __init__(self) -> None:
        self.current: SlotPlan | None = None
        self.coming: SlotPlan | None = None

    def receive(self, plan: SlotPlan, now: float) -> None:
        self._promote(now)
        if plan.epoch <= now:
            self.current, self.coming = plan, None
        else:
            self.coming = plan

    def plan(self, now: float) -> SlotPlan | None:
        """The plan in force at ``now`` (None before the first one's epoch)."""
        self._promote(now)
        return self.current

    def _promote(self, now: float) -> None:
        if self.coming is not None and now >= self.coming.epoch:
            self.current, self.coming = self.coming, None

    def start(self, gateway: str, now: float, duration: float) -> float:
        """When ``gateway`` may start a transmission of ``duration`` s (clipped to a slot): in its slot of
        the plan in force, or of the coming one if it would straddle the change; ``now`` when no plan
        in force holds the gateway (alone on its band)."""
        return self._first(
            gateway,
            now,
            lambda plan, t: plan.next_start(gateway, t, min(duration, plan.usable)),
            lambda plan: min(duration, plan.usable),
        )

    def room(self, gateway: str, now: float) -> float:
        """How long from ``now`` ``gateway`` may go on transmitting (its ACKs in): to its slot's end less the
        guard in the plan in force, cut at a coming plan's epoch; 0 outside its slot, and before the
        epoch of a plan to come when none is in force; ``inf`` when no plan holds it (alone on its band)."""
        self._promote(now)
        plan, coming = self.current, self.coming
        if plan is None:
            return 0.0 if coming is not None else math.inf
        if gateway not in plan.order:
            return math.inf if coming is None else max(0.0, coming.epoch - now)
        room = plan.room(gateway, now)
        return room if coming is None else min(room, max(0.0, coming.epoch - now))

    def opening(self, gateway: str, after: float) -> float:
        """When ``gateway``'s first slot opening at ``after`` or later opens (as ``start`` picks it for
        a slot's exchange); ``after`` when no plan in force holds the gateway."""
        return self._first(
            gateway, after, lambda plan, t: plan.next_slot(gateway, t), lambda plan: plan.usable
        )

    def _first(
        self,
        gateway: str,
        now: float,
        pick: Callable[[SlotPlan, float], float],
        length: Callable[[SlotPlan], float],
    ) -> float:
        """``pick``'s time in the plan in force, or in the coming one when what takes ``length`` would
        straddle the change (nothing before a coming plan's epoch when none is in force)."""
        self._promote(now)
        plan, coming = self.current, self.coming
        if plan is None and coming is not None:  # only a plan to come: nothing before its epoch
            at = now
        elif plan is None or gateway not in plan.order:
            return now
        else:
            at = pick(plan, now)
        if coming is not None and (plan is None or at + length(plan) > coming.epoch):
            if gateway not in coming.order:
                return max(at, coming.epoch)
            return pick(coming, max(now, coming.epoch))
        return at
