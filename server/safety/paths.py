"""Where a vehicle may go, as the separation check sees it: pure functions, no I/O.

A vehicle's plan is a list of parts, each a set of points whose convex hull holds every place the vehicle
may be during that part (``Plan.parts``). It is built from what the shore knows (``Course``: the predicted
position, where the vehicle steers now, its own mission's route) and then, in order, each command the
vehicle has not started yet, as the vehicle would carry them out:

- a command starts wherever the vehicle is when it arrives: anywhere in what came before it (the link
  sends the next command as soon as the last was acknowledged, not when it ended), so a relative move
  sweeps the whole of that region along its displacement (``Plan.go``), and a route goes from anywhere in
  it to its first waypoint (``Plan.route``);
- a mission (``start_mission``, ``resume``, or the one it follows) is its waypoints and then home at the
  surface, reached from any point of it (its time may run out anywhere);
- after its commands, a team member's remaining lanes (``tail``);
- its lost-link action from any point of the plan (the link is shared: it may be lost anywhere): holding
  keeps the plan, surfacing adds each part's points at the surface, returning adds home at the surface.

A region stays small: when a part holds more than ``MAX_POINTS`` points, the box around them (its eight
corners) takes their place, which holds their hull. The distance between two plans (``gap``) is the
smallest distance between the hulls of their parts, centre to centre.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from server.safety.geometry import Flat, Point, box_gap, hull_gap
from tacit.navigation import move_target
from tacit.packets import Command
from tacit.params import LostAction, Param

MAX_POINTS = 16  # a part's points before its bounding box replaces them
Region = tuple[Point, ...]


class Steering(Protocol):
    """A command's fields that say where it goes (``CommandIn`` and ``CommandRecord`` both have them)."""

    command: str
    distance: float
    angle: float
    depth: float
    absolute_angle: bool
    param_id: int
    param_value: float


class Unplaced(ValueError):
    """A command that moves the vehicle where the shore cannot tell: the message says why."""


def bounded(points: Iterable[Point]) -> Region:
    """The points (no repeats), or the eight corners of their box when there are more than ``MAX_POINTS``."""
    unique = tuple(dict.fromkeys(points))
    if len(unique) <= MAX_POINTS:
        return unique
    lo = [min(p[i] for p in unique) for i in range(3)]
    hi = [max(p[i] for p in unique) for i in range(3)]
    return tuple((n, e, d) for n in (lo[0], hi[0]) for e in (lo[1], hi[1]) for d in (lo[2], hi[2]))


@dataclass(frozen=True)
class Course:
    """What the shore knows of a vehicle now: where it predicts it (``here``, ``radius`` its uncertainty),
    its last reported heading, where it steers (``steering``), the mission it has (``mission`` by number,
    ``waypoint``: the one its route goes on with after ``steering``; ``following``: it goes on with it by
    itself, now and after a command), its home and its lost-link action."""

    name: str
    here: Point
    radius: float
    heading: float
    home: Flat
    lost_action: LostAction
    steering: Point | None = None
    mission: int | None = None
    waypoint: int = 0
    following: bool = False


@dataclass
class Plan:
    """A vehicle's parts (``parts``), built command by command; ``centre`` is the line through the targets
    (what the screens draw and the refusals name)."""

    name: str
    home: Point  # home at the surface: where a return goes
    heading: float
    radius: float
    where: Region  # where the vehicle may be when the next command arrives
    parts: list[Region] = field(default_factory=list)
    centre: list[Point] = field(default_factory=list)
    actions: set[LostAction] = field(default_factory=set)
    mission: int | None = None
    waypoint: int = 0
    following: bool = False

    @classmethod
    def of(cls, course: Course, missions: Mapping[int, Sequence[Point]]) -> Plan:
        """The plan of what the vehicle does now, before the commands it has not started."""
        plan = cls(
            course.name,
            (*course.home, 0.0),
            course.heading,
            course.radius,
            (course.here,),
            [(course.here,)],
            [course.here],
            {course.lost_action},
            course.mission,
            course.waypoint,
        )
        if course.steering is not None:
            plan.route([course.steering])
        if course.following and course.mission is not None:
            plan.follow(missions, course.waypoint)
        return plan

    # --- what a part does -------------------------------------------------------------------------

    def go(self, to: Callable[[Point], Point]) -> None:
        """A part from anywhere the vehicle may be to ``to`` of that place (an affine map: a relative move,
        a depth, or a fixed point): the hull of both ends holds every such path."""
        part = bounded([*self.where, *(to(p) for p in self.where)])
        self.parts.append(part)
        self.where = part
        self.centre.append(to(self.centre[-1]))

    def route(self, points: Sequence[Point], home_from_each: bool = False) -> None:
        """From anywhere the vehicle may be through ``points`` in turn; ``home_from_each``: it may head home
        from any point of it (a mission whose time runs out). A command after it may find the vehicle
        anywhere along it."""
        if not points:
            return
        extra = (self.home,) if home_from_each else ()
        ends = [*self.where, self.centre[-1]]
        self.parts.append(bounded([*self.where, points[0], *extra]))
        self.parts += [bounded([a, b, *extra]) for a, b in zip(points, points[1:], strict=False)]
        self.where = bounded([*ends, *points, *extra])
        self.centre += points

    def follow(self, missions: Mapping[int, Sequence[Point]], start: int) -> None:
        """The rest of its mission from waypoint ``start``, then home: it goes on with it by itself."""
        if self.mission is None:
            return
        if self.mission not in missions:
            raise Unplaced(
                f"{self.name} follows mission {self.mission}, whose waypoints this shore does not have "
                f"(record it: POST /api/v1/vehicles/{{id}}/missions)"
            )
        self.route([*missions[self.mission][start:], self.home], home_from_each=True)
        self.following = True

    # --- commands ---------------------------------------------------------------------------------

    def command(self, c: Steering, missions: Mapping[int, Sequence[Point]]) -> None:
        """What the vehicle does with ``c`` (``vehicle_agent.mission.MissionFSM.on_control``)."""
        kind = Command[c.command.upper()]
        if kind is Command.MOVE:
            heading = self.heading

            def moved(p: Point) -> Point:
                n, e = move_target(p[0], p[1], heading, c.distance, c.angle, c.absolute_angle)
                return (n, e, p[2] + c.depth)

            self.go(moved)
            if c.distance > 0:
                self.heading = c.angle if c.absolute_angle else (heading + c.angle) % 360
            self._resumes(missions)
        elif kind is Command.GOTO_DEPTH:
            self.go(lambda p: (p[0], p[1], c.depth))
            self._resumes(missions)
        elif kind is Command.RETURN_HOME:
            home = self.home
            self.go(lambda _p: home)
            self.mission, self.following = None, False
        elif kind in (Command.HOLD, Command.ABORT_MISSION):
            self.following = False
            if kind is Command.ABORT_MISSION:
                self.mission = None
        elif kind is Command.RESUME:
            self.follow(missions, self.waypoint)
        elif kind is Command.START_MISSION:
            if c.param_id not in missions:
                raise Unplaced(
                    f"{self.name}'s mission {c.param_id} is not recorded on this shore, so its route cannot "
                    "be checked: record it (POST /api/v1/vehicles/{id}/missions) and start it from there"
                )
            self.mission, self.waypoint = c.param_id, 0
            self.follow(missions, 0)
        elif kind is Command.SET_PARAM and c.param_id == Param.LOST_ACTION:
            action = LostAction.of_code(c.param_value)
            if action is not None:
                self.actions.add(action)  # the old one holds until the vehicle has the new one

    def _resumes(self, missions: Mapping[int, Sequence[Point]]) -> None:
        """After a course of its own, a vehicle that followed its mission goes back to it."""
        if self.following:
            self.follow(missions, self.waypoint)

    def then(self, tail: Sequence[Point]) -> None:
        """A team member's waypoints still to come after its commands, one leg each."""
        self.route(tail)

    # --- the result -------------------------------------------------------------------------------

    def done(self) -> Planned:
        """The plan with its lost-link actions from any point of it."""
        parts = tuple(self._lost(part) for part in self.parts)
        actions = tuple(a for a in LostAction if a in self.actions)
        return Planned(self.name, parts, tuple(self.parts), tuple(self.centre), self.radius, actions)

    def _lost(self, part: Region) -> Region:
        extra: list[Point] = []
        if LostAction.SURFACE in self.actions:
            extra += [(p[0], p[1], 0.0) for p in part]
        if LostAction.RETURN in self.actions:
            extra.append(self.home)
        return bounded([*part, *extra]) if extra else part


@dataclass(frozen=True)
class Planned:
    """A vehicle's plan: its parts (hulls of points, with and without its lost-link actions), the line
    through its targets, the uncertainty about its position now and its lost-link actions."""

    name: str
    parts: tuple[Region, ...]
    paths: tuple[Region, ...]  # the parts without the lost-link actions
    centre: tuple[Point, ...]
    radius: float
    lost_actions: tuple[LostAction, ...]

    @property
    def start(self) -> Point:
        return self.centre[0]

    @property
    def end(self) -> Point:
        return self.centre[-1]

    def as_dict(self) -> dict[str, Any]:
        return {
            "vehicle": self.name,
            "start": _rounded(self.start),
            "end": _rounded(self.end),
            "route": [_rounded(p) for p in self.centre],
            "radius_m": round(self.radius, 2),
        }


def _rounded(p: Point) -> list[float]:
    return [round(x, 2) + 0.0 for x in p]


def gap(a: Planned, b: Planned, within: float = math.inf, lost: bool = True) -> float:
    """The smallest distance between a part of ``a`` and a part of ``b`` (``lost``: with their lost-link
    actions), exact when below ``within`` (pairs whose boxes are that far apart are not measured):
    ``within`` or more otherwise."""
    best = within
    for p in a.parts if lost else a.paths:
        for q in b.parts if lost else b.paths:
            if box_gap(p, q) < best:
                best = min(best, hull_gap(p, q))
    return best
