"""The temperature field: samples wait for a check-point, only verified ones are fitted, and the fit
finds the front and the place it knows least."""

from __future__ import annotations

import numpy as np

from server.telemetry.field import KEPT, MIN_SAMPLES, TemperatureField


def front_at_north_20(field: TemperatureField) -> None:
    """Warm water north of 20 m, cold south of it, sampled on a 10 m grid from 0 to 40 m."""
    for north in range(0, 41, 10):
        for east in range(0, 41, 10):
            field.verified((float(north), float(east), 2.0, 20.0 if north < 20 else 24.0))


def test_a_packet_s_samples_wait_for_a_check_point_and_only_trusted_ones_are_kept() -> None:
    field = TemperatureField()
    field.heard(1, [(0.0, 0.0, 2.0, 20.0)])
    field.heard(2, [(0.0, 0.0, 2.0, 40.0)])
    field.heard(3, [(0.0, 0.0, 2.0, 21.0), (1.0, 0.0, 2.0, 21.5)])
    verified, pending = field.samples()
    assert len(verified) == 0 and len(pending) == 4 and field.range() is None
    field.settle([1, 2, 3], trusted=[1])
    verified, pending = field.samples()
    assert list(verified[:, 3]) == [20.0] and len(pending) == 0 and field.range() == (20.0, 20.0)


def test_no_estimate_from_too_few_or_too_close_samples() -> None:
    field = TemperatureField()
    for i in range(MIN_SAMPLES - 1):
        field.verified((float(i * 10), 0.0, 2.0, 20.0))
    assert field.fit() is None  # too few
    close = TemperatureField()
    for i in range(MIN_SAMPLES * 2):
        close.verified((i * 0.1, 0.0, 2.0, 20.0 + i))
    assert close.fit() is None  # all within a metre and a half


def test_the_estimate_follows_the_samples_and_finds_the_front() -> None:
    field = TemperatureField()
    front_at_north_20(field)
    found = field.fit()
    assert found is not None and found.depth == 2.0
    north = found.points[:, 0]
    assert found.mean[north < 5].mean() < 21.0 and found.mean[north > 30].mean() > 23.0
    assert 10.0 < float(np.median(found.front[:, 0])) <= 20.0  # mostly between the 10 and 20 m rows
    assert found.std.min() >= 0.0


def test_the_suggestion_is_where_the_estimate_is_least_sure() -> None:
    field = TemperatureField()
    front_at_north_20(field)
    found = field.fit()
    assert found is not None
    north, east = found.suggestion
    assert float(found.std.max()) == found.std[np.argmax(found.std)]
    nearest = min(np.hypot(north - n, east - e) for n in range(0, 41, 10) for e in range(0, 41, 10))
    assert nearest > 5.0  # away from every sample: at the grid's edge, beyond what was sampled


def test_only_the_newest_samples_are_kept() -> None:
    field = TemperatureField()
    for i in range(KEPT + 10):
        field.verified((0.0, 0.0, 2.0, float(i)))
    verified, _ = field.samples()
    assert len(verified) == KEPT and verified[0, 3] == 10.0
