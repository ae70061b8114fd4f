"""The center's safety functions (the paper's "critical/safety functions" of a multi-vehicle center).

- **Separation of plans** (``Separation.check``, the command desk's guard, and ``refuse_closer`` for a team
  start): every command that may move a vehicle, from every door (one vehicle's, the fleet's, a mission
  start, a team's legs, a resume, a return home, a lost-link action set by ``set_param``), is checked with
  the vehicle's whole plan (``server.safety.paths``: where it is predicted, where it steers, the commands
  it has not started, its mission's route, its team lanes, its lost-link action) against every other
  vehicle's. It is refused (422, naming the other vehicle and how close) when a part of the new plan comes
  closer than ``Settings.separation`` (centre to centre) to a part of another's, unless no closer than the
  two plans already are (a vehicle too close may always move away). A command whose path the shore
  cannot place (a mission it has no waypoints for) is refused while another vehicle has a plan.
- **Warnings** (``Separation.warnings``): two vehicles whose predicted positions are closer than the
  separation plus both uncertainties. A silent vehicle's uncertainty grows, so it warns: it never blocks a
  command (refusals use the paths' centres only). Checked again when a check-point moves a vehicle and
  every ``separation_check_interval``; a change is published on the bus (``SeparationWarning``).
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.db import saved_id
from server.core.errors import Refused
from server.core.events import Bus, Event, SeparationWarning, VehicleReported
from server.missions.service import Missions
from server.safety.geometry import Flat, Point
from server.safety.paths import Course, Plan, Planned, Steering, Unplaced, gap
from server.screens import estimate
from server.screens.service import Screens
from server.vehicles.models import Vehicle
from server.vehicles.service import Vehicles
from tacit.packets import ControlPacket, MissionState

log = logging.getLogger("tacit.server.safety")
CLOSER = 1e-6  # m: a plan counts as closer than another beyond this (rounding aside)
# m: what the separation allows for a move's distance as the control packet carries it (0.1 m steps):
# a leg computed to keep a lane exactly the separation from another's may end that much nearer
SLACK = ControlPacket.field("distance").resolution
ON_ROUTE = (*estimate.FOLLOWING, MissionState.SELF_DETERMINED)  # it steers along its mission's route


def _where(p: Point) -> str:
    n, e, d = (round(x, 1) + 0.0 for x in p)  # + 0.0: no "-0.0"
    return f"({n:.1f} N, {e:.1f} E, {d:.1f} m deep)"


@dataclass(frozen=True)
class Candidate:
    """A vehicle's plan with new commands, and where the first of them starts and the last ends (what a
    refusal names)."""

    planned: Planned
    start: Point
    end: Point


class Separation:
    def __init__(
        self,
        settings: Settings,
        screens: Screens,
        vehicles: Vehicles,
        desk: CommandDesk,
        missions: Missions,
        bus: Bus,
    ) -> None:
        self.settings = settings
        self.screens = screens
        self.vehicles = vehicles
        self.desk = desk
        self.missions = missions
        self.bus = bus
        self._warned: dict[tuple[str, str], dict[str, Any]] = {}  # the watcher's thread only

    # --- plans ----------------------------------------------------------------------------------------

    def course(self, vehicle: Vehicle) -> Course | None:
        """What the shore knows of the vehicle now (None before its first check-point)."""
        guess = self.screens.estimate(saved_id(vehicle))
        predicted, cp = guess["predicted"], guess["reported"]
        if predicted is None:
            return None
        state = estimate.state_of(cp)
        steering: Point | None = tuple(predicted["target"]) if predicted["target"] else None
        if state is MissionState.RETURNING:
            steering = (*vehicle.home, 0.0)  # the agent returns home at the surface
        mission = int(cp.get("mission_id", 0)) or None
        on_route = state in ON_ROUTE
        return Course(
            vehicle.name,
            (predicted["north"], predicted["east"], predicted["depth"]),
            predicted["radius_m"],
            float(cp.get("heading", 0.0)),
            vehicle.home,
            vehicle.lost_action,
            steering,
            mission,
            int(cp.get("waypoint", 0)) + (1 if on_route and steering is not None else 0),
            mission is not None and (on_route or state is MissionState.COMMANDED),
        )

    def candidate(
        self,
        vehicle: Vehicle,
        then: Sequence[Steering] = (),
        tail: Sequence[Point] | None = None,
    ) -> Candidate | None:
        """The vehicle's plan with the commands ``then`` after those it has not started, and ``tail`` (its
        team's waypoints still to come, default its started team's) after them; None before its first
        check-point. ``Unplaced`` if a command goes where the shore cannot tell."""
        course = self.course(vehicle)
        if course is None:
            return None
        missions = self.missions.routes(vehicle)
        plan = Plan.of(course, missions)
        for queued in self.desk.not_started(saved_id(vehicle)):
            plan.command(queued, missions)
        start = plan.centre[-1]
        for command in then:
            plan.command(command, missions)
        end = plan.centre[-1]
        plan.then(self.missions.team_ahead(saved_id(vehicle)) if tail is None else tail)
        return Candidate(plan.done(), start, end)

    def planned(self, vehicle: Vehicle) -> Planned | None:
        """The vehicle's plan now (None before its first check-point, or where the shore cannot place it:
        then it is only where it is predicted)."""
        try:
            found = self.candidate(vehicle)
        except Unplaced as exc:
            log.warning("vehicle %s: %s", vehicle.name, exc)
            course = self.course(vehicle)
            return None if course is None else Plan.of(course, {}).done()
        return None if found is None else found.planned

    # --- checks ---------------------------------------------------------------------------------------

    def check(self, vehicle_ids: Sequence[int], command: Steering) -> None:
        """The command desk's guard: refuse (``Refused``, 422) ``command`` for the vehicles (one, or a
        fleet's: each also against the others' new plans) if it brings a plan closer than the separation
        to another's."""
        chosen = [self.vehicles.get(i) for i in vehicle_ids]
        candidates: dict[int, Candidate] = {}
        for vehicle in chosen:
            try:
                found = self.candidate(vehicle, [command])
            except Unplaced as exc:
                if any(self.planned(v) for v in self.vehicles.every() if v.id != vehicle.id):
                    raise Refused(str(exc), "command") from None
                continue  # no other vehicle is placed: nothing to keep it apart from
            if found is not None:
                candidates[saved_id(vehicle)] = found
        self.refuse_closer(candidates, command.command)

    def check_home(self, vehicle_id: int, home: Flat) -> None:
        """Refuse a new home that would bring the vehicle's plan (a return home queued or under way, its
        mission's end, a lost-link return) closer than the separation to another vehicle's."""
        vehicle = self.vehicles.get(vehicle_id)
        moved = vehicle.model_copy(update={"home_north": home[0], "home_east": home[1]})
        try:
            found = self.candidate(moved)
        except Unplaced:
            return  # where its commands go is unknown with either home
        if found is not None:
            self.refuse_closer({vehicle_id: found}, f"a home at {home[0]:g} N, {home[1]:g} E")

    def refuse_closer(self, candidates: Mapping[int, Candidate], what: str) -> None:
        """Refuse (``Refused``) if a candidate plan comes closer than the separation to another vehicle's
        plan (its candidate if it has one), unless no closer than their plans now are. ``what``: the
        action, as the refusal names it."""
        fleet = self.vehicles.every()
        now = {saved_id(v): self.planned(v) for v in fleet}
        names = {saved_id(v): v.name for v in fleet}
        limit = self.settings.separation
        for vehicle_id, new in candidates.items():
            for other, theirs in now.items():
                if other == vehicle_id or theirs is None:
                    continue
                against = candidates[other].planned if other in candidates else theirs
                closest = gap(new.planned, against, limit)
                if closest >= limit - SLACK:
                    continue
                own = now[vehicle_id]
                # measured only as far as decides it: anything beyond closest + CLOSER is farther
                before = math.inf if own is None else gap(own, theirs, closest + 2 * CLOSER)
                if closest < before - CLOSER:
                    raise Refused(self._refusal(names[vehicle_id], what, new, names[other], against, closest))

    def _refusal(
        self, name: str, what: str, new: Candidate, other: str, theirs: Planned, closest: float
    ) -> str:
        limit = f"closer than the {self.settings.separation:g} m separation"
        if (
            gap(new.planned, theirs, self.settings.separation - SLACK, lost=False)
            >= self.settings.separation - SLACK
        ):
            return (
                f"if the link is lost, {name} ({' or '.join(new.planned.lost_actions)}) and {other} "
                f"({' or '.join(theirs.lost_actions)}) may come {closest:.1f} m apart, {limit}"
            )
        going = (
            f"holds at {_where(theirs.end)}"
            if theirs.start == theirs.end
            else f"goes from {_where(theirs.start)} to {_where(theirs.end)}"
        )
        path = (
            f"path from {_where(new.start)} to {_where(new.end)}"
            if new.start != new.end
            else f"plan after {what} (from {_where(new.planned.start)} to {_where(new.planned.end)})"
        )
        shared = (
            f" (both end at {_where(new.end)}: send them one at a time, or give each its own home)"
            if new.start != new.end and theirs.start != theirs.end and math.dist(new.end, theirs.end) < CLOSER
            else ""
        )
        return f"{name}'s {path} passes {closest:.1f} m from {other}, which {going}: {limit}{shared}"

    def paths(self) -> list[Planned]:
        return [p for v in self.vehicles.every() if (p := self.planned(v)) is not None]

    def warnings(self) -> list[dict[str, Any]]:
        """Pairs of vehicles whose predicted positions are within the separation plus both uncertainties."""
        found = []
        courses = [c for v in self.vehicles.every() if (c := self.course(v)) is not None]
        for a, b in itertools.combinations(courses, 2):
            apart = math.dist(a.here, b.here)
            limit = self.settings.separation + a.radius + b.radius
            if apart < limit:
                found.append(
                    {
                        "vehicles": [a.name, b.name],
                        "distance_m": round(apart, 2),
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
