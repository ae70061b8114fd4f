"""The local-level Kalman filter the codec predicts with is filterpy's, bit for bit: the shore and a vehicle
running another version must make the same predictions, or every value after the first difference decodes
wrong."""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from tacit.predict import ABSENT_R, _ConstantVelocity, _LocalLevel


def _filterpy_level(initial: np.ndarray) -> KalmanFilter:
    """The local-level filter as filterpy runs it: F = H = I, P = 1e6 I."""
    n = len(initial)
    kf = KalmanFilter(dim_x=n, dim_z=n)
    kf.F, kf.H = np.eye(n), np.eye(n)
    kf.x = np.array(initial, dtype=np.float64)
    kf.P *= 1e6
    return kf


@pytest.mark.parametrize("seed", range(8))
def test_local_level_is_filterpy_bit_for_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 13))
    initial = rng.normal(0, 10.0 ** rng.integers(-3, 6), n)
    ours, theirs = _LocalLevel(initial), _filterpy_level(initial)
    for step in range(600):
        if step % 16 == 0:  # the adaptive tuning's ratios, from tiny to large gains
            ratio = 10.0 ** rng.uniform(-6, 2, n)
            ours.tune(ratio)
            theirs.Q = np.kron(np.diag(ratio), np.array([[1.0]]))
        for _ in range(int(rng.choice([1, 1, 1, 2, 5]))):
            ours.predict()
            theirs.predict()
        scale = 10.0 ** rng.choice([-3, 0, 2, 6, 100])  # a glitch may be fed at the clip, 1e100
        values = rng.normal(ours.x, scale)
        absent = rng.random(n) < 0.2
        if absent.any():
            z, r = np.where(absent, ours.x, values), np.where(absent, ABSENT_R, 1.0)
            theirs.update(np.where(absent, theirs.x, values), R=np.diag(r))
        else:
            z, r = values, np.ones(n)
            theirs.update(values)
        ours.update(z, r)
        x, p = ours.state()
        assert np.array_equal(x, theirs.x) and np.array_equal(p, theirs.P), f"differ at step {step}"


def test_a_state_saved_by_either_restores_the_same_filter() -> None:
    rng = np.random.default_rng(0)
    ours = _LocalLevel(np.zeros(3))
    ours.tune(np.full(3, 0.1))
    for _ in range(5):
        ours.predict()
        ours.update(rng.normal(0, 1, 3), np.ones(3))
    x, p = ours.state()
    assert p.shape == (3, 3) and np.array_equal(p, np.diag(np.diag(p)))
    again = _LocalLevel(np.ones(3))
    again.restore(x, p)
    assert np.array_equal(again.x, ours.x) and np.array_equal(again.p, ours.p)


def test_constant_velocity_filter_is_the_kalman_filter() -> None:
    """The constant-velocity filter written out per channel makes filterpy's predictions (to rounding:
    filterpy's matrix products run on BLAS kernels that round differently on each CPU)."""
    rng = np.random.default_rng(3)
    n = 4
    ours = _ConstantVelocity(np.zeros(n))
    theirs = KalmanFilter(dim_x=2 * n, dim_z=n)
    theirs.F = np.kron(np.eye(n), np.array([[1.0, 1.0], [0.0, 1.0]]))
    theirs.H = np.kron(np.eye(n), np.array([[1.0, 0.0]]))
    theirs.x, theirs.P = np.zeros(2 * n), theirs.P * 1e6
    for step in range(300):
        if step % 16 == 0:
            ratio = 10.0 ** rng.uniform(-4, 1, n)
            ours.tune(ratio)
            theirs.Q = np.kron(np.diag(ratio), np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]]))
        ours.predict()
        theirs.predict()
        r = np.where(rng.random(n) < 0.2, ABSENT_R, 1.0)
        z = np.where(r == 1.0, 0.01 * step**2 + rng.normal(0, 1, n), ours.level())
        ours.update(z, r)
        theirs.update(z, R=np.diag(r))
        x, p = ours.state()
        assert np.allclose(x, theirs.x, rtol=1e-9, atol=1e-9)
        assert np.allclose(p, theirs.P, rtol=1e-6, atol=1e-9)
    restored = _ConstantVelocity(np.zeros(n))
    restored.restore(*ours.state())
    assert all(np.array_equal(a, b) for a, b in zip(restored.state(), ours.state(), strict=True))
