"""The center process's operations beside its consumer: the metrics listener and the retention's
hourly pruning, in the consumer's event loop."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable

from sqlalchemy import Engine

from server.core.config import Settings
from server.ops.endpoints import metrics_app
from server.ops.service import Consumer, Metrics, Retention

log = logging.getLogger("tacit.ops")


async def operate(consumer: Consumer, run: Awaitable[None], db: Engine, settings: Settings) -> None:
    """``run`` (the consumer's loop), with retention and, on ``metrics_port``, ``/metrics``."""
    import uvicorn

    retention = Retention(db, settings.retention_days)
    tasks = [run, retention.run(active=lambda: consumer.coordinator)]
    if settings.metrics_port:
        app = metrics_app(Metrics(consumer, retention))
        config = uvicorn.Config(
            app, host=settings.metrics_host, port=settings.metrics_port, log_level="warning"
        )
        tasks.append(uvicorn.Server(config).serve())
        log.info("center: metrics on http://%s:%d/metrics", settings.metrics_host, settings.metrics_port)
    await asyncio.gather(*tasks)
