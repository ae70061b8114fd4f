"""The tick grid: which tick a sample belongs to, and how the vehicle keeps the grid where the sensor samples.

Each stream has a tick period T and a grid phase f (in sixteenths of a tick); a sample taken at time t
belongs to tick k = round(t / T - f / 16), and the shore dates it (k + f / 16) T: **every sample's time
is known to within T / 2** (``StreamSpec.time_precision``), whatever its jitter, and jitter costs no
bits. The phase keeps the grid's ticks where the sensor samples: on a grid half a tick off, each
jittered sample would land in the tick before or after its own (two samples in one tick, then a tick
without one: bits for nothing). START sends the first sample's phase; the vehicle follows the sensor's
phase (a circular mean over about 8 samples) and, when a grid there would misplace fewer samples (a
jittered first sample, a clock that drifts against T), moves the grid with PHASE (``Grid``). Nothing is
dropped: a tick may hold no sample (a dropped message, a blank row, a slower sensor), one, or several (a
burst, duplicate times: each is coded, in order, with the same tick).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PHASE_BITS = 4  # the grid phase in sixteenths of a tick
PHASES = 1 << PHASE_BITS
PHASE_FOLLOW = 1 / 8  # the vehicle follows a sensor's phase and misplacement rates over about 8 samples
PHASE_GAIN = 0.15  # the grid moves to the followed phase when that would misplace 15 % fewer samples ...
PHASE_SURE = 0.4  # ... and the samples agree on it (mean resultant length: 1 for a steady clock, 0.5 for
# +-30 % uniform jitter, ~0.25 for random phases)


def tick(period: float, time: float, phase: int = 0) -> int:
    """The tick a sample taken at ``time`` belongs to, on the grid of ``phase`` (sixteenths)."""
    return round(time / period - phase / PHASES)


def phasor(period: float, time: float) -> complex:
    """Where ``time`` falls within a tick, as a unit phasor (so phases average across the wrap)."""
    return complex(np.exp(2j * np.pi * (time / period % 1.0)))


def nearest_phase(phasor: complex) -> int:
    """The grid phase (sixteenths of a tick) nearest a phasor's angle."""
    return round(float(np.angle(phasor)) / (2 * np.pi) % 1.0 * PHASES) % PHASES


def regrid(cursor: int, phase: int, new: int) -> int:
    """The tick of the grid of phase ``new`` nearest the time of tick ``cursor`` of the grid ``phase``."""
    return cursor + (phase - new + PHASES // 2) // PHASES


def unregrid(cursor: int, phase: int, new: int) -> int:
    """The exact inverse of ``regrid``: the tick of the grid ``phase`` that ``regrid`` takes to ``cursor``
    of the grid ``new``."""
    return cursor - (phase - new + PHASES // 2) // PHASES


@dataclass
class Grid:
    """Where the vehicle puts a stream's ticks. The first sample sets the phase; the vehicle follows the
    sensor's phase (a forgetting circular mean) and how often each grid misplaces a sample (puts two
    consecutive samples a different number of ticks apart than their times are periods apart), and
    moves the grid only when the followed phase misplaces ``PHASE_GAIN`` fewer: a steady clock that
    sits near a tick boundary or drifts is followed; a loose one (intervals from half to one and a half
    periods) misplaces as many samples on any grid, and does not pay for PHASE tokens chasing it."""

    followed: complex  # the sensor's phase, as a phasor (``phasor``) averaged
    phase: int  # the grid's, sixteenths of a tick
    last: float  # the previous sample's time
    misplaced: tuple[float, float] = (0.0, 0.0)  # forgetting rates: on this grid, on the followed phase's

    @classmethod
    def start(cls, period: float, time: float) -> Grid:
        """The grid a stream's first sample, taken at ``time``, sets (ticks ``period`` seconds apart)."""
        here = phasor(period, time)
        return cls(here, nearest_phase(here), time)

    def follow(self, period: float, time: float) -> int | None:
        """Take a sample's time into account; the phase the grid should move to (None: stay)."""
        self.followed += PHASE_FOLLOW * (phasor(period, time) - self.followed)
        candidate = nearest_phase(self.followed)
        apart = round((time - self.last) / period)
        rates = [
            rate + PHASE_FOLLOW * ((tick(period, time, grid) - tick(period, self.last, grid) != apart) - rate)
            for rate, grid in zip(self.misplaced, (self.phase, candidate), strict=True)
        ]
        self.misplaced, self.last = (rates[0], rates[1]), time
        better = rates[0] - rates[1] >= PHASE_GAIN and abs(self.followed) >= PHASE_SURE
        return candidate if candidate != self.phase and better else None

    def move(self, phase: int) -> None:
        self.phase, self.misplaced = phase, (self.misplaced[1], self.misplaced[1])
