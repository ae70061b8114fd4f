"""The map panel's logic without a browser: where a click lands, the command it fills in, the limits."""

from __future__ import annotations

import pytest

from server.commands.schemas import CommandIn
from server.commands.service import CommandRefused, check_limits
from server.map.geometry import move_to, ray_to_depth_plane
from server.vehicles.models import Vehicle
from tacit.navigation import Pose

VEHICLE = Vehicle(
    name="rov1", address=2, key_hex="00" * 32, max_depth=20.0, max_distance=50.0, geofence_radius=100.0
)


def test_a_ray_lands_on_the_water_surface_or_a_depth_plane() -> None:
    camera = (10.0, -20.0, 30.0)  # x = east, y = north, z = up
    looking = (0.0, 0.5, -1.0)
    assert ray_to_depth_plane(camera, looking, 0.0) == pytest.approx((-5.0, 10.0))  # (north, east)
    assert ray_to_depth_plane(camera, looking, 10.0) == pytest.approx((0.0, 10.0))
    assert ray_to_depth_plane(camera, (0.0, 1.0, 0.0), 0.0) is None  # parallel: never meets it
    assert ray_to_depth_plane(camera, (0.0, 0.0, 1.0), 0.0) is None  # looking up: behind the camera


@pytest.mark.parametrize(
    "pose, point, absolute, expected",
    [
        (Pose(0, 0, 2, 0), (10, 0, 2), False, (10.0, 0.0, 0.0)),  # straight ahead
        (Pose(0, 0, 2, 90), (10, 0, 2), False, (10.0, -90.0, 0.0)),  # heading east, target north: turn left
        (Pose(0, 0, 2, 90), (10, 0, 5), True, (10.0, 0.0, 3.0)),  # as a bearing; 3 m deeper
        (Pose(5, 5, 1, 180), (5, -5, 1), False, (10.0, 90.0, 0.0)),  # heading south, target west: turn right
    ],
)
def test_clicked_point_becomes_distance_angle_and_depth(
    pose: Pose, point: tuple, absolute: bool, expected: tuple
) -> None:
    command = move_to(pose, *point, absolute=absolute)
    assert (command.command, command.absolute_angle) == ("move", absolute)
    assert (command.distance, command.angle, command.depth) == pytest.approx(expected)


def refusal(command: CommandIn, pose: Pose | None) -> str | None:
    try:
        check_limits(command, VEHICLE, pose)
    except CommandRefused as exc:
        return f"{exc.field}: {exc}"
    return None


def test_limits_refuse_a_clicked_target_with_the_field_and_reason() -> None:
    here = Pose(0, 0, 2, 0)
    assert refusal(move_to(here, 30, 0, 2), here) is None
    assert "distance" in refusal(move_to(here, 80, 0, 2), here)  # more than 50 m per move
    assert "geofence" in refusal(move_to(Pose(90, 0, 2, 0), 130, 0, 2), Pose(90, 0, 2, 0))
    assert "depth" in refusal(move_to(here, 5, 0, 25), here)
    assert "depth" in refusal(CommandIn(command="goto_depth", depth=30), None)
