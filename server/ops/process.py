"""A shore process's operations: the center's beside its consumer (the metrics listener and the
retention's hourly pruning, in the consumer's event loop), and a single shore's metrics listener."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable

from sqlalchemy import Engine

from server.core.config import Settings
from server.ops.endpoints import Exposition, metrics_app
from server.ops.service import Consumer, Metrics, Retention, ShoreMetrics
from server.shore import Shore

log = logging.getLogger("tacit.ops")


async def operate(consumer: Consumer, run: Awaitable[None], db: Engine, settings: Settings) -> None:
    """``run`` (the consumer's loop), with retention and, on ``metrics_port``, ``/metrics``."""
    retention = Retention(db, settings.retention_days)
    tasks = [run, retention.run(active=lambda: consumer.coordinator)]
    if settings.metrics_port:
        tasks.append(_listen(Metrics(consumer, retention), settings, "center"))
    await asyncio.gather(*tasks)


async def expose(shore: Shore) -> None:
    """A shore with its own modem (``tacit serve``, the demo): ``/metrics`` on ``metrics_port`` (0:
    none), for the app's life."""
    if shore.settings.metrics_port:
        await _listen(ShoreMetrics(shore.link), shore.settings, "shore")


async def _listen(service: Exposition, settings: Settings, who: str) -> None:
    import uvicorn

    app = metrics_app(service)
    config = uvicorn.Config(app, host=settings.metrics_host, port=settings.metrics_port, log_level="warning")
    log.info("%s: metrics on http://%s:%d/metrics", who, settings.metrics_host, settings.metrics_port)
    server = uvicorn.Server(config)
    serving = asyncio.ensure_future(server.serve())
    try:
        await asyncio.shield(serving)
    except asyncio.CancelledError:  # the process stops: the listener too, cleanly (no traceback)
        server.should_exit = True
        await serving
        raise
