"""The water temperature field as the shore knows it: the samples the vehicles reported, and a
Gaussian-process estimate fitted on the verified ones.

A priority packet's temperatures are *pending* until a check-point settles their packet: trusted, they
join the *verified* samples; forged, decoded on a chain nobody vouched for, or out of every check-point's
reach, they are dropped. A check-point's own temperature is verified as it arrives. The estimate
(``TemperatureField.fit``) is fitted on verified samples only: its mean and standard deviation on a grid
around them, the front (where the mean crosses its median) and the suggested next sample (where the
estimate is least sure). Positions are metres north and east of the fleet's origin, depth in metres.
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

Sample = tuple[float, float, float, float]  # north, east, depth, degC
KEPT = 2000  # verified samples kept (the newest)
FITTED = 400  # the newest verified samples the estimate is fitted on
PENDING_PACKETS = 500  # packets whose samples wait for a check-point (older ones were never covered)
MIN_SAMPLES = 8  # fewer: no estimate
MIN_SPREAD = 2.0  # m: samples closer together than this in both directions give no estimate
MARGIN = 10.0  # m the grid reaches beyond the samples
GRID = 30  # grid points along each direction


@dataclass(frozen=True)
class FieldEstimate:
    """The fitted field on a ``GRID`` x ``GRID`` grid at the samples' median depth: ``points`` (north,
    east) of each grid point, the ``mean`` and ``std`` there (degC), the ``front`` (north, east points
    where the mean crosses its median) and the ``suggestion`` (north, east), the most uncertain point."""

    points: np.ndarray  # (GRID * GRID, 2)
    mean: np.ndarray
    std: np.ndarray
    depth: float
    front: np.ndarray  # (n, 2)
    suggestion: tuple[float, float]


class TemperatureField:
    """The samples (thread-safe: the map's event thread adds, its tick thread fits) and their estimate."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._verified: list[Sample] = []
        self._pending: dict[int, list[Sample]] = {}  # by packet id

    def verified(self, sample: Sample) -> None:
        """A sample vouched for as it arrives (a check-point's own temperature)."""
        with self._lock:
            self._verified.append(sample)
            del self._verified[:-KEPT]

    def heard(self, packet_id: int, samples: Iterable[Sample]) -> None:
        """A packet's samples, pending until a check-point settles the packet."""
        with self._lock:
            self._pending.setdefault(packet_id, []).extend(samples)
            while len(self._pending) > PENDING_PACKETS:
                del self._pending[min(self._pending)]

    def settle(self, packets: Iterable[int], trusted: Iterable[int]) -> None:
        """Settled ``packets``: the samples of the ``trusted`` ones are verified, the others dropped."""
        keep = set(trusted)
        with self._lock:
            for packet_id in packets:
                samples = self._pending.pop(packet_id, [])
                if packet_id in keep:
                    self._verified.extend(samples)
            del self._verified[:-KEPT]

    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        """(verified, pending) as arrays of rows (north, east, depth, degC)."""
        with self._lock:
            verified = np.array(self._verified).reshape(-1, 4)
            pending = np.array([x for s in self._pending.values() for x in s]).reshape(-1, 4)
        return verified, pending

    def range(self) -> tuple[float, float] | None:
        """The verified samples' lowest and highest temperature (the colour scale's range)."""
        verified, _ = self.samples()
        return None if not len(verified) else (float(verified[:, 3].min()), float(verified[:, 3].max()))

    def fit(self) -> FieldEstimate | None:
        """The estimate from the newest ``FITTED`` verified samples; None while there are too few, or
        they all lie within ``MIN_SPREAD`` of each other."""
        verified, _ = self.samples()
        data = verified[-FITTED:]
        if len(data) < MIN_SAMPLES or np.ptp(data[:, :2], axis=0).max() < MIN_SPREAD:
            return None
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import RBF, WhiteKernel

        xy = data[:, :2]
        with warnings.catch_warnings():  # a length scale at its bound is expected for a sharp front: not news
            warnings.simplefilter("ignore", ConvergenceWarning)
            gp = GaussianProcessRegressor(
                RBF(length_scale=10.0, length_scale_bounds=(2.0, 100.0)) + WhiteKernel(0.01), normalize_y=True
            ).fit(xy, data[:, 3])
        lo, hi = xy.min(axis=0) - MARGIN, xy.max(axis=0) + MARGIN
        grid_n, grid_e = np.meshgrid(
            np.linspace(lo[0], hi[0], GRID), np.linspace(lo[1], hi[1], GRID), indexing="ij"
        )
        points = np.column_stack([grid_n.ravel(), grid_e.ravel()])
        mean, std = gp.predict(points, return_std=True)
        best = int(np.argmax(std))
        return FieldEstimate(
            points,
            mean,
            std,
            float(np.median(data[:, 2])),
            _front(grid_n, grid_e, mean.reshape(grid_n.shape)),
            (float(points[best, 0]), float(points[best, 1])),
        )


def _front(grid_n: np.ndarray, grid_e: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """(north, east) midway between grid points north and south of each other where the mean crosses its
    median."""
    field = mean - float(np.median(mean))
    crossings = np.argwhere(np.sign(field[:-1, :]) != np.sign(field[1:, :]))
    return np.array(
        [[(grid_n[i, j] + grid_n[i + 1, j]) / 2, grid_e[i, j]] for i, j in crossings], dtype=float
    ).reshape(-1, 2)
