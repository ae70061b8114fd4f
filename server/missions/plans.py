"""A team mission's plan, as pure functions: the survey area's lanes (a lawnmower), their split among the
vehicles (one contiguous set of lanes each), each vehicle's waypoints, the control packets they cost on
the link, and the restructuring rule applied when one vehicle reports a time-sensitive anomaly.

Frame: the fleet's shared local frame, m north and east of its origin, depth in m (down). Lanes run
north-south, ``spacing`` m apart, centred in the area's east-west extent.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from server.safety.geometry import Flat, Point, area, convex_hull, crossings, is_simple
from tacit import rates

MAX_LANES = 500  # a team mission's lanes: each is about two legs, each leg about 15 s of the channel


class PlanError(ValueError):
    """An area or a split that cannot make a survey: the message says why."""


@dataclass(frozen=True)
class Lane:
    east: float
    south: float
    north: float


def lanes(polygon: Sequence[Flat], spacing: float) -> list[Lane]:
    """The lanes covering a simple polygon, west to east: where a lane's line crosses a concave area
    more than once, each span inside it is a lane of its own."""
    if len(convex_hull(polygon)) < 3:
        raise PlanError("the area is empty: it needs at least three corners enclosing some water")
    if not is_simple(polygon) or area(polygon) <= 0:
        raise PlanError("the area's edges cross or touch each other: give a simple polygon")
    west, east = min(p[1] for p in polygon), max(p[1] for p in polygon)
    count = math.floor((east - west) / spacing + 1e-9)
    if count > MAX_LANES:
        raise PlanError(
            f"the area holds {count} lanes at {spacing:g} m, more than {MAX_LANES}: space them wider"
        )
    if count < 1:
        raise PlanError(f"the area is {east - west:g} m wide, narrower than one {spacing:g} m lane")
    first = west + (east - west - (count - 1) * spacing) / 2
    found = []
    for i in range(count):
        x = first + i * spacing
        spans = crossings(polygon, x)
        found += [Lane(x, spans[k], spans[k + 1]) for k in range(0, len(spans) - 1, 2)]
    return [lane for lane in found if lane.north - lane.south > 1e-6]


def split(all_lanes: Sequence[Lane], vehicles: int) -> list[list[Lane]]:
    """Contiguous groups of lanes, west to east, as equal as they can be: one group per vehicle."""
    if len(all_lanes) < vehicles:
        raise PlanError(f"the area holds {len(all_lanes)} lanes, fewer than the {vehicles} vehicles")
    size, extra = divmod(len(all_lanes), vehicles)
    groups, start = [], 0
    for k in range(vehicles):
        end = start + size + (1 if k < extra else 0)
        groups.append(list(all_lanes[start:end]))
        start = end
    return groups


def sweep(group: Sequence[Lane], depth: float) -> list[Point]:
    """A vehicle's waypoints over its lanes: up the first, down the next (a lawnmower)."""
    points: list[Point] = []
    for i, lane in enumerate(group):
        ends = [(lane.south, lane.east, depth), (lane.north, lane.east, depth)]
        points += ends if i % 2 == 0 else ends[::-1]
    return points


@dataclass(frozen=True)
class LegCost:
    """What one leg (one MOVE command) costs on the link at rate 0: the command frame down (after its
    cycle-init) and its ACK, and the two check-points the vehicle sends anyway when the leg starts and
    ends (executing, executed), each in a poll slot of its own."""

    bits_down: int
    bits_up: int
    channel_s: float

    @classmethod
    def at(cls, range_m: float, sound_speed: float) -> LegCost:
        frame = rates.rate(0).frame_bytes * 8
        round_trip = 2 * range_m / sound_speed + rates.TURNAROUND_S
        slot = rates.airtime_s(rates.CYCLE_INIT_BITS, 0) + rates.airtime_s(frame, 0) + round_trip
        command = slot + rates.airtime_s(rates.ACK_BITS, 0)
        return cls(
            bits_down=rates.CYCLE_INIT_BITS * 3 + frame,
            bits_up=rates.ACK_BITS + 2 * frame,
            channel_s=command + 2 * slot,
        )


def restructure(
    anomaly: Point, helpers: Mapping[str, Point], radius: float, count: int, apart: float
) -> dict[str, Point]:
    """The restructuring rule: when a team vehicle reports a time-sensitive anomaly (the warm plume) at
    ``anomaly`` (its predicted position then), the ``count`` other team vehicles nearest to it (by their
    predicted positions, ``helpers``) each get one new waypoint ``radius`` m from it, at its depth.

    Each helper's waypoint is on its own side of the anomaly (the point of that circle nearest to it), so
    no helper crosses the anomaly or the finder's work to get there (the finder turns towards the warmer
    water on its own, Algorithm 2). Helpers on the same side are turned apart around the circle, in
    bearing order, until their waypoints are at least ``apart`` m from each other (the separation). Every
    resulting command still passes the separation check."""
    chosen = sorted(helpers, key=lambda name: math.dist(helpers[name][:2], anomaly[:2]))[:count]

    def bearing(name: str) -> float:
        dn, de = helpers[name][0] - anomaly[0], helpers[name][1] - anomaly[1]
        return math.degrees(math.atan2(de, dn)) % 360

    gap = math.degrees(2 * math.asin(min(1.0, apart / (2 * radius))))
    out: dict[str, Point] = {}
    last = -math.inf
    for name in sorted(chosen, key=bearing):
        last = max(bearing(name), last + gap)
        b = math.radians(last)
        out[name] = (anomaly[0] + radius * math.cos(b), anomaly[1] + radius * math.sin(b), anomaly[2])
    return out
