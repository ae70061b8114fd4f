"""What both ends agree on for a stream: its channels, error bounds, tick period and predictor.

Quantisation. For channel c with error bound eps_c, the vehicle sends q = round((x - p) / s) with p the
dual prediction (``tacit.codec.prediction``) and s = 2 eps_c (1 - 1e-9); the shore reconstructs
p + q s, so |reconstruction - x| <= eps_c for every present sample (the 1e-9 margin absorbs
floating-point rounding). q = 0 is the paper's "predictable" verdict. A channel's first value is
quantised on steps of s / 16 (``tacit.codec.prediction.FIRST_FINE``: within eps / 16). A channel may be absent from a
sample (NaN, a blank cell): the shore stores it as absent (NaN / None), never as a made-up value, and
the predictors skip it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacit.codec import grid
from tacit.packets import Stream
from tacit.predict import Predictor, make_predictor

MARGIN = 1 - 1e-9


@dataclass(frozen=True)
class StreamSpec:
    """What both ends agree on for one stream of samples."""

    name: str
    stream: Stream
    channels: tuple[str, ...]
    eps: tuple[float, ...]
    period: float
    method: str = "kalman"
    initial: tuple[float, ...] | None = None
    cross: bool = True  # predict each channel's residual from the channels coded before it (``Dual``)
    time_tolerance: float | None = None  # s; version 4 dates each sample within this (None: period / 2)
    depth: str | None = None  # the channel that is the vehicle's depth (or pressure): version 4's profiles

    def __post_init__(self) -> None:
        if len(self.eps) != len(self.channels):
            raise ValueError("one eps per channel")
        if any(not e > 0 for e in self.eps):
            raise ValueError("every eps must be positive")
        if not self.period > 0:
            raise ValueError("period must be positive")
        if self.time_tolerance is not None and not self.time_tolerance >= 0:
            raise ValueError("time_tolerance must be at least 0")
        if self.depth is not None and self.depth not in self.channels:
            raise ValueError(f"depth channel {self.depth!r} is not one of the stream's channels")

    @property
    def step(self) -> np.ndarray:
        return 2 * np.asarray(self.eps, dtype=np.float64) * MARGIN

    @property
    def time_precision(self) -> float:
        """The shore dates every sample to within this many seconds: half a tick, or (version 4) the
        stream's time tolerance, where the vehicle dates a sample on the tick after the last sample's
        rather than its nearest, to keep a wandering clock's samples a tick apart."""
        return self.period / 2 if self.time_tolerance is None else max(self.time_tolerance, self.period / 2)

    def predictor(self) -> Predictor:
        return make_predictor(
            self.method, len(self.channels), None if self.initial is None else np.array(self.initial)
        )

    def tick(self, time: float, phase: int = 0) -> int:
        """The tick a sample taken at ``time`` belongs to, on the grid of ``phase`` (sixteenths)."""
        return grid.tick(self.period, time, phase)
