"""The vehicle's clock on the shore's: how far ahead of the shore's clock the vehicle's runs, and when, on
the shore's clock, something the vehicle reported happened at the latest.

A check-point is stamped with the vehicle's time in whole seconds when it is made, and the shore hears it
later (it waits for its slot, then its airtime): so ``time - heard_at`` is never more than the true offset
(vehicle minus shore), and the largest of it over recent check-points (the one that waited least) is the
tightest such bound, as NTP's minimum-delay filter. An event the vehicle stamped ``time`` happened before
``time + 1`` on its clock, so before ``time + 1 - offset`` on the shore's, and before the shore heard of
it: that bound never comes before the event's cause (a command's "sent"), which a raw vehicle time can
(the stamp drops up to a second, and the clocks differ).

A SYNC that steps the vehicle's clock (beyond the agent's 30 s dead band) leaves the bound too high until
the check-points before the step are out of the window; the agent's dead band makes that rare.
"""

from __future__ import annotations

from collections.abc import Iterable

RESOLUTION_S = 1.0  # a check-point's time is whole seconds (tacit.packets.CheckpointPacket's time field)
WINDOW = 8  # the check-points the offset is taken over


def offset(stamps: Iterable[tuple[float, float]]) -> float | None:
    """A lower bound of vehicle clock minus shore clock from (vehicle time, shore time heard) pairs; None
    without any."""
    return max((time - heard_at for time, heard_at in stamps), default=None)


def on_shore_clock(time: float, heard_at: float, vehicle_offset: float | None) -> float:
    """The latest shore time at which an event the vehicle stamped ``time`` can have happened, as the shore
    heard of it at ``heard_at``."""
    if vehicle_offset is None:
        return heard_at
    return min(heard_at, time + RESOLUTION_S - vehicle_offset)
