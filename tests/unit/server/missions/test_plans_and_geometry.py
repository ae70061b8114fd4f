"""The safety functions' geometry, the team missions' lanes and the restructuring rule: pure functions."""

from __future__ import annotations

import math
import random

import pytest

from server.missions.plans import LegCost, PlanError, lanes, restructure, split, sweep
from server.safety.geometry import area, convex_hull, crossings, hull_gap, is_simple, segment_distance

SQUARE = [(0.0, 0.0), (20.0, 0.0), (20.0, 20.0), (0.0, 20.0)]


def test_segment_distance_in_three_dimensions() -> None:
    assert segment_distance((0, 0, 0), (10, 0, 0), (5, -5, 3), (5, 5, 3)) == pytest.approx(
        3.0
    )  # crossing above
    assert segment_distance((0, 0, 0), (10, 0, 0), (0, 4, 0), (10, 4, 0)) == pytest.approx(4.0)  # parallel
    assert segment_distance((0, 0, 0), (10, 0, 0), (13, 4, 0), (20, 4, 0)) == pytest.approx(5.0)  # end to end
    assert segment_distance((1, 1, 1), (1, 1, 1), (0, 0, 0), (2, 2, 2)) == pytest.approx(0.0)  # a point on it
    assert segment_distance((0, 0, 0), (0, 0, 0), (3, 4, 0), (3, 4, 0)) == pytest.approx(5.0)  # two points
    assert segment_distance((0, 0, 0), (10, 0, 0), (20, 0, 0), (30, 0, 0)) == pytest.approx(10.0)  # in line


def test_hulls_and_the_gap_between_hulls_in_three_dimensions() -> None:
    hull = convex_hull([(0, 0), (10, 0), (10, 10), (0, 10), (5, 5)])
    assert sorted(hull) == [(0, 0), (0, 10), (10, 0), (10, 10)]
    assert convex_hull([(1, 1), (1, 1)]) == [(1, 1)]
    square = [(0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (10.0, 10.0, 0.0), (0.0, 10.0, 0.0)]
    assert hull_gap(square, [(5.0, 5.0, 0.0)]) == 0.0  # inside
    assert hull_gap(square, [(5.0, 5.0, 4.0)]) == pytest.approx(4.0)  # above
    assert hull_gap(square, [(13.0, 0.0, 0.0), (13.0, 10.0, 0.0)]) == pytest.approx(3.0)
    assert hull_gap(square, [(-5.0, 4.0, 0.0), (15.0, 6.0, 0.0)]) == 0.0  # crossing
    tetrahedron = [(0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (0.0, 10.0, 0.0), (0.0, 0.0, 10.0)]
    assert hull_gap(tetrahedron, [(1.0, 1.0, 1.0)]) == 0.0
    assert hull_gap(tetrahedron, [(10.0, 10.0, 10.0)]) == pytest.approx(
        math.dist((10, 10, 10), (10 / 3,) * 3)
    )


def test_the_gap_between_two_segments_is_their_distance() -> None:
    rng = random.Random(7)
    for _ in range(500):
        p0, p1, q0, q1 = (tuple(rng.uniform(-10, 10) for _ in range(3)) for _ in range(4))
        assert hull_gap([p0, p1], [q0, q1]) == pytest.approx(segment_distance(p0, p1, q0, q1), abs=1e-6)


def test_polygons() -> None:
    assert area(SQUARE) == 400 and is_simple(SQUARE)
    assert not is_simple([(0, 0), (10, 10), (10, 0), (0, 10)])  # a bow tie
    assert crossings(SQUARE, 5.0) == [0.0, 20.0]
    u = [(0, 0), (30, 0), (30, 20), (20, 20), (20, 10), (10, 10), (10, 20), (0, 20)]  # a U opening east
    assert crossings(u, 5.0) == [0.0, 30.0] and crossings(u, 15.0) == [0.0, 10.0, 20.0, 30.0]
    assert [(lane.east, lane.south, lane.north) for lane in lanes(u, 10.0)] == [
        (5.0, 0.0, 30.0),
        (15.0, 0.0, 10.0),  # each span inside the U is a lane of its own
        (15.0, 20.0, 30.0),
    ]


def test_lanes_cover_the_area_and_split_west_to_east() -> None:
    found = lanes(SQUARE, 5.0)
    assert [lane.east for lane in found] == [2.5, 7.5, 12.5, 17.5]
    assert all((lane.south, lane.north) == (0.0, 20.0) for lane in found)
    groups = split(lanes([(0, 0), (20, 0), (20, 25), (0, 25)], 5.0), 2)
    assert [[lane.east for lane in g] for g in groups] == [[2.5, 7.5, 12.5], [17.5, 22.5]]
    assert sweep(groups[1], 3.0) == [(0.0, 17.5, 3.0), (20.0, 17.5, 3.0), (20.0, 22.5, 3.0), (0.0, 22.5, 3.0)]


@pytest.mark.parametrize(
    ("polygon", "spacing", "vehicles", "says"),
    [
        ([(0, 0), (20, 0), (20, 0), (0, 0)], 5.0, 1, "the area is empty"),
        ([(0, 0), (10, 10)], 5.0, 1, "the area is empty"),
        ([(0, 0), (10, 10), (10, 0), (0, 10)], 2.0, 1, "edges cross"),
        (SQUARE, 30.0, 1, "20 m wide, narrower than one 30 m lane"),
        (SQUARE, 10.0, 3, "holds 2 lanes, fewer than the 3 vehicles"),
    ],
)
def test_bad_areas_say_why(polygon: list, spacing: float, vehicles: int, says: str) -> None:
    with pytest.raises(PlanError, match=says):
        split(lanes(polygon, spacing), vehicles)


def test_a_leg_costs_a_command_and_two_check_points_at_rate_0() -> None:
    cost = LegCost.at(range_m=300.0, sound_speed=1500.0)
    assert cost.bits_down == 3 * 21 + 256 and cost.bits_up == 13 + 2 * 256
    assert 14.0 < cost.channel_s < 16.0  # about 15 s of an 80 bit/s channel per leg


def test_the_restructuring_rule_sends_the_nearest_helpers_to_their_side_of_the_anomaly() -> None:
    anomaly = (10.0, 10.0, 2.0)
    helpers = {"near": (10.0, 30.0, 1.0), "far": (10.0, 90.0, 1.0), "south": (-20.0, 10.0, 1.0)}
    work = restructure(anomaly, helpers, radius=15.0, count=2, apart=5.0)
    assert set(work) == {"near", "south"}  # the two nearest
    assert work["near"] == pytest.approx((10.0, 25.0, 2.0))  # on its own side (east), at the anomaly's depth
    assert work["south"] == pytest.approx((-5.0, 10.0, 2.0))
    same_side = {"a": (10.0, 30.0, 1.0), "b": (10.5, 30.0, 1.0)}
    turned = restructure(anomaly, same_side, radius=15.0, count=2, apart=5.0)
    assert math.dist(turned["a"], turned["b"]) == pytest.approx(5.0)  # turned apart to the separation
    assert all(math.dist(t[:2], anomaly[:2]) == pytest.approx(15.0) for t in turned.values())
    assert restructure(anomaly, {}, 15.0, 2, 5.0) == {}
    assert restructure(anomaly, helpers, 15.0, 0, 5.0) == {}
