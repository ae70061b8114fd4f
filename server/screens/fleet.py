"""The fleet as both screens show it: each vehicle's colour (one palette, here, served by the API to the
dashboard and used by the map; the gateways' too), and when a silent vehicle is overdue for its place in
the schedule.

Overdue: a vehicle answers when it is polled, and it has something to say at least once per report gap
(its check-point interval: measured as the median gap between its last check-points, on the shore's
clock, so a simulation's time scale needs nothing). Once that much time has passed it must wait for
its next slot, and a lost frame costs it a slot more: so it is overdue after its report gap and
``OVERDUE_SLOTS`` of its slot intervals (the time between its slots in the polled MAC's plan, in
proportion to its share) without a frame. Before two of its check-points were heard, its registered
report interval stands for its report gap, and its silence counts from when the shore began to listen
(or it was registered): until then it is *awaited* (its first report is not due yet), not overdue.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence

#: One colour per vehicle, in order of registration (Okabe-Ito's colour-blind-safe set without its
#: yellow, which a white page and the map's light water do not show).
PALETTE = ("#0072b2", "#d55e00", "#009e73", "#cc79a7", "#e69f00", "#56b4e9", "#7a4a00", "#000000")
#: A gateway's marker and its row: one dark colour per gateway (in order of name, none of the vehicles'
#: colours) while its heartbeats come, light grey once it is silent.
GATEWAYS = ("#6a3d9a", "#8c510a", "#01665e", "#b2182b", "#333333")
GATEWAY_SILENT = "#b0b0b0"
OVERDUE_SLOTS = 3  # slots a vehicle may miss (a frame lost, a slot taken by a command) before it is greyed


def colour(index: int) -> str:
    """The palette's colour for the ``index``-th vehicle (by registration), as ``#rrggbb``."""
    return PALETTE[index % len(PALETTE)]


def gateway_colour(index: int, alive: bool) -> str:
    """The ``index``-th gateway's colour (by name) on both screens, or ``GATEWAY_SILENT`` once it is silent."""
    return GATEWAYS[index % len(GATEWAYS)] if alive else GATEWAY_SILENT


def rgb(hex_colour: str) -> tuple[int, int, int]:
    """``#rrggbb`` as (r, g, b), for the map."""
    value = int(hex_colour.removeprefix("#"), 16)
    return (value >> 16) & 255, (value >> 8) & 255, value & 255


def latlon_text(lat: float, lon: float) -> str:
    """``40.48620° N, 74.45180° W``."""
    return f"{abs(lat):.5f}° {'N' if lat >= 0 else 'S'}, {abs(lon):.5f}° {'E' if lon >= 0 else 'W'}"


def report_gap(heard: Sequence[float]) -> float | None:
    """The median time between the shore hearing consecutive check-points (``heard``, any order: the
    screens take the last 8, the window of ``server.telemetry.clock``)."""
    times = sorted(heard)
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
    return statistics.median(gaps) if gaps else None


def slot_interval(share: float, slots: Sequence[tuple[float, float]]) -> float | None:
    """The time between a vehicle's slots: the plan's mean slot (``slots``: each planned vehicle's share and
    slot length) times the slots the others take for each of its own."""
    if not slots or share <= 0:
        return None
    mean_slot = sum(length for _, length in slots) / len(slots)
    return mean_slot * sum(s for s, _ in slots) / share


def overdue_after(gap: float, interval: float | None) -> float:
    """The silence (s) after which a vehicle is overdue: its report gap and ``OVERDUE_SLOTS`` of its slot
    ``interval`` (none: no slot planned for it yet)."""
    return gap + OVERDUE_SLOTS * (interval or 0.0)


def silence(last_heard: float | None, listening: float, registered: float, now: float) -> float:
    """How long the shore has heard nothing from a vehicle: since its last frame, or (none heard since the
    shore began ``listening``) since then or since it was ``registered``, whichever came later."""
    return now - (last_heard if last_heard is not None else max(listening, registered))
