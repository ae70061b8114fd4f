"""Version 4's profile prediction (``tacit.codec.profile``): what the last pass in the same direction says."""

from __future__ import annotations

import numpy as np

from tacit.codec.profile import POINTS, Profile


def temperature(depth: float, offset: float = 0.0) -> float:
    return 4 + 6 * float(np.tanh((40 - depth) / 5)) + offset


def dive_and_climb(profile: Profile, offset: float, deep: float = 100.0) -> None:
    """One dive to ``deep`` m and the climb back, a sample every 0.25 m, the water ``offset`` warmer."""
    for depth in [*np.arange(0.0, deep, 0.25), *np.arange(deep, 0.0, -0.25)]:
        profile.update(np.array([temperature(depth, offset), depth]))


def test_a_dive_is_predicted_from_the_last_dive_and_keeps_its_own_offset() -> None:
    """The last dive's change between two depths, added to this dive's last value: the thermocline, which
    no line through the last values follows, is predicted to within its interpolation (a point every
    4 depth steps), and this dive's own offset from the last one carries over."""
    profile = Profile(2, 1, step=0.1)
    assert profile.predict(0, 10.0) is None  # no pass yet
    dive_and_climb(profile, 0.0)
    dive_and_climb(profile, 0.0)
    for depth in np.arange(0.0, 60.0, 0.25):  # a third dive, the water 0.3 warmer
        profile.update(np.array([temperature(depth, 0.3), depth]))
    predicted = profile.predict(0, 60.25)
    assert predicted is not None and abs(predicted - temperature(60.25, 0.3)) < 0.01
    assert profile.predict(0, 150.0) is None  # deeper than the last dive: it does not say
    assert profile.predict(1, 60.25) is None  # the depth channel itself is not predicted by depth


def test_a_pass_keeps_at_most_its_points_and_its_state_round_trips() -> None:
    profile = Profile(2, 1, step=0.01)
    dive_and_climb(profile, 0.0, deep=400.0)
    dive_and_climb(profile, 0.0, deep=400.0)
    assert 0 < len(profile.before) <= POINTS and 0 < len(profile.previous) <= POINTS
    copy = Profile(2, 1, step=0.01)
    copy.restore(profile.state())
    for depth in (5.0, 39.9, 250.0):
        profile.update(np.array([temperature(depth), depth]))
        copy.update(np.array([temperature(depth), depth]))
        assert copy.predict(0, depth + 0.5) == profile.predict(0, depth + 0.5)
    assert profile.predict(0, 200.0) is not None  # the thinned pass still spans the dive
