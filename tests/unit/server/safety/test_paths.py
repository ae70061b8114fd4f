"""Where the separation check sees a vehicle going (``server.safety.paths``): pure functions."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from server.safety.geometry import hull_gap
from server.safety.paths import MAX_POINTS, Course, Plan, Unplaced, bounded, gap
from tacit.params import LostAction, Param

SQUARE = {1: [(0.0, 0.0, 2.0), (20.0, 0.0, 2.0), (20.0, 20.0, 2.0), (0.0, 20.0, 2.0), (0.0, 0.0, 2.0)]}


@dataclass
class Order:
    """A command as the plan reads it (``CommandIn`` and ``CommandRecord`` have these fields)."""

    command: str
    distance: float = 0.0
    angle: float = 0.0
    depth: float = 0.0
    absolute_angle: bool = True
    param_id: int = 0
    param_value: float = 0.0


def course(**kw: object) -> Course:
    values: dict = {
        "name": "rov1",
        "here": (0.0, 0.0, 2.0),
        "radius": 1.0,
        "heading": 0.0,
        "home": (0.0, 0.0),
        "lost_action": LostAction.HOLD,
    }
    return Course(**{**values, **kw})


def plan(*orders: Order, tail: tuple = (), **kw: object) -> Plan:
    built = Plan.of(course(**kw), SQUARE)
    for order in orders:
        built.command(order, SQUARE)
    built.then(list(tail))
    return built


def near(built: Plan, point: tuple[float, float, float]) -> float:
    """How close the plan comes to ``point``."""
    return min(hull_gap(part, [point]) for part in built.done().parts)


def test_a_second_move_starts_anywhere_along_the_first() -> None:
    """Two moves queued together: the second arrives while the first runs, so it may start anywhere on it:
    the plan holds the whole parallelogram, not only the route through the first move's end."""
    east = Order("move", distance=20.0, angle=90.0)
    north = Order("move", distance=20.0, angle=0.0)
    built = plan(east, north)
    assert built.centre == [
        (0.0, 0.0, 2.0),
        pytest.approx((0.0, 20.0, 2.0)),
        pytest.approx((20.0, 20.0, 2.0)),
    ]
    assert near(built, (10.0, 10.0, 2.0)) == pytest.approx(0.0, abs=1e-9)  # inside the parallelogram
    assert near(built, (10.0, 25.0, 2.0)) == pytest.approx(5.0)
    assert near(plan(east), (10.0, 10.0, 2.0)) == pytest.approx(10.0)


def test_a_relative_move_turns_from_the_heading_the_last_one_left() -> None:
    built = plan(
        Order("move", distance=10.0, angle=90.0),
        Order("move", distance=10.0, angle=90.0, absolute_angle=False),
    )
    assert built.centre[-1] == pytest.approx((-10.0, 10.0, 2.0))  # east, then a right turn: south


def test_a_mission_is_its_route_then_home_from_anywhere_on_it() -> None:
    started = plan(Order("start_mission", param_id=1), here=(-10.0, 10.0, 0.0))
    assert started.centre[1:] == [*SQUARE[1], (0.0, 0.0, 0.0)]
    assert near(started, (20.0, 10.0, 2.0)) == pytest.approx(0.0)
    assert near(started, (10.0, 10.0, 1.0)) == pytest.approx(0.0, abs=1e-9)  # home from the far side
    assert near(started, (10.0, -5.0, 2.0)) == pytest.approx(5.0)
    with pytest.raises(Unplaced, match="mission 7 is not recorded"):
        plan(Order("start_mission", param_id=7))


def test_a_resume_and_a_command_under_a_mission_go_back_to_its_route() -> None:
    following = course(steering=(20.0, 0.0, 2.0), mission=1, waypoint=2, following=True)  # on to waypoint 1
    built = Plan.of(following, SQUARE)
    assert built.centre == [(0.0, 0.0, 2.0), (20.0, 0.0, 2.0), *SQUARE[1][2:], (0.0, 0.0, 0.0)]
    held = Plan.of(following, SQUARE)
    held.command(Order("hold"), SQUARE)
    held.command(Order("move", distance=5.0, angle=180.0), SQUARE)
    assert held.centre[-1] == pytest.approx((-5.0, 0.0, 0.0))  # held: it does not go back by itself
    held.command(Order("resume"), SQUARE)
    assert held.centre[-1] == (0.0, 0.0, 0.0)  # resumed: the rest of the square, then home
    aborted = Plan.of(following, SQUARE)
    aborted.command(Order("abort_mission"), SQUARE)
    aborted.command(Order("resume"), SQUARE)  # the vehicle refuses it: no mission
    assert aborted.centre[-1] == (0.0, 0.0, 0.0) and len(aborted.parts) == len(built.parts)
    with pytest.raises(Unplaced, match="follows mission 3"):
        Plan.of(course(mission=3, following=True), SQUARE)


def test_the_lost_link_action_reaches_from_every_part() -> None:
    lanes = ((0.0, 40.0, 2.0), (40.0, 40.0, 2.0))
    holding = plan(tail=lanes, home=(0.0, 100.0))
    assert near(holding, (20.0, 100.0, 2.0)) == pytest.approx(60.0)
    returning = plan(tail=lanes, home=(0.0, 100.0), lost_action=LostAction.RETURN)
    assert near(returning, (20.0, 70.0, 1.0)) == pytest.approx(0.0, abs=1e-9)  # on the way home from a lane
    surfacing = plan(tail=lanes, lost_action=LostAction.SURFACE)
    assert near(surfacing, (20.0, 40.0, 0.0)) == pytest.approx(0.0)
    assert near(plan(tail=lanes), (20.0, 40.0, 0.0)) == pytest.approx(2.0)
    code = float(LostAction.RETURN.code)
    changed = plan(
        Order("set_param", param_id=int(Param.LOST_ACTION), param_value=code), tail=lanes, home=(0.0, 100.0)
    )
    assert changed.done().lost_actions == (LostAction.HOLD, LostAction.RETURN)  # both: until it has the new
    assert near(changed, (20.0, 70.0, 1.0)) == pytest.approx(0.0, abs=1e-9)


def test_a_part_of_many_points_is_the_box_around_them() -> None:
    points = [(float(k), float(k % 3), 1.0) for k in range(40)]
    box = bounded(points)
    assert len(box) == 8 and {p[0] for p in box} == {0.0, 39.0} and {p[1] for p in box} == {0.0, 2.0}
    assert bounded(points[:MAX_POINTS]) == tuple(points[:MAX_POINTS])


def test_the_gap_between_plans_is_measured_as_far_as_asked() -> None:
    a = plan(Order("move", distance=20.0, angle=90.0)).done()
    b = plan(here=(8.0, 10.0, 2.0)).done()
    assert gap(a, b) == pytest.approx(8.0)
    assert gap(a, b, within=5.0) == 5.0  # farther than asked: not measured exactly
    assert gap(a, b, lost=False) == pytest.approx(8.0)
