"""An asyncio event loop on virtual time: ``loop.time()`` jumps to the next timer whenever nothing is
ready, so code that sleeps and waits (the shore's MAC, a simulated sea) runs minutes of its time in
milliseconds, exactly and in the same order every run. No real I/O: a wait with no timer pending is a
deadlock, raised as such.

    loop = VirtualLoop(start=1_700_000_000.0)
    loop.run_until_complete(main())  # ``loop.time()`` is the virtual clock (UNIX-like seconds)
"""

from __future__ import annotations

import asyncio
import selectors
from collections.abc import Mapping
from typing import Any


class _Map(Mapping[Any, selectors.SelectorKey]):
    def __init__(self, keys: dict[Any, selectors.SelectorKey]) -> None:
        self._keys = keys

    def __getitem__(self, fileobj: Any) -> selectors.SelectorKey:
        return self._keys[fileobj]

    def __iter__(self) -> Any:
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)


class _VirtualSelector(selectors.BaseSelector):
    """Keeps the loop's registrations (its self-pipe) but never waits: a timeout advances the clock."""

    def __init__(self, loop: VirtualLoop) -> None:
        self._loop = loop
        self._keys: dict[Any, selectors.SelectorKey] = {}

    def register(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        key = selectors.SelectorKey(
            fileobj, fileobj if isinstance(fileobj, int) else fileobj.fileno(), events, data
        )
        self._keys[fileobj] = key
        return key

    def unregister(self, fileobj: Any) -> selectors.SelectorKey:
        return self._keys.pop(fileobj)

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        if timeout is None:
            raise RuntimeError("virtual loop: every task waits and no timer is pending (a deadlock)")
        self._loop.advance(timeout)
        return []

    def get_map(self) -> Mapping[Any, selectors.SelectorKey]:
        return _Map(self._keys)

    def close(self) -> None:
        self._keys.clear()


class VirtualLoop(asyncio.SelectorEventLoop):
    def __init__(self, start: float = 0.0) -> None:
        self._now = start
        super().__init__(selector=_VirtualSelector(self))
        self._clock_resolution = 1e-6  # a timer at ``time()`` is due (1e-9 vanishes at UNIX-like magnitudes)

    def time(self) -> float:
        return self._now

    def advance(self, seconds: float) -> None:
        """Jump ``seconds`` on: to the next timer exactly (a sum could round short of it at UNIX-like
        magnitudes, and the timer would never be due)."""
        if seconds <= 0:
            return
        timers: list[asyncio.TimerHandle] = getattr(self, "_scheduled", [])
        target = self._now + seconds
        if timers and timers[0].when() <= target + 1e-6:
            target = timers[0].when()
        self._now = max(self._now, target)


def run(main: Any, start: float = 1_700_000_000.0) -> Any:
    """Run the coroutine ``main`` on a fresh virtual loop starting at ``start``; its result."""
    loop = VirtualLoop(start)
    try:
        return loop.run_until_complete(main)
    finally:
        left = asyncio.all_tasks(loop)  # what ``main`` left running (a modem's answer under way): ended
        for task in left:
            task.cancel()
        if left:
            loop.run_until_complete(_ended(left))
        loop.close()


async def _ended(tasks: set[asyncio.Task[Any]]) -> None:
    await asyncio.gather(*tasks, return_exceptions=True)
