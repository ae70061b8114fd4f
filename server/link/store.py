"""The link's database access, off the event loop that serves the modem.

Every write runs in a worker thread; while the database is busy (another process holds its write lock
past the busy timeout) it is tried again with backoff, so what arrived stays in memory and is never
dropped for want of a lock.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Coroutine
from typing import TypeVar

from sqlalchemy import Engine
from sqlalchemy.exc import OperationalError

from server.core.db import writing
from server.link import repository as link

log = logging.getLogger("tacit.server.link")
T = TypeVar("T")


class LinkStore:
    def __init__(self, db: Engine) -> None:
        self.db = db
        self._background: set[asyncio.Task[None]] = set()

    async def run(self, work: Callable[..., T], *args: object) -> T:
        """``work(*args)`` in a worker thread, retried while the database is busy."""
        delay = 0.2
        while True:
            try:
                return await asyncio.to_thread(work, *args)
            except OperationalError as exc:
                log.warning("database busy (%s): retrying in %.1f s", exc.orig, delay)
                await asyncio.sleep(delay)
                delay = min(delay * 2, 5.0)

    async def add(self, *rows: object) -> None:
        """Insert ORM rows in one transaction."""
        await self.run(self._add_now, *rows)

    def add_later(self, *rows: object) -> None:
        """``add`` from a callback that cannot wait (a modem event); the task is kept until it ends."""
        self.spawn(self.add(*rows))

    def spawn(self, work: Coroutine[object, object, None]) -> None:
        task = asyncio.get_running_loop().create_task(work)
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    def _add_now(self, *rows: object) -> None:
        with writing(self.db) as s:
            link.add(s, *rows)
            s.commit()
