"""The operator panel's logic, without a browser: where a click lands, and what command it makes.

Scene frame: x = east, y = north, z = up (z = -depth), metres from home. A click in viser is a ray;
it lands where the ray meets the water surface or the chosen depth plane.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

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


MARGIN = 0.3  # a fitted view's margin around what it shows, as a share of their extent
MIN_VIEW = 70.0  # m: the narrowest fitted view (a single vehicle and its neighbourhood)


def top_down(north: float, east: float, height: float = 330.0) -> tuple[Point, Point]:
    """(camera position, look-at point) looking straight down on (north, east), north up on screen (the
    camera sits a little south: exactly overhead, "up" on screen would be undefined). With
    ``PLAN_FOV`` it shows about ``height`` / 4.8 m of the area."""
    return (east, north - height / 66.0, height), (east, north, -2.0)


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


LABEL_WIDTH = 8.0  # a label's width in label heights (a name, a state, a heading and an age)


def stack(places: Sequence[tuple[float, float]], gap: float) -> list[tuple[float, float]]:
    """Where to put the labels of things at ``places`` (north, east) so that no two overlap, seen from
    above: a label is ``gap`` high and ``LABEL_WIDTH`` gaps wide; from the southernmost up, each stays at
    its own place or moves north until it clears those placed before it."""
    placed: dict[int, tuple[float, float]] = {}
    for i in sorted(range(len(places)), key=lambda i: (places[i][0], places[i][1])):
        north, east = places[i]
        clash = True
        while clash:
            clash = False
            for other_north, other_east in placed.values():
                if abs(other_east - east) < LABEL_WIDTH * gap and abs(other_north - north) < gap:
                    north, clash = other_north + gap, True
        placed[i] = (north, east)
    return [placed[i] for i in range(len(places))]


def fit(
    points: Sequence[tuple[float, float]], fov: float = PLAN_FOV, aspect: float = 16 / 9, panel: float = 0.25
) -> tuple[Point, Point, float]:
    """The top-down view that shows every point (north, east) with a margin around them, north up:
    (camera position, look-at point, the height of the view in metres at the water). The view's right
    ``panel`` share is left free for the map's panel (the points sit in the rest); ``aspect``: the
    view's width over its height."""
    norths, easts = [p[0] for p in points] or [0.0], [p[1] for p in points] or [0.0]
    usable = aspect * (1.0 - panel)  # the free part's width over the view's height
    span = max(max(norths) - min(norths), (max(easts) - min(easts)) / usable, MIN_VIEW / (1 + MARGIN))
    seen = span * (1 + MARGIN)
    centre_north, centre_east = (max(norths) + min(norths)) / 2, (max(easts) + min(easts)) / 2
    look_east = centre_east + aspect * seen * panel / 2  # the free part's centre on the points' centre
    height = seen / 2 / math.tan(fov / 2)
    position, look_at = top_down(centre_north, look_east, height)
    return position, look_at, seen


def far_plane(height: float) -> float:
    """The camera's far clipping distance for a view from ``height``: room to zoom out four times."""
    return max(1000.0, 5.0 * height)
