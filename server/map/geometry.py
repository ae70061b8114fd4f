"""The operator panel's logic, without a browser: where a click lands, and what command it makes.

Scene frame: x = east, y = north, z = up (z = -depth), metres from home. A click in viser is a ray;
it lands where the ray meets the water surface or the chosen depth plane.
"""

from __future__ import annotations

import math

from server.commands.schemas import CommandIn
from tacit import navigation
from tacit.navigation import Pose
from tacit.packets import ControlPacket

Point = tuple[float, float, float]


def ray_to_depth_plane(
    origin: tuple[float, float, float], direction: tuple[float, float, float], depth: float
) -> tuple[float, float] | None:
    """(north, east) where the ray meets the horizontal plane at ``depth``; None if it never does."""
    z = -depth
    if abs(direction[2]) < 1e-9:
        return None
    t = (z - origin[2]) / direction[2]
    if t <= 0:
        return None
    return origin[1] + t * direction[1], origin[0] + t * direction[0]


PLAN_FOV = math.radians(12.0)  # top-down: high and narrow, near a plan (depth barely shifts what is deep)
OBLIQUE_FOV = math.radians(75.0)  # viser's default


def top_down(north: float, east: float, height: float = 330.0) -> tuple[Point, Point]:
    """(camera position, look-at point) looking straight down on (north, east), north up on screen (the
    camera sits a few metres south: exactly overhead, "up" on screen would be undefined). With
    ``PLAN_FOV`` it shows about 70 m of the area."""
    return (east, north - 5.0, height), (east, north, -2.0)


def move_to(pose: Pose, north: float, east: float, depth: float, absolute: bool = False) -> CommandIn:
    """The control packet that takes the vehicle from ``pose`` to a point: distance, angle, depth change."""
    distance, angle = navigation.distance_and_angle(
        pose.north, pose.east, pose.heading, north, east, absolute
    )
    return CommandIn(
        command="move",
        distance=round(min(distance, ControlPacket.field("distance").hi), 1),
        angle=round(angle, 2),
        depth=round(depth - pose.depth, 2),
        absolute_angle=absolute,
    )
