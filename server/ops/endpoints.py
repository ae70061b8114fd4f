"""``GET /metrics``: the center's metrics in Prometheus' text format, on the center's own listener
(``tacit center --metrics-port``), not on the operators' API."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, FastAPI, Request
from fastapi.responses import PlainTextResponse

from server.ops.exposition import CONTENT_TYPE
from server.ops.service import Metrics

router = APIRouter(tags=["operations"])


def _metrics(request: Request) -> Metrics:
    return request.app.state.metrics


MetricsDep = Annotated[Metrics, Depends(_metrics)]


@router.get("/metrics", response_class=PlainTextResponse)
def metrics(service: MetricsDep) -> PlainTextResponse:
    return PlainTextResponse(service.text(), media_type=CONTENT_TYPE)


def metrics_app(service: Metrics) -> FastAPI:
    """The listener Prometheus scrapes: ``/metrics`` and nothing else."""
    app = FastAPI(title="Tacit center metrics", docs_url=None, redoc_url=None, openapi_url=None)
    app.state.metrics = service
    app.include_router(router)
    return app
