"""The map's ground: the water (a grid covering the fleet and its gateways), the north and east arrows
with their labels, a depth scale, and the fleet's origin. Labels are anchored away from the origin so
that they never lie across a track near it."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from server.map.geometry import MIN_VIEW

DEPTH_SCALE = (-14.0, -6.0)  # (east, north) of the depth scale: off the side of the area, away from home
DEPTH_LABEL_STEP = 4.0  # metres south between depth labels: apart when seen from above
WATER = 300.0  # m: the water's least width, centred on the origin
WATER_MARGIN = 50.0  # m of water beyond the farthest vehicle or gateway
FADE = 40.0  # the water's grid fades this many of its widths from the camera (beyond a fitted view's height)


def nice(x: float) -> float:
    """The 1, 2, 2.5 or 5 times a power of ten nearest below ``x`` (>= 1): a round step for metre marks."""
    power = 10.0 ** math.floor(math.log10(x))
    return max(m * power for m in (1.0, 2.0, 2.5, 5.0) if m * power <= x)


def water_extent(points: Sequence[tuple[float, float]]) -> tuple[float, float, float, float]:
    """(centre east, centre north, width, height) of water covering ``WATER`` around the origin and every
    point (north, east) with ``WATER_MARGIN``, rounded out to 25 m sections."""
    norths = [p[0] for p in points] + [-WATER / 2, WATER / 2]
    easts = [p[1] for p in points] + [-WATER / 2, WATER / 2]
    south, north = _out(min(norths) - WATER_MARGIN, -1), _out(max(norths) + WATER_MARGIN, 1)
    west, east = _out(min(easts) - WATER_MARGIN, -1), _out(max(easts) + WATER_MARGIN, 1)
    return (west + east) / 2, (south + north) / 2, east - west, north - south


def _out(x: float, side: int) -> float:
    """``x`` rounded away from the centre to a 25 m section."""
    return float(np.ceil(x / 25.0) * 25.0) if side > 0 else float(np.floor(x / 25.0) * 25.0)


class Ground:
    """The ground, drawn at a scale: 1 for a view of ``geometry.MIN_VIEW`` (a vehicle's neighbourhood);
    a wider fitted view draws the arrows, the metre marks and the depth scale as much larger, so that
    seen from as high they stay apart (``rescale``)."""

    def __init__(self, scene: Any, origin: str) -> None:
        self.scene = scene
        self.origin = origin  # the origin's label
        self.extent: tuple[float, float, float, float] | None = None
        self.scale = 1.0

    def build(self) -> None:
        self.scene.set_up_direction("+z")
        self.cover([])
        self._axes()

    def rescale(self, seen: float) -> None:
        """Draw the axes for a view ``seen`` metres high (never smaller than for ``MIN_VIEW``)."""
        scale = max(1.0, seen / MIN_VIEW)
        if abs(scale - self.scale) > 0.05 * self.scale:
            self.scale = scale
            self._axes()

    def _axes(self) -> None:
        scene, k = self.scene, self.scale
        self._depth_scale()
        step = nice(25.0 * k)  # the metre marks' step
        length = 0.48 * step  # the arrows: half way to the first mark, their names clear of it
        arrows = np.array(
            [[[0, 0, 0.05], [0, length, 0.05]], [[0, 0, 0.05], [length, 0, 0.05]]], dtype=np.float32
        )
        scene.add_arrows(
            "/axes/north_east",
            arrows,
            np.array([[200, 20, 20], [40, 40, 40]], dtype=np.uint8),
            shaft_radius=0.12 * k,
            head_radius=0.45 * k,
            head_length=1.2 * k,
        )
        # the axes' names beyond their arrows' tips, the east's a row below the metre marks beside its axis
        scene.add_label(
            "/axes/north", "N (north, +y)", position=(0.0, length + k, 0.3), anchor="bottom-center"
        )
        scene.add_label("/axes/east", "E (east, +x)", position=(length + k, -3 * k, 0.3), anchor="top-left")
        for i, metres in enumerate((step, 2 * step, 4 * step)):
            scene.add_label(
                f"/axes/grid/n{i}", f"{metres:g} m N", position=(-k, metres, 0.1), anchor="center-right"
            )
            scene.add_label(
                f"/axes/grid/e{i}", f"{metres:g} m E", position=(metres, -k, 0.1), anchor="top-center"
            )
        scene.add_label("/home", self.origin, position=(-k, -k, 0.8), anchor="top-right")

    def cover(self, points: Sequence[tuple[float, float]]) -> None:
        """Water under the origin's neighbourhood and every point (north, east)."""
        extent = water_extent(points)
        if extent == self.extent:
            return
        self.extent = extent
        east, north, width, height = extent
        self.scene.add_grid(
            "/water",
            width=width,
            height=height,
            plane="xy",
            position=(east, north, 0.0),
            cell_size=5,
            section_size=25,
            plane_color=(60, 130, 190),
            plane_opacity=0.18,
            cell_color=(150, 180, 210),
            fade_distance=FADE * max(width, height),  # seen from high above, the whole of it
        )

    def _depth_scale(self) -> None:
        """The depth scale, off to the south-west of home (``DEPTH_SCALE``): a vertical line with its labels
        stepped south, one per 10 m, so that seen from above they neither cover each other nor the track."""
        east, north = DEPTH_SCALE[0] * self.scale, DEPTH_SCALE[1] * self.scale
        scene = self.scene
        scene.add_line_segments(
            "/axes/depth",
            np.array([[[east, north, 0], [east, north, -30]]], dtype=np.float32),
            (30, 30, 30),
            thickness=0.08,
        )
        ticks = []
        for step, depth in enumerate((10, 20, 30, 33), start=1):
            at = (east - 0.5 * self.scale, north - DEPTH_LABEL_STEP * self.scale * step, -depth)
            text = "depth" if depth == 33 else f"{depth} m deep"
            scene.add_label(f"/axes/depth/{depth}", text, position=at, anchor="center-right")
            ticks.append([(east, north, -depth), at])
        scene.add_line_segments(
            "/axes/depth/ticks", np.array(ticks, dtype=np.float32), (30, 30, 30), thickness=0.04
        )
