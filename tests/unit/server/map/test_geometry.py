"""The map's views and labels, without a browser: the fitted view shows every point clear of the panel,
zooming out reaches the whole fleet, and close labels are stacked."""

from __future__ import annotations

import itertools
import math

import pytest

from server.map.geometry import LABEL_WIDTH, PLAN_FOV, fit, stack

SPLIT_DEMO = [
    (0.0, 0.0),
    (0.0, 30.0),
    (0.0, 60.0),
    (0.0, -300.0),
    (0.0, 600.0),
]  # three vehicles, two gateways


def on_screen(
    point: tuple[float, float], position: tuple, look_at: tuple, aspect: float
) -> tuple[float, float]:
    """Where a point (north, east) at the surface appears, as shares of the view's width and height from
    its left and bottom edges (straight down, north up)."""
    height = position[2] - 0.0
    seen = 2 * height * math.tan(PLAN_FOV / 2)  # the view's height in metres at the surface
    x = (point[1] - look_at[0]) / (seen * aspect) + 0.5
    y = (point[0] - look_at[1]) / seen + 0.5
    return x, y


@pytest.mark.parametrize("points", [SPLIT_DEMO, [(5.0, 5.0)], [(-400.0, 20.0), (350.0, 10.0)]])
def test_the_fitted_view_shows_every_point_left_of_the_panel(points: list) -> None:
    aspect, panel = 16 / 9, 0.25
    position, look_at, seen = fit(points, aspect=aspect, panel=panel)
    assert seen >= 70.0
    for p in points:
        x, y = on_screen(p, position, look_at, aspect)
        assert 0.0 < x < 1.0 - panel and 0.0 < y < 1.0, f"{p} at {x:.2f}, {y:.2f}"
    assert abs(position[0] - look_at[0]) < 1e-9 and position[2] > 0  # from above, north up


def test_labels_of_close_things_are_stacked_and_far_ones_stay() -> None:
    places = [(0.0, 0.0), (0.5, 3.0), (1.0, 6.0), (0.0, 500.0)]
    lifted = stack(places, 4.0)
    assert lifted[3] == places[3] and lifted[0] == places[0]
    for a, b in itertools.combinations(lifted, 2):
        assert abs(a[1] - b[1]) >= LABEL_WIDTH * 4.0 or abs(a[0] - b[0]) >= 4.0 - 1e-9
    assert [east for _, east in lifted] == [east for _, east in places]  # moved north only
