"""In-process publish/subscribe for the live event stream (SSE) and the map.

Publishing is thread-safe (the ingest worker publishes from its thread). Each subscriber has a bounded
queue: a slow browser loses its oldest events, it never slows the link engine.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from typing import Any


class EventBus:
    def __init__(self, queue_size: int = 1000) -> None:
        self.queue_size = queue_size
        self._subscribers: set[asyncio.Queue[dict[str, Any]]] = set()
        self._callbacks: list[Callable[[dict[str, Any]], None]] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self.published = 0

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    def subscribe(self) -> asyncio.Queue[dict[str, Any]]:
        queue: asyncio.Queue[dict[str, Any]] = asyncio.Queue(self.queue_size)
        self._subscribers.add(queue)
        return queue

    def unsubscribe(self, queue: asyncio.Queue[dict[str, Any]]) -> None:
        self._subscribers.discard(queue)

    def on_event(self, callback: Callable[[dict[str, Any]], None]) -> None:
        """Also call ``callback`` (from the event loop) for every event: the map uses this."""
        self._callbacks.append(callback)

    def publish(self, kind: str, **data: Any) -> None:
        event = {"kind": kind, "at": time.time(), **data}
        self.published += 1
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop:
            self._deliver(event)
        else:
            loop.call_soon_threadsafe(self._deliver, event)

    def _deliver(self, event: dict[str, Any]) -> None:
        for queue in list(self._subscribers):
            if queue.full():
                queue.get_nowait()
            queue.put_nowait(event)
        for callback in self._callbacks:
            callback(event)

    @staticmethod
    def sse(event: dict[str, Any]) -> str:
        return f"event: {event['kind']}\ndata: {json.dumps(event)}\n\n"
