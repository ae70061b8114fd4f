"""The map's tracks layer: each vehicle's reported track (its check-points, a line in its colour) and
the packets heard, as dots above where the vehicle last reported, coloured by priority."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from server.core.events import PacketHeard

PRIORITY_COLOURS = {0: (70, 130, 230), 1: (240, 200, 40), 2: (245, 130, 30), 3: (220, 30, 30)}
MARKERS = 500  # the newest packets drawn
Rgb = tuple[int, int, int]
Point = tuple[float, float, float]


def segments(points: list[Point]) -> np.ndarray:
    """Consecutive points as line segments (viser's ``add_line_segments``)."""
    return np.array([[a, b] for a, b in zip(points[:-1], points[1:], strict=True)], dtype=np.float32)


class TrackLayer:
    def __init__(self, scene: Any, colour: Callable[[str], Rgb]) -> None:
        self.scene = scene
        self.colour = colour
        self.tracks: dict[str, list[Point]] = {}  # by vehicle name, scene points (east, north, -depth)
        self.markers: list[tuple[float, float, float, int]] = []

    def checkpoint(self, name: str, cp: dict[str, Any]) -> None:
        track = self.tracks.setdefault(name, [])
        track.append((cp["east"], cp["north"], -cp["depth"]))
        if len(track) >= 2:
            self.scene.add_line_segments(
                f"/tracks/{name}/actual", segments(track), self.colour(name), thickness=0.15
            )

    def heard(self, event: PacketHeard, where: dict[str, Any] | None) -> None:
        """A packet at ``where`` (its vehicle's last check-point; none yet: not drawn)."""
        if where is None:
            return
        self.markers.append((where["east"], where["north"], -where["depth"], event.priority))
        del self.markers[:-MARKERS]
        points = np.array([m[:3] for m in self.markers], dtype=np.float32)
        colours = np.array([PRIORITY_COLOURS[m[3]] for m in self.markers], dtype=np.uint8)
        self.scene.add_point_cloud(
            "/markers",
            points + np.array([0, 0, 0.4], dtype=np.float32),
            colours,
            point_size=0.5,
            point_shape="circle",
        )
