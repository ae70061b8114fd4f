"""The dual predictors: the vehicle and the shore run the same one on the same information.

Every predictor sees only *reconstructed* values (what the shore holds), never raw measurements, so
both ends compute identical predictions; the quantizer in ``tacit.codec`` then guarantees
|reconstruction - truth| <= eps for every sample. Methods (``make_predictor``):

``kalman`` (default) -- a local-level Kalman filter per channel (filterpy's equations, on the
    diagonals: ``_LocalLevel``): level_k = level_{k-1} + w,
    z_k = level_k + v, Q = q, R = r. Only q/r shapes the prediction; it is tuned from data every
    ``ADAPT_EVERY`` ticks: over the last ``ADAPT_WINDOW`` reconstructed values, each channel takes the
    steady-state gain K from ``GAINS`` with the smallest one-step prediction error, and the filter gets
    q/r = K^2 / (1 - K), the ratio whose steady state has that gain. Gains come from a fixed grid, so
    both ends land on identical filters. A white-noise channel picks a small K (a long running mean);
    a random walk picks a large one (it follows the last value). (The method of moments on first
    differences was tried first: on 64 ticks of real IMU data it overestimates q/r by 4-40x.)
    This is the paper's model-based approach with its equations corrected.
``kalman-cv`` -- a constant-velocity Kalman filter per channel (level and rate), white-noise
    acceleration of intensity q (same adaptive estimate), for smooth kinematic channels.
``mean`` -- the paper's model-free test (Algorithm 1) made dual-consistent: the prediction mu is the
    mean of the last ``MEAN_WINDOW`` reconstructed values; a sample is unpredictable when
    |x - mu| > eps (the quantizer's zero bin), i.e. |X - mu|^2 > T_h with T_h = eps^2.
``hold`` -- the last reconstructed value: send-on-delta's predictor, here with the packet codec.

Before any data the prediction is ``initial`` (per channel). Across ticks without a sample (``skip``)
the Kalman filters predict without update, so their uncertainty grows exactly as it does on the other
side; a gap longer than ``MAX_SKIP`` ticks advances them ``MAX_SKIP`` ticks (both ends alike: the
prediction after a long gap is poor anyway, and a day's gap must not cost a million filter steps).
A channel without a value in a tick (NaN: a blank cell, a sensor slower than the stream) is skipped
for that channel only: the Kalman update leaves its level untouched (zero innovation, R = 1e12), the
window mean and hold ignore it, and the gain tuning leaves it out. ``current`` is the prediction for a
second sample in the same tick (no time passes: the filter is not advanced).

The vehicle (an ARM computer) and the shore (x86) must predict the same values to the bit: every filter
here is element-wise arithmetic on each channel's own numbers and sums taken in a fixed order
(``ordered``), never a BLAS product or a LAPACK inverse, whose results differ by CPU in their last bits.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

ADAPT_EVERY = 16
ADAPT_WINDOW = 64
MEAN_WINDOW = 8
MAX_SKIP = 64
ABSENT_R = 1e12
METHODS = ("kalman", "kalman-cv", "mean", "hold")


class Predictor(Protocol):
    def predict(self) -> np.ndarray:
        """Advance one tick; the prediction for it (one value per channel)."""
        ...

    def current(self) -> np.ndarray:
        """The prediction for another sample in the tick just predicted (no advance)."""
        ...

    def update(self, reconstructed: np.ndarray) -> None:
        """Take the tick's reconstructed values (what the shore holds); NaN = that channel is absent."""
        ...

    def skip(self, ticks: int = 1) -> None:
        """Ticks whose values neither side holds (absent or lost): advance without an update."""
        ...

    def state(self) -> Any:
        """A snapshot that ``restore`` returns to (cheap: arrays, not objects)."""
        ...

    def restore(self, state: Any) -> None: ...


def ordered(terms: list[float], weights: list[float] | None = None) -> float:
    """The sum of ``terms`` (each times its weight, if given), added one by one in index order: the same
    IEEE operations on every CPU and Python (``sum`` compensates since Python 3.12; a BLAS dot product
    blocks and fuses by CPU)."""
    total = 0.0
    if weights is None:
        for term in terms:
            total += term
    else:
        for term, weight in zip(terms, weights, strict=True):
            total += term * weight
    return total


GAINS = np.array([1 / 64, 1 / 32, 1 / 16, 1 / 8, 1 / 4, 1 / 2, 3 / 4, 7 / 8])


def _best_gain(history: np.ndarray) -> np.ndarray:
    """Per channel, the steady-state gain from ``GAINS`` with the smallest one-step prediction error
    over ``history`` (ticks x channels of reconstructed values). Every candidate runs at once."""
    present = ~np.isnan(history)
    first = np.where(
        present.any(axis=0), history[np.argmax(present, axis=0), np.arange(history.shape[1])], 0.0
    )
    level = np.broadcast_to(np.nan_to_num(first), (len(GAINS), history.shape[1])).copy()
    error = np.zeros_like(level)
    gains = GAINS[:, None]
    for row in history[1:]:
        innovation = np.where(np.isnan(row), 0.0, row - level)
        error += innovation * innovation
        level += gains * innovation
    return GAINS[np.argmin(error, axis=0)]


def _ratio_for_gain(gain: np.ndarray) -> np.ndarray:
    """The q/r whose local-level Kalman filter has steady-state gain ``gain``: K^2 / (1 - K)."""
    return gain * gain / (1 - gain)


class _LocalLevel:
    """Every channel's local-level filter (F = H = I, diagonal P, Q and R), kept as the diagonals: filterpy's
    ``KalmanFilter.predict`` and ``update`` restricted to them. Each entry of filterpy's matrix products
    then has a single non-zero term, so these element-wise operations are the same floating-point
    operations on the same numbers, bit for bit (``tests/unit/tacit/test_predict.py`` runs both on random
    series), without nine-by-nine products, an inverse and copies for every sample."""

    def __init__(self, initial: np.ndarray) -> None:
        self.x = np.array(initial, dtype=np.float64)
        self.p = np.full(len(self.x), 1e6)
        self.q = np.zeros(len(self.x))

    def tune(self, ratio: np.ndarray) -> None:
        self.q = ratio.copy()

    def predict(self) -> None:
        self.p = self.p + self.q  # P = F P F' + Q

    def update(self, z: np.ndarray, r: np.ndarray) -> None:
        gain = self.p * (1.0 / (self.p + r))  # K = P H' inv(H P H' + R)
        self.x = self.x + gain * (z - self.x)
        keep = 1.0 - gain  # I - K H
        self.p = keep * self.p * keep + gain * r * gain  # Joseph form: (I-KH) P (I-KH)' + K R K'

    def level(self) -> np.ndarray:
        return self.x

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(x, P) as filterpy holds them (P a matrix), so that a saved state reads the same either way."""
        return self.x.copy(), np.diag(self.p)

    def restore(self, x: np.ndarray, p: np.ndarray) -> None:
        self.x, self.p = np.array(x, dtype=np.float64), np.diag(p).astype(np.float64)


class _ConstantVelocity:
    """Every channel's constant-velocity filter (level and rate, white-noise acceleration of intensity q),
    F = [[1, 1], [0, 1]], H = [1, 0]: the Kalman equations written out on each channel's 2 x 2 covariance
    (``p``: its entries 00, 01, 11), element-wise in a fixed order. State as filterpy would hold it: x
    interleaved (level, rate per channel), P block-diagonal."""

    def __init__(self, initial: np.ndarray) -> None:
        n = len(initial)
        self.x, self.v = np.array(initial, dtype=np.float64), np.zeros(n)
        self.p = np.array([np.full(n, 1e6), np.zeros(n), np.full(n, 1e6)])
        self.q = np.zeros(n)

    def tune(self, ratio: np.ndarray) -> None:
        self.q = ratio.copy()

    def predict(self) -> None:
        p00, p01, p11 = self.p
        self.x = self.x + self.v
        # F P F' + Q, Q = q [[1/3, 1/2], [1/2, 1]]
        self.p = np.array([(p00 + p01) + (p01 + p11) + self.q / 3, p01 + p11 + self.q / 2, p11 + self.q])

    def update(self, z: np.ndarray, r: np.ndarray) -> None:
        p00, p01, p11 = self.p
        s = p00 + r
        k0, k1 = p00 / s, p01 / s  # K = P H' / (H P H' + R)
        innovation = z - self.x
        self.x, self.v = self.x + k0 * innovation, self.v + k1 * innovation
        keep = 1.0 - k0  # Joseph form: (I - K H) P (I - K H)' + K R K'
        a00, a01 = keep * p00, keep * p01
        a10, a11 = p01 - k1 * p00, p11 - k1 * p01
        self.p = np.array(
            [a00 * keep + k0 * r * k0, a01 - a00 * k1 + k0 * r * k1, a11 - a10 * k1 + k1 * r * k1]
        )

    def level(self) -> np.ndarray:
        return self.x

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        n = len(self.x)
        x, p = np.zeros(2 * n), np.zeros((2 * n, 2 * n))
        x[::2], x[1::2] = self.x, self.v
        p[::2, ::2], p[::2, 1::2], p[1::2, ::2], p[1::2, 1::2] = (np.diag(e) for e in self.p[[0, 1, 1, 2]])
        return x, p

    def restore(self, x: np.ndarray, p: np.ndarray) -> None:
        self.x, self.v = np.array(x[::2], dtype=np.float64), np.array(x[1::2], dtype=np.float64)
        self.p = np.array([np.diag(p[::2, ::2]), np.diag(p[::2, 1::2]), np.diag(p[1::2, 1::2])])


class _AdaptiveKalman:
    """A Kalman filter per channel whose Q is re-tuned from the reconstructed series it has seen. R is 1 in
    the filter's own units (only q/r matters for the prediction); an absent channel's update has R =
    ``ABSENT_R`` and no innovation."""

    def __init__(self, kf: _LocalLevel | _ConstantVelocity, channels: int) -> None:
        self.kf = kf
        self.ones = np.ones(channels)
        self.ratio = _ratio_for_gain(np.full(channels, 0.25))
        self.history: deque[np.ndarray] = deque(maxlen=ADAPT_WINDOW)
        self.count = 0
        self.kf.tune(self.ratio)

    def predict(self) -> np.ndarray:
        self.kf.predict()
        return self.current()

    def current(self) -> np.ndarray:
        return self.kf.level().copy()

    def update(self, reconstructed: np.ndarray) -> None:
        values = np.array(reconstructed, dtype=np.float64)
        absent = np.isnan(values)
        if absent.all():
            return
        if absent.any():
            self.kf.update(np.where(absent, self.kf.level(), values), np.where(absent, ABSENT_R, 1.0))
        else:
            self.kf.update(values, self.ones)
        self.history.append(values)
        self.count += 1
        if self.count % ADAPT_EVERY == 0 and len(self.history) >= 8:
            self.ratio = _ratio_for_gain(_best_gain(np.array(self.history)))
            self.kf.tune(self.ratio)

    def skip(self, ticks: int = 1) -> None:
        for _ in range(min(ticks, MAX_SKIP)):
            self.kf.predict()

    def state(self) -> Any:
        x, p = self.kf.state()
        return (x, p, self.ratio.copy(), list(self.history), self.count)

    def restore(self, state: Any) -> None:
        x, p, ratio, history, count = state
        self.kf.restore(x, p)
        self.ratio, self.count = ratio.copy(), count
        self.history = deque(history, maxlen=ADAPT_WINDOW)
        self.kf.tune(self.ratio)


def kalman_level(channels: int, initial: np.ndarray) -> _AdaptiveKalman:
    return _AdaptiveKalman(_LocalLevel(initial), channels)


def kalman_cv(channels: int, initial: np.ndarray) -> _AdaptiveKalman:
    return _AdaptiveKalman(_ConstantVelocity(initial), channels)


class WindowMean:
    """The paper's model-free predictor: mean of the last ``window`` reconstructed values."""

    def __init__(self, channels: int, initial: np.ndarray, window: int = MEAN_WINDOW) -> None:
        self.last = np.array(initial, dtype=np.float64)  # each channel's last value (initial before any)
        self.values: deque[np.ndarray] = deque(maxlen=window)

    def predict(self) -> np.ndarray:
        return self.current()

    def current(self) -> np.ndarray:
        if not self.values:
            return self.last.copy()
        total, count = np.zeros(len(self.last)), np.zeros(len(self.last))
        for values in self.values:  # oldest first: a fixed order
            present = ~np.isnan(values)
            total, count = total + np.where(present, values, 0.0), count + present
        return np.where(count > 0, total / np.maximum(count, 1), self.last)

    def update(self, reconstructed: np.ndarray) -> None:
        values = np.array(reconstructed, dtype=np.float64)
        self.values.append(values)
        self.last = np.where(np.isnan(values), self.last, values)

    def skip(self, ticks: int = 1) -> None:
        pass

    def state(self) -> Any:
        return list(self.values), self.last.copy()

    def restore(self, state: Any) -> None:
        values, last = state
        self.values = deque(values, maxlen=self.values.maxlen)
        self.last = last.copy()


class Hold(WindowMean):
    """Send-on-delta's predictor: the last reconstructed value."""

    def __init__(self, channels: int, initial: np.ndarray) -> None:
        super().__init__(channels, initial, window=1)


def make_predictor(method: str, channels: int, initial: np.ndarray | None = None) -> Predictor:
    start = np.zeros(channels) if initial is None else np.asarray(initial, dtype=np.float64)
    factories: dict[str, Callable[[int, np.ndarray], Predictor]] = {
        "kalman": kalman_level,
        "kalman-cv": kalman_cv,
        "mean": WindowMean,
        "hold": Hold,
    }
    try:
        return factories[method](channels, start)
    except KeyError:
        raise ValueError(f"unknown method {method!r}: one of {', '.join(METHODS)}") from None
