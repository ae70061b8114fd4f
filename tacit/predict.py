"""The dual predictors: the vehicle and the shore run the same one on the same information.

Every predictor sees only *reconstructed* values (what the shore holds), never raw measurements, so
both ends compute identical predictions; the quantizer in ``tacit.codec`` then guarantees
|reconstruction - truth| <= eps for every sample. Methods (``make_predictor``):

``kalman`` (default) -- a local-level Kalman filter per channel (filterpy): level_k = level_{k-1} + w,
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
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
from filterpy.kalman import KalmanFilter

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


class _AdaptiveKalman:
    """A filterpy Kalman filter whose Q is re-tuned from the reconstructed series it has seen."""

    def __init__(self, kf: KalmanFilter, channels: int, initial: np.ndarray, order: int) -> None:
        self.kf, self.channels, self.order = kf, channels, order
        self.kf.x = np.zeros(channels * order)
        self.kf.x[::order] = initial
        self.kf.P *= 1e6
        self.ratio = _ratio_for_gain(np.full(channels, 0.25))
        self.history: deque[np.ndarray] = deque(maxlen=ADAPT_WINDOW)
        self.count = 0
        self._set_noise()

    def _set_noise(self) -> None:
        # R is 1 in the filter's own units; only q/r matters for the prediction.
        self.kf.R = np.eye(self.channels)
        block = np.array([[1.0]]) if self.order == 1 else np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]])
        self.kf.Q = np.kron(np.diag(self.ratio), block)

    def predict(self) -> np.ndarray:
        self.kf.predict()
        return self.current()

    def current(self) -> np.ndarray:
        return self.kf.x[:: self.order].copy()

    def update(self, reconstructed: np.ndarray) -> None:
        values = np.array(reconstructed, dtype=np.float64)
        absent = np.isnan(values)
        if absent.all():
            return
        if absent.any():
            level = self.kf.x[:: self.order]
            self.kf.update(np.where(absent, level, values), R=np.diag(np.where(absent, ABSENT_R, 1.0)))
        else:
            self.kf.update(values)
        self.history.append(values)
        self.count += 1
        if self.count % ADAPT_EVERY == 0 and len(self.history) >= 8:
            self.ratio = _ratio_for_gain(_best_gain(np.array(self.history)))
            self._set_noise()

    def skip(self, ticks: int = 1) -> None:
        for _ in range(min(ticks, MAX_SKIP)):
            self.kf.predict()

    def state(self) -> Any:
        return (self.kf.x.copy(), self.kf.P.copy(), self.ratio.copy(), list(self.history), self.count)

    def restore(self, state: Any) -> None:
        x, p, ratio, history, count = state
        self.kf.x, self.kf.P, self.ratio, self.count = x.copy(), p.copy(), ratio.copy(), count
        self.history = deque(history, maxlen=ADAPT_WINDOW)
        self._set_noise()


def kalman_level(channels: int, initial: np.ndarray) -> _AdaptiveKalman:
    kf = KalmanFilter(dim_x=channels, dim_z=channels)
    kf.F = np.eye(channels)
    kf.H = np.eye(channels)
    return _AdaptiveKalman(kf, channels, initial, order=1)


def kalman_cv(channels: int, initial: np.ndarray) -> _AdaptiveKalman:
    kf = KalmanFilter(dim_x=2 * channels, dim_z=channels)
    kf.F = np.kron(np.eye(channels), np.array([[1.0, 1.0], [0.0, 1.0]]))
    kf.H = np.kron(np.eye(channels), np.array([[1.0, 0.0]]))
    return _AdaptiveKalman(kf, channels, initial, order=2)


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
        window = np.array(self.values)
        present = ~np.isnan(window)
        count = present.sum(axis=0)
        total = np.where(present, window, 0.0).sum(axis=0)
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
