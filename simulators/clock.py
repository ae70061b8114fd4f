"""Simulated time. The channel and the modem emulators schedule through a ``Scheduler``, so the same
code runs in a discrete-event loop (tests: exact, instant) or in real time scaled by a factor
(``tacit sim --time-scale 10`` runs ten simulated seconds per wall second, same event order).
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
from collections.abc import Callable
from typing import Protocol


class Cancellable(Protocol):
    def cancel(self) -> None: ...


class Scheduler(Protocol):
    def now(self) -> float:
        """Simulated seconds."""
        ...

    def call_later(self, delay: float, callback: Callable[[], None]) -> Cancellable: ...


class _Entry:
    __slots__ = ("callback", "cancelled")

    def __init__(self, callback: Callable[[], None]) -> None:
        self.callback = callback
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class VirtualScheduler:
    """A discrete-event scheduler: ``run()`` jumps from event to event."""

    def __init__(self, start: float = 0.0) -> None:
        self._now = start
        self._queue: list[tuple[float, int, _Entry]] = []
        self._order = itertools.count()

    def now(self) -> float:
        return self._now

    def call_later(self, delay: float, callback: Callable[[], None]) -> _Entry:
        entry = _Entry(callback)
        heapq.heappush(self._queue, (self._now + max(0.0, delay), next(self._order), entry))
        return entry

    def run(self, until: float | None = None) -> None:
        """Process events in time order (ties in scheduling order) up to ``until``."""
        while self._queue and (until is None or self._queue[0][0] <= until):
            when, _, entry = heapq.heappop(self._queue)
            self._now = when
            if not entry.cancelled:
                entry.callback()
        if until is not None:
            self._now = max(self._now, until)


class RealtimeScheduler:
    """Simulated time = wall time x ``scale`` on the running asyncio loop.

    While a scheduled event runs, ``now()`` is the simulated time it was due at, not the (slightly
    later) time the loop got to it: chains of events (a ping, its reply, the travel time computed from
    both) stay exact in simulated time however late the wall clock runs them.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, scale: float = 1.0) -> None:
        if scale <= 0:
            raise ValueError("time scale must be positive")
        self.loop = loop
        self.scale = scale
        self._origin = loop.time()
        self._current: float | None = None

    def now(self) -> float:
        if self._current is not None:
            return self._current
        return (self.loop.time() - self._origin) * self.scale

    def call_later(self, delay: float, callback: Callable[[], None]) -> asyncio.TimerHandle:
        due = self.now() + max(0.0, delay)

        def run() -> None:
            self._current = due
            try:
                callback()
            finally:
                self._current = None

        return self.loop.call_at(self._origin + due / self.scale, run)
