"""Payload version 4's profile prediction: water properties as a function of depth, from the vehicle's own
last profile.

A vehicle that dives and climbs measures, on each pass, nearly the profile it measured on the pass
before: a channel's value changes between two samples about as much as it changed between those two
depths on the last pass. ``Profile`` keeps, for a stream with a depth channel (``StreamSpec.depth``), the
reconstructions of the pass under way (a point each ``SPACING`` depth steps, thinned to ``POINTS``) and of the last two finished
ones; a pass ends when the depth turns back by ``TURN`` steps. A channel's profile prediction at depth D is
its last value v0 (at depth D0) plus ref(D) - ref(D0), ref the values of the last pass in the same
direction interpolated linearly at those depths (none where D or D0 lies outside that pass, or a value there is absent).

Both ends run it on reconstructions, in Python floats (the same IEEE operations on every CPU: no numpy
interpolation, whose compiled loops may fuse a multiply and an add), so both predict to the bit.
"""

from __future__ import annotations

from bisect import bisect_left
from typing import Any

import numpy as np

SPACING = 4.0  # a pass keeps a point each time the depth has moved this many of its steps
TURN = 8.0  # a pass ends when the depth has turned back this many steps from its extreme
POINTS = 128  # a pass keeps at most this many points: when full, every other one of them goes (the
# shore saves its states with every batch it stores: a pass stays a few kilobytes)


class Profile:
    """The last finished pass and the one under way, per depth: what ``predict`` needs."""

    def __init__(self, channels: int, depth: int, step: float) -> None:
        self.channels, self.depth = channels, depth
        self.spacing, self.turn = SPACING * step, TURN * step
        self.current = np.zeros((0, channels))  # the pass under way: rows of reconstructions
        self.previous = np.zeros((0, channels))  # the last finished pass, sorted by depth
        self.before = np.zeros((0, channels))  # the one before it (the last in the direction under way)
        self.extreme = np.nan  # the pass's deepest (descending) or shallowest (ascending) depth
        self.direction = 0  # 1 descending, -1 ascending, 0 not yet known
        self.anchor = np.full(channels, np.nan)  # per channel its last value ...
        self.anchor_depth = np.full(channels, np.nan)  # ... and the depth it was measured at
        self._reference()

    def _reference(self) -> None:
        """The reference pass as Python lists, for ``predict``: the last one in the direction under way (a
        sensor's lag puts a climb's profile off a dive's: predicting from the last pass, the other way, did
        worse on a Slocum glider's CTD)."""
        self._depths: list[float] = self.before[:, self.depth].tolist()
        self._rows: list[list[float]] = self.before.tolist()

    def _at(self, c: int, depth: float) -> float | None:
        """Channel c's value on the last pass at ``depth`` (linear between its points; None outside)."""
        depths = self._depths
        if not depths or not depths[0] <= depth <= depths[-1]:
            return None
        i = bisect_left(depths, depth)
        if depths[i] == depth:
            value = self._rows[i][c]
        else:
            d0, d1 = depths[i - 1], depths[i]
            v0, v1 = self._rows[i - 1][c], self._rows[i][c]
            value = v0 + (v1 - v0) * ((depth - d0) / (d1 - d0))
        return None if value != value else value  # NaN: absent there

    def predict(self, c: int, depth: float) -> float | None:
        """Channel c's profile prediction at ``depth`` (None: the last pass does not say)."""
        v0, d0 = float(self.anchor[c]), float(self.anchor_depth[c])
        if c == self.depth or v0 != v0 or d0 != d0 or depth != depth:
            return None
        here, there = self._at(c, depth), self._at(c, d0)
        return None if here is None or there is None else v0 + (here - there)

    def update(self, values: np.ndarray) -> None:
        """A sample's reconstructions (NaN: absent); nothing to do without its depth."""
        depth = float(values[self.depth])
        if depth != depth:
            return
        seen = ~np.isnan(values)
        self.anchor = np.where(seen, values, self.anchor)
        self.anchor_depth = np.where(seen, depth, self.anchor_depth)
        if self.extreme != self.extreme:
            self.extreme = depth
        elif self.direction >= 0 and depth > self.extreme or self.direction <= 0 and depth < self.extreme:
            if self.direction == 0 and abs(depth - self.extreme) >= self.turn:
                self.direction = 1 if depth > self.extreme else -1
            self.extreme = depth if self.direction else self.extreme
        elif self.direction and abs(depth - self.extreme) >= self.turn:  # turned back: a new pass
            order = np.argsort(self.current[:, self.depth], kind="stable")
            self.before, self.previous = self.previous, self.current[order]
            self.current = np.zeros((0, self.channels))
            self.direction, self.extreme = -self.direction, depth
            self._reference()
        last = self.current[-1, self.depth] if len(self.current) else np.nan
        if not abs(depth - last) < self.spacing:
            if len(self.current) == POINTS:
                self.current = np.vstack([self.current[:-1:2], self.current[-1:]])  # the ends kept
            self.current = np.vstack([self.current, values[None, :]])

    def state(self) -> tuple[Any, ...]:
        return (
            self.current.copy(),
            self.previous.copy(),
            self.before.copy(),
            self.extreme,
            self.direction,
            self.anchor.copy(),
            self.anchor_depth.copy(),
        )

    def restore(self, state: Any) -> None:
        current, previous, before, extreme, direction, anchor, anchor_depth = state
        shape = (-1, self.channels)
        self.current = np.array(current, dtype=np.float64).reshape(shape)
        self.previous = np.array(previous, dtype=np.float64).reshape(shape)
        self.before = np.array(before, dtype=np.float64).reshape(shape)
        self.extreme, self.direction = float(extreme), int(direction)
        self.anchor = np.array(anchor, dtype=np.float64)
        self.anchor_depth = np.array(anchor_depth, dtype=np.float64)
        self._reference()
