"""The center's safety functions (the paper's "critical/safety functions" of a multi-vehicle center).

- **Separation of planned paths** (``Separation.check``, the command desk's guard): a command whose path,
  a 3D segment from the vehicle's predicted position to its target, passes closer than
  ``Settings.separation`` (centre to centre) to another vehicle's planned path is refused (422, naming
  the other vehicle and how close), unless it comes no closer than the vehicle already is (a vehicle
  too close may always move away). Another vehicle's planned path is its newest command not yet running
  (queued, sent, acknowledged; a return home goes to its registered home), else what the shore
  predicts it steers to (its executing command, its mission's waypoint, home), else its predicted
  position.
- **Warnings** (``Separation.warnings``): two vehicles whose predicted positions are closer than the
  separation plus both uncertainties. A silent vehicle's uncertainty grows, so it warns: it never blocks a
  command (refusals use the paths' centres only). Checked again when a check-point moves a vehicle and
  every ``separation_check_interval``; a change is published on the bus (``SeparationWarning``).
- **Lost-link actions** (``lost_link_conflict``): checked when a team mission starts.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from server.commands.models import CommandState
from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.db import saved_id
from server.core.errors import Refused
from server.core.events import Bus, Event, SeparationWarning, VehicleReported
from server.safety.geometry import Flat, Point, convex_hull, hull_distance, segment_distance
from server.screens.service import Screens
from server.vehicles.models import Vehicle
from server.vehicles.service import Vehicles
from tacit.navigation import move_target
from tacit.packets import Command

log = logging.getLogger("tacit.server.safety")
NOT_RUNNING = (CommandState.QUEUED, CommandState.SENT, CommandState.ACKNOWLEDGED)


class Steering(Protocol):
    """A command's fields that say where it goes (``CommandIn`` and ``CommandRecord`` both have them)."""

    command: str
    distance: float
    angle: float
    depth: float
    absolute_angle: bool


def target_of(command: Steering, start: Point, heading: float, home: Flat) -> Point | None:
    """Where a command steers a vehicle at ``start`` heading ``heading`` whose home is ``home``; None if
    it names no target we can place (hold, resume, a mission, a parameter)."""
    kind = Command[command.command.upper()]
    if kind is Command.RETURN_HOME:
        return (home[0], home[1], 0.0)  # the agent returns to its home at the surface
    if kind is Command.MOVE:
        north, east = move_target(
            start[0], start[1], heading, command.distance, command.angle, command.absolute_angle
        )
        return (north, east, start[2] + command.depth)
    if kind is Command.GOTO_DEPTH:
        return (start[0], start[1], command.depth)
    return None


@dataclass(frozen=True)
class Planned:
    """Where the shore sees a vehicle going: from its predicted position to ``end`` (``end`` equals
    ``start`` when idle), the uncertainty about that position, and its last reported heading."""

    name: str
    start: Point
    end: Point
    radius: float
    heading: float

    def as_dict(self) -> dict[str, Any]:
        return {
            "vehicle": self.name,
            "start": [round(x, 2) for x in self.start],
            "end": [round(x, 2) for x in self.end],
            "radius_m": round(self.radius, 2),
        }


def _where(p: Point) -> str:
    n, e, d = (round(x, 1) + 0.0 for x in p)  # + 0.0: no "-0.0"
    return f"({n:.1f} N, {e:.1f} E, {d:.1f} m deep)"


class Separation:
    def __init__(
        self, settings: Settings, screens: Screens, vehicles: Vehicles, desk: CommandDesk, bus: Bus
    ) -> None:
        self.settings = settings
        self.screens = screens
        self.vehicles = vehicles
        self.desk = desk
        self.bus = bus
        self._warned: dict[tuple[str, str], dict[str, Any]] = {}  # the watcher's thread only

    def planned(self, vehicle: Vehicle) -> Planned | None:
        """The vehicle's planned path (None before its first check-point)."""
        guess = self.screens.estimate(saved_id(vehicle))
        predicted, reported = guess["predicted"], guess["reported"]
        if predicted is None:
            return None
        here: Point = (predicted["north"], predicted["east"], predicted["depth"])
        heading = float(reported.get("heading", 0.0))
        end: Point = tuple(predicted["target"]) if predicted["target"] else here
        newest = self.desk.page(saved_id(vehicle), 1)
        if newest and newest[0][0].status in NOT_RUNNING:
            end = target_of(newest[0][0], here, heading, vehicle.home) or end
        return Planned(vehicle.name, here, end, predicted["radius_m"], heading)

    def check(self, vehicle_id: int, command: Steering, instead: Mapping[int, Planned] | None = None) -> None:
        """Refuse (``Refused``, 422) a command whose path passes closer than the separation to another
        vehicle's planned path; ``instead``: planned paths to assume for some vehicles (by id), e.g. the
        first legs of a team mission about to start."""
        vehicle = self.vehicles.get(vehicle_id)
        own = self.planned(vehicle)
        target = target_of(command, own.start, own.heading, vehicle.home) if own else None
        if own is None or target is None:
            return  # never heard from, or no target: nothing to place (the vehicle checks its own limits)
        for other in self.vehicles.every():
            if other.id == vehicle_id:
                continue
            path = (instead or {}).get(saved_id(other)) or self.planned(other)
            if path is None:
                continue
            gap = segment_distance(own.start, target, path.start, path.end)
            now = segment_distance(own.start, own.start, path.start, path.end)
            if gap < self.settings.separation and gap < now - 1e-6:
                going = "holds at" if path.start == path.end else f"goes from {_where(path.start)} to"
                raise Refused(
                    f"{vehicle.name}'s path from {_where(own.start)} to {_where(target)} passes {gap:.1f} m "
                    f"from {other.name}, which {going} {_where(path.end)}: closer than the "
                    f"{self.settings.separation:g} m separation",
                    "command",
                )

    def paths(self) -> list[Planned]:
        return [p for v in self.vehicles.every() if (p := self.planned(v)) is not None]

    def warnings(self) -> list[dict[str, Any]]:
        """Pairs of vehicles whose predicted positions are within the separation plus both uncertainties."""
        found = []
        for a, b in itertools.combinations(self.paths(), 2):
            gap = math.dist(a.start, b.start)
            limit = self.settings.separation + a.radius + b.radius
            if gap < limit:
                found.append(
                    {
                        "vehicles": [a.name, b.name],
                        "distance_m": round(gap, 2),
                        "limit_m": round(limit, 2),
                        "separation_m": self.settings.separation,
                        "uncertainty_m": round(a.radius + b.radius, 2),
                    }
                )
        return found

    def recheck(self) -> None:
        """Publish the warnings that began and those that ended since the last check."""
        now = {(w["vehicles"][0], w["vehicles"][1]): w for w in self.warnings()}
        for pair, w in now.items():
            if pair not in self._warned:
                log.warning(
                    "vehicles %s and %s: %.1f m apart, within %.1f m", *pair, w["distance_m"], w["limit_m"]
                )
                self.bus.publish(
                    SeparationWarning(
                        vehicles=list(pair), distance_m=w["distance_m"], limit_m=w["limit_m"], active=True
                    )
                )
        for pair, w in self._warned.items():
            if pair not in now:
                self.bus.publish(
                    SeparationWarning(
                        vehicles=list(pair), distance_m=w["distance_m"], limit_m=w["limit_m"], active=False
                    )
                )
        self._warned = now

    def on_event(self, event: Event) -> None:
        """A check-point moved a vehicle: check the warnings again."""
        if isinstance(event, VehicleReported):
            self.recheck()


@dataclass(frozen=True)
class LostLinkPlan:
    """A team member's part as its lost-link action would play it out: the points it may be at (its
    position now and its waypoints), its action (``hold``, ``surface`` or ``return``) and its home."""

    name: str
    points: Sequence[Point]
    action: str
    home: Flat

    def region(self) -> list[Flat]:
        """Where the vehicle may be, horizontally, if the link is lost anywhere along its plan: holding or
        surfacing keeps it on its plan; returning takes it in a straight line to its home from any point
        of it (the convex hull covers every such line)."""
        flat = [(p[0], p[1]) for p in self.points]
        return convex_hull(flat + ([self.home] if self.action == "return" else []))


def lost_link_conflict(plans: Sequence[LostLinkPlan], separation: float) -> str | None:
    """Why the members' lost-link actions could bring two of them closer than ``separation`` (None if
    they cannot). The link is shared: when the shore's modem goes quiet every vehicle loses it at once,
    anywhere along its plan, so the regions must stay apart."""
    for a, b in itertools.combinations(plans, 2):
        gap = hull_distance(a.region(), b.region())
        if gap < separation:
            return (
                f"if the link is lost, {a.name} ({a.action}) and {b.name} ({b.action}) may come {gap:.1f} m "
                f"apart, closer than the {separation:g} m separation"
            )
    return None
