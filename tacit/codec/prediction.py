"""The dual predictor both ends run per stream: the channel's own predictor plus a cross-channel term.

p is the channel's predictor (``tacit.predict``) plus a cross-channel term (``Dual``): channels are coded
in order, and channel c's residual is predicted by a ridge regression on the residuals of the channels
already coded in the same sample and on the previous sample's residuals, fitted on reconstructions (so
both ends hold the same coefficients), used by a channel only while it has lately cut its squared error
by 10 %. Each channel predicts with a held value instead (hold: send-on-delta's predictor, the last
reconstruction moved no further than it must) while that would lately have missed (|value - prediction|
> eps) less than half as often as its own, or no more often while both have missed about once or never
(a stream starts on hold, and a first surprise both missed does not leave it on a lagging Kalman filter
for another; a channel's first value neither predicted is not counted): a slow profiling sensor's drift and a quantised sensor's
dither are followed by hold, noise by the Kalman filter, and both ends choose alike from reconstructions,
so the choice costs no bits. Both ends feed the reconstruction, not the raw value, back into the
predictor; a single value sent raw (a glitch, ``tacit.codec.grammar.RawValue``) is not given to the
predictor, a second one in a row is (a real jump). A channel's first value is coded on steps
``FIRST_FINE`` of the usual (``Dual.fine``), so what later values are predicted from is within eps / 16 of
the truth, not up to eps.

Payload version 4 (``tacit.codec.versions``) adds a third prediction per channel, the line through its last
three values fed (``x1 + (x1 - x3) / 2``: half the noise of the line through the last two, which cost 4 %
more bits on a SeaExplorer CTD), used while it has lately missed less often and by less (squared error in
steps, capped at ``TREND_FAR``) than the prediction it would replace, both by a margin ``TREND_USE``.
In a stream with a depth channel, version 4 may also predict a channel from the vehicle's last pass at
this depth (``tacit.codec.profile``), as a correction in place of the cross-channel one, while that has
lately (``PROFILE_FORGET``) erred less by the same margin.

Both ends must compute every prediction to the bit, on a vehicle's ARM and a shore's x86 alike: the
arithmetic here is element-wise operations and sums in a fixed order (``tacit.predict.ordered``), with a
small solver of its own (``_solve``), never a BLAS product or a LAPACK solve, whose kernels differ by CPU
(with or without fused multiply-add, other blockings) and so by ulps.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from tacit.codec.profile import Profile
from tacit.codec.versions import Coding
from tacit.predict import ordered

if TYPE_CHECKING:
    from tacit.codec.spec import StreamSpec

FEED_LIMIT = 1e100  # the predictors see values clipped to +-this (both ends), so they stay finite
CROSS_FORGET = 1 - 1 / 256  # the regression's memory: about 256 samples
CROSS_REFIT = 4  # samples between refits of the coefficients
CROSS_CLIP = 3.0  # residuals (in steps) enter the regression clipped to +-this (a jump must not dominate)
CROSS_RIDGE = 0.05  # ridge, as a fraction of the mean residual power
CROSS_USE = 0.9  # a channel uses the correction while it has cut its squared error by 10 % lately
CROSS_MIN_R2 = 0.1  # a channel whose fit explains less of its residual power is predicted without it
HOLD_FORGET = 1 - 1 / 32  # the predictor choice's memory: about 32 samples
HOLD_USE = 0.5  # a channel holds while hold would lately have missed less than half as often as its own
HOLD_MISS = 0.99  # a step (2 eps), less a margin for rounding: a prediction this far off certainly missed
TREND_USE = 0.8  # version 4: a channel extends its last line while that has lately done 20 % better
TREND_FAR = 64.0  # ... its squared errors (in steps) counted up to this
PROFILE_FORGET = 1 - 1 / 4  # version 4: the profile's choice remembers about 4 samples (a thermocline
# is crossed in tens of samples; 32 lagged it, on a Slocum glider's CTD 2 % more bits)
HOLD_SLACK = 0.75  # ... or missed at most as often while both have missed about once or never (a tie)
FIRST_FINE = 1 / 16  # a channel's first value is coded on steps this much finer (within eps / 16)


def _feed(values: np.ndarray) -> np.ndarray:
    """What the predictors are given (both ends): the reconstruction, clipped so they stay finite."""
    return np.clip(values, -FEED_LIMIT, FEED_LIMIT)


def _eliminate(a: np.ndarray) -> np.ndarray:
    """Gaussian elimination without pivoting (``a`` symmetric positive definite), element-wise in a fixed
    order: the upper triangle U, and above the diagonal of each column m, U[:m, m] = L^-1 a[:m, m]
    (each leading block's solve of the next column needs only a back substitution)."""
    a = a.copy()
    for k in range(len(a) - 1):
        factor = a[k + 1 :, k] / a[k, k]
        a[k + 1 :, k + 1 :] = a[k + 1 :, k + 1 :] - factor[:, None] * a[k, k + 1 :]
    return a


def _back(rows: list[list[float]], m: int) -> list[float]:
    """x with U[:m, :m] x = U[:m, m], U upper triangular (``_eliminate``'s rows): back substitution in a
    fixed order."""
    x = [0.0] * m
    for k in range(m - 1, -1, -1):
        row = rows[k]
        x[k] = (row[m] - ordered(row[k + 1 : m], x[k + 1 :])) / row[k]
    return x


class Dual:
    """A stream's predictor as both ends run it: the per-channel predictor (``tacit.predict``), and on top
    a cross-channel prediction of the residual. Channels are coded in order; channel c's prediction is
    the predictor's plus sum_j<c beta_cj z_j step_c, z_j = (reconstruction_j - prediction_j) / step_j of
    the channels already coded in the same sample (0 if absent). beta is a ridge regression of each z_c
    on the earlier z, over exponentially forgotten sums, refitted every ``CROSS_REFIT`` samples: from
    reconstructions only, so both ends hold the same coefficients. A value sent raw (a glitch) is not
    given to the predictor unless the channel's previous value was raw too (a real jump is learnt)."""

    def __init__(self, spec: StreamSpec, coding: Coding | None = None) -> None:
        n = len(spec.channels)
        self.trend = coding is not None and coding.trend
        self.lines = np.full((3, n), np.nan)  # version 4: per channel its last three values, newest first
        self.trend_misses = np.zeros(n)  # ... forgotten count of the line's misses
        self.trend_errors = np.zeros((3, n))  # ... forgotten squared errors in steps: own, hold, line
        self.base, self.step, self.cross = spec.predictor(), spec.step, spec.cross and n > 1
        self.sums, self.count = np.zeros((2 * n, 2 * n)), 0
        self._set_beta(np.zeros((n, 2 * n)))  # per channel: on this sample's channels, then the previous
        self.raw_before = np.zeros(n, dtype=bool)
        self.previous = np.zeros(n)  # the previous sample's z (across a gap too)
        self.errors = np.zeros((2, n))  # per channel, forgotten squared error: without, with the correction
        self.held = np.full(n, np.nan)  # per channel, hold's prediction (NaN: no value yet)
        self.misses = np.zeros((2, n))  # per channel, forgotten count of misses: own predictor, hold
        self.own = np.zeros(n)  # the own predictor's prediction for the sample being coded
        self.use: list[bool] | None = None  # per channel, whether it uses the correction (until an update)
        self.miss_by, self.near = HOLD_MISS * self.step, self.step / 4  # ``_score``'s bounds
        self.chosen = np.zeros(n)  # the prediction ``_choose`` made for the sample being coded
        self.profile: Profile | None = None  # version 4, a stream with a depth channel: its last profile
        if coding is not None and coding.profile and spec.depth is not None:
            self.depth = spec.channels.index(spec.depth)
            self.profile = Profile(n, self.depth, float(self.step[self.depth]))
        self.profile_errors = np.zeros((2, n))  # ... forgotten squared errors in steps: chosen, profile
        self.profile_use = np.zeros(n, dtype=bool)  # ... per channel, whether it predicts by the profile

    def predict(self) -> np.ndarray:
        self.own = self.base.predict()
        return self._choose()

    def current(self) -> np.ndarray:
        self.own = self.base.current()
        return self._choose()

    def _choose(self) -> np.ndarray:
        """Per channel: the held value where hold has lately missed far less often (the Kalman filter,
        fed reconstructions, lags a drift; hold follows it a step at a time)."""
        hold = (self.misses[1] < HOLD_USE * self.misses[0] + HOLD_SLACK) & ~np.isnan(self.held)
        chosen = np.where(hold, self.held, self.own)
        if self.trend:
            line = self._line()
            fewer = self.trend_misses < TREND_USE * np.where(hold, self.misses[1], self.misses[0])
            closer = self.trend_errors[2] < TREND_USE * np.where(
                hold, self.trend_errors[1], self.trend_errors[0]
            )
            chosen = np.where(fewer & closer & ~np.isnan(line), line, chosen)
        self.chosen = chosen
        return chosen

    def _line(self) -> np.ndarray:
        """Per channel the line's prediction: its last value plus half the change over its last three."""
        return self.lines[0] + (self.lines[0] - self.lines[2]) / 2

    def fine(self) -> np.ndarray:
        """Per channel, the fraction of a step its next q counts: ``FIRST_FINE`` for a channel that has no
        value yet, else 1. A first value on the step grid may land up to eps from the truth, and every
        value predicted from it starts that far off (a quantised sensor's whole unit costs a surprise);
        on a finer grid it costs a few bits once (both ends know which channels have a value)."""
        return np.where(np.isnan(self.held), FIRST_FINE, 1.0)

    def skip(self, ticks: int = 1) -> None:
        self.base.skip(ticks)  # the previous sample's residuals still predict (zeroing them cost 6 % on gaps)

    def correction(self, c: int, z: np.ndarray) -> float:
        """Channel c's predicted residual, in steps: from its last profile (version 4, where that has lately
        done better; at this sample's depth if coded before c, else at the depth predicted), or from the
        earlier channels' ``z``."""
        if self.profile is not None and self.profile_use[c]:
            d = self.depth
            depth = float(self.chosen[d]) + (float(z[d]) * float(self.step[d]) if d < c else 0.0)
            predicted = self.profile.predict(c, depth)
            if predicted is not None:
                return (predicted - float(self.chosen[c])) / float(self.step[c])
        if not self.cross:
            return 0.0
        if self.use is None:
            self.use = (self.errors[1] < CROSS_USE * self.errors[0]).tolist()
        if not self.use[c]:
            return 0.0
        return self._predicted(c, z.tolist())

    def update(self, values: np.ndarray, z: np.ndarray, raw: np.ndarray) -> None:
        """The sample's reconstruction (NaN: absent), residuals in steps (0: absent or raw), raw channels."""
        present = ~np.isnan(values)
        fed = np.where(raw & ~self.raw_before, np.nan, values)
        self.raw_before = np.where(present, raw, self.raw_before)
        self.base.update(_feed(fed))
        self._score(fed)
        if self.profile is not None:
            self._score_profile(_feed(fed))
        if not self.cross:
            return
        zz = np.concatenate([np.clip(z, -CROSS_CLIP, CROSS_CLIP), self.previous])
        clipped = zz[: len(z)].tolist()
        candidate = np.array([self._predicted(c, clipped) for c in range(len(z))])
        self.errors = self.errors * CROSS_FORGET + np.where(present, np.array([z, z - candidate]) ** 2, 0.0)
        self.use = None
        self.previous = zz[: len(z)]
        self.sums = self.sums * CROSS_FORGET + np.outer(zz, zz)
        self.count += 1
        if self.count % CROSS_REFIT == 0:
            self._refit()

    def _score(self, fed: np.ndarray) -> None:
        """Count which of the two predictions certainly missed the values fed: by more than a step from
        the reconstruction, so more than eps from the value (the one in use misses by whole steps, q != 0;
        counting the other's near misses too would favour whichever is in use). The held value then
        moves only as far as to lie within eps/2 of the reconstruction: a value dithering across a step's
        edge (a quantised sensor, noise) does not make hold miss at every crossing, as send-on-delta's
        exact value does not."""
        seen = ~np.isnan(fed)
        with np.errstate(over="ignore", invalid="ignore"):
            missed = np.abs(fed - np.array([self.own, self.held])) > self.miss_by
            kept = np.clip(self.held, fed - self.near, fed + self.near)
        missed &= ~np.isnan(self.held)  # a channel's first value: neither predicted it
        self.misses = self.misses * HOLD_FORGET + np.where(seen, missed, 0.0)
        if self.trend:
            guesses = np.array([self.own, self.held, self._line()])
            with np.errstate(over="ignore", invalid="ignore"):
                off = np.minimum(((fed - guesses) / self.step) ** 2, TREND_FAR)
            off = np.where(np.isnan(off), TREND_FAR, off)  # no guess: as far off as counted
            self.trend_errors = self.trend_errors * HOLD_FORGET + np.where(seen, off, 0.0)
            line_missed = off[2] > self.miss_by**2 / self.step**2
            self.trend_misses = self.trend_misses * HOLD_FORGET + np.where(seen, line_missed, 0.0)
            self.lines = np.where(seen, np.array([fed, self.lines[0], self.lines[1]]), self.lines)
        self.held = np.where(seen, np.where(np.isnan(self.held), fed, kept), self.held)

    def _score_profile(self, fed: np.ndarray) -> None:
        """Version 4: how far the profile prediction at this sample's depth and the one chosen were off
        (squared, in steps, capped at ``TREND_FAR``; no profile prediction counts as that far), and so which
        channels predict by the profile next: those where it has lately (``PROFILE_FORGET``) erred 20 %
        less. Then the sample
        joins the profile."""
        profile = self.profile
        assert profile is not None
        depth = float(fed[self.depth])
        for c in range(len(fed)):
            value = float(fed[c])
            if value != value:
                continue
            predicted = profile.predict(c, depth)
            step = float(self.step[c])
            off = TREND_FAR if predicted is None else min(((value - predicted) / step) ** 2, TREND_FAR)
            chosen = min(((value - float(self.chosen[c])) / step) ** 2, TREND_FAR)
            self.profile_errors[0, c] = self.profile_errors[0, c] * PROFILE_FORGET + chosen
            self.profile_errors[1, c] = self.profile_errors[1, c] * PROFILE_FORGET + off
        self.profile_use = self.profile_errors[1] < TREND_USE * self.profile_errors[0]
        profile.update(fed)

    def _refit(self) -> None:
        """Every channel's ridge regression from one elimination. The regressors ordered as the previous
        sample's residuals, then this sample's channels: channel c's system is then the leading n + c
        block of the one matrix, and its target column the next one, so one elimination serves all."""
        n = len(self.step)
        ridge = CROSS_RIDGE * ordered(np.diagonal(self.sums).tolist()) / (2 * n) + 1e-9
        order = np.r_[n : 2 * n, 0:n]
        a = self.sums[np.ix_(order, order)]
        u = _eliminate(a + ridge * np.eye(2 * n)).tolist()
        beta = np.zeros((n, 2 * n))
        for c in range(n):
            m = n + c
            x = _back(u, m)
            explained = ordered(x, a[:m, m].tolist()) / (self.sums[c, c] + 1e-12)  # R^2 of the fit
            if explained >= CROSS_MIN_R2:
                beta[c, order[:m]] = x
        self._set_beta(beta)

    def _set_beta(self, beta: np.ndarray) -> None:
        """The coefficients (channel c's on channels c.. are 0), and each channel's as ``_predicted``
        takes them."""
        n = len(beta)
        self.beta = beta
        rows = beta.tolist()
        self.weights = [row[:c] + row[n:] for c, row in enumerate(rows)]  # ``_predicted``'s, per channel

    def _predicted(self, c: int, z: list[float]) -> float:
        """Channel c's predicted residual from the earlier channels' ``z`` and the previous residuals."""
        return ordered(self.weights[c], z[:c] + self.previous.tolist())

    def state(self) -> Any:
        return (
            self.base.state(),
            self.sums.copy(),
            self.beta.copy(),
            self.count,
            self.raw_before.copy(),
            self.previous.copy(),
            self.errors.copy(),
            self.held.copy(),
            self.misses.copy(),
            *((self.lines.copy(), self.trend_misses.copy(), self.trend_errors.copy()) if self.trend else ()),
            *(
                (self.profile.state(), self.profile_errors.copy(), self.profile_use.copy())
                if self.profile is not None
                else ()
            ),
        )

    def restore(self, state: Any) -> None:
        base, sums, beta, count, raw_before, previous, errors, held, misses, *rest = state
        if self.trend:
            self.lines, self.trend_misses, self.trend_errors = (
                np.array(x, dtype=np.float64) for x in rest[:3]
            )
            rest = rest[3:]
        if self.profile is not None:
            profile, profile_errors, profile_use = rest
            self.profile.restore(profile)
            self.profile_errors = np.array(profile_errors, dtype=np.float64)
            self.profile_use = np.array(profile_use, dtype=bool)
        self.held, self.misses = np.array(held, dtype=np.float64), np.array(misses, dtype=np.float64)
        self.previous, self.errors = np.array(previous, dtype=np.float64), np.array(errors, dtype=np.float64)
        self.base.restore(base)
        self.sums = np.array(sums, dtype=np.float64)
        self._set_beta(np.array(beta, dtype=np.float64))
        self.count = int(count)
        self.use = None
        self.raw_before = np.array(raw_before, dtype=bool)
