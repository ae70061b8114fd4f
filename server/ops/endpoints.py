"""``GET /metrics``: a shore process's metrics in Prometheus' text format, on a listener of its own
(``--metrics-port`` of ``tacit center``, ``tacit serve`` and ``tacit demo``), not on the operators' API."""

from __future__ import annotations

from typing import Annotated, Protocol

from fastapi import APIRouter, Depends, FastAPI, Request
from fastapi.responses import PlainTextResponse

from server.ops.exposition import CONTENT_TYPE

router = APIRouter(tags=["operations"])


class Exposition(Protocol):
    """What a listener exposes: the center's ``Metrics``, a single shore's ``ShoreMetrics``."""

    def text(self) -> str: ...


def _metrics(request: Request) -> Exposition:
    return request.app.state.metrics


MetricsDep = Annotated[Exposition, Depends(_metrics)]


@router.get("/metrics", response_class=PlainTextResponse)
def metrics(service: MetricsDep) -> PlainTextResponse:
    return PlainTextResponse(service.text(), media_type=CONTENT_TYPE)


def metrics_app(service: Exposition) -> FastAPI:
    """The listener Prometheus scrapes: ``/metrics`` and nothing else."""
    app = FastAPI(title="Tacit metrics", docs_url=None, redoc_url=None, openapi_url=None)
    app.state.metrics = service
    app.include_router(router)
    return app
