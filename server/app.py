"""The shore control center: ``create_app`` and ``tacit serve``.

At start-up (FastAPI lifespan) the database is migrated to the latest schema, the link engine opens
the shore modem, and the operator's 3D map starts beside uvicorn. Everything stops cleanly on exit.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import socket
import sys
from collections.abc import AsyncIterator, Sequence
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import Depends, FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles
from sqlalchemy.exc import OperationalError

from server import operator
from server.api import commands, data, missions, screens, vehicles
from server.auth import require_read
from server.db import make_engine, migrate
from server.errors import ApiError
from server.schemas import json_safe
from server.settings import Settings, SettingsError
from server.shore import Shore

log = logging.getLogger("tacit.server")
WEB = Path(__file__).resolve().parent / "web"
DOCS_ASSETS = "/docs-assets"

DESCRIPTION = """
Tacit's shore control center. Writes (vehicles, commands, missions) need an operator's bearer token,
reads an observer's or an operator's: click **Authorize** and paste the token, or send
`Authorization: Bearer <token>`. Errors are JSON: `{"detail": ..., "field": ...}` names the field at fault.
"""


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    shore: Shore = app.state.shore
    settings = shore.settings
    await asyncio.to_thread(migrate, settings.database_url)
    shore.bus.bind(asyncio.get_running_loop())
    await shore.link.start()
    if settings.map_enabled:
        from server.map.scene import OperatorMap  # viser is heavy: imported only when the map runs

        shore.map = OperatorMap(shore, settings.host, settings.map_port)
        shore.map.start()
    log.info("tacit server ready: API http://%s:%d/docs", settings.host, settings.port)
    try:
        yield
    finally:
        if shore.map:
            shore.map.stop()
        await shore.link.stop()


def create_app(settings: Settings) -> FastAPI:
    app = FastAPI(title="Tacit", version="1", description=DESCRIPTION, lifespan=lifespan, docs_url=None,
                  redoc_url=None)  # fmt: skip
    shore = Shore.build(settings, make_engine(settings.database_url))
    app.state.shore = shore
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["*"],
                           allow_headers=["Authorization", "Content-Type"])  # fmt: skip
    for module in (vehicles, commands, missions, data, screens):
        app.include_router(module.router)

    @app.get("/api/v1/health", tags=["data"])
    def health() -> dict:
        return {"status": "ok", "modem": shore.link.status()["modem"]}

    @app.get("/api/v1/whoami", tags=["data"])
    def whoami(found: str = Depends(require_read)) -> dict:
        """The caller's role: ``write`` (operator) or ``read`` (observer)."""
        return {"role": found}

    @app.get("/api/v1/config", tags=["data"])
    def config() -> dict:
        """What the browser needs (no secrets): the map's port, the streams' channels with units, what
        the mission states mean, the commands' fields (packet ranges; per vehicle with its limits at
        ``/vehicles/{id}/form``) and the simulated time scale (1 on a real deployment)."""
        streams = {s.name: {"channels": list(s.channels), "eps": list(s.eps), "period": s.period,
                            "units": [operator.UNITS.get(c, "") for c in s.channels]}
                   for s in shore.ingest.streams.values()}  # fmt: skip
        port = shore.map.port if shore.map else None
        states = {k: {"label": label, "hint": hint} for k, (label, hint) in operator.STATES.items()}
        return {
            "map_port": port,
            "streams": streams,
            "states": states,
            "form": operator.command_form(),
            "time_scale": settings.time_scale,
        }

    @app.exception_handler(RequestValidationError)
    async def invalid(_: Request, exc: RequestValidationError) -> JSONResponse:
        first = exc.errors()[0] if exc.errors() else {"loc": ["body"], "msg": "invalid request"}
        loc = [str(p) for p in first.get("loc", ["body"])]
        field = "body" if first.get("type") == "json_invalid" else ".".join(loc[1:]) or loc[0]
        return JSONResponse({"detail": first.get("msg", "invalid request"), "field": field,
                             "errors": jsonable(exc.errors())}, status_code=422)  # fmt: skip

    @app.exception_handler(ApiError)
    async def refused(_: Request, exc: ApiError) -> JSONResponse:
        return JSONResponse({"detail": exc.detail, "field": exc.field}, status_code=exc.status)

    @app.exception_handler(OperationalError)
    async def busy(_: Request, exc: OperationalError) -> JSONResponse:
        """Another process held the database's write lock past the busy timeout: nothing was written.
        Any other database failure is the server's own (500), logged with its cause."""
        if "locked" not in str(exc.orig) and "busy" not in str(exc.orig):
            log.error("database error: %s", exc.orig)
            return JSONResponse(
                {"detail": "database error; nothing was changed", "field": None}, status_code=500
            )
        log.warning("database busy: %s", exc.orig)
        return JSONResponse({"detail": "the database is busy; nothing was changed, try again", "field": None},
                            status_code=503, headers={"Retry-After": "1"})  # fmt: skip

    @app.exception_handler(HTTPException)
    async def http_error(_: Request, exc: HTTPException) -> JSONResponse:
        body = exc.detail if isinstance(exc.detail, dict) else {"detail": exc.detail, "field": None}
        return JSONResponse(body, status_code=exc.status_code, headers=exc.headers)

    _offline_docs(app)
    if WEB.is_dir():
        app.mount("/", StaticFiles(directory=WEB, html=True), name="web")
    return app


def _offline_docs(app: FastAPI) -> None:
    """Swagger UI at /docs from files installed with the server, not from a CDN: shore stations are
    usually offline. The files come from fastapi-offline's package (Swagger UI 5, which reads the
    OpenAPI 3.1 that FastAPI writes; swagger-ui-bundle's Swagger UI 4 cannot)."""
    import fastapi_offline
    from fastapi.openapi.docs import get_swagger_ui_html
    from fastapi.responses import HTMLResponse

    assets = Path(fastapi_offline.__file__).parent / "static"
    app.mount(DOCS_ASSETS, StaticFiles(directory=assets), name="docs-assets")

    @app.get("/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        return get_swagger_ui_html(openapi_url=app.openapi_url or "/openapi.json", title="Tacit API",
                                   swagger_js_url=f"{DOCS_ASSETS}/swagger-ui-bundle.js",
                                   swagger_css_url=f"{DOCS_ASSETS}/swagger-ui.css",
                                   swagger_favicon_url=f"{DOCS_ASSETS}/favicon.png")  # fmt: skip


class PortBusy(OSError):
    pass


def check_port(host: str, port: int, option: str = "--port") -> None:
    """Raise ``PortBusy`` (one line for the operator) if something already listens on ``host:port``;
    checked before anything starts, rather than learnt from uvicorn's exit inside a task."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn binds: TIME_WAIT is fine
        try:
            probe.bind((host, port))
        except OSError as exc:
            raise PortBusy(
                f"cannot listen on {host}:{port} ({exc.strerror}); choose another with {option}"
            ) from None


def jsonable(errors: Sequence[Any]) -> list[Any]:
    return json_safe(errors)  # a NaN or Infinity in the input is echoed as text, never a JSON encoder error


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="a TOML settings file (TACIT_* environment variables override it)")
    parser.add_argument("--host", help="bind address (default 127.0.0.1: only this machine)")
    parser.add_argument("--port", type=int, help="API and dashboard port (default 8000)")
    parser.add_argument("--map-port", type=int, help="3D map port (default 8080)")
    parser.add_argument("--database-url", help="e.g. sqlite:///data/tacit.db or postgresql+psycopg://...")
    parser.add_argument("--modem-url", help="the shore modem: /dev/ttyUSB0, a pty, socket://host:port")
    parser.add_argument("--no-map", action="store_true", help="do not start the 3D map")


def settings_from(args: argparse.Namespace) -> Settings:
    settings = Settings.load(args.config)
    for name in ("host", "port", "map_port", "database_url", "modem_url"):
        value = getattr(args, name)
        if value is not None:
            setattr(settings, name, value)
    if args.no_map:
        settings.map_enabled = False
    return settings


def run(args: argparse.Namespace) -> int:
    import uvicorn

    try:
        settings = settings_from(args)
    except (SettingsError, OSError) as exc:
        print(f"tacit serve: {exc}", file=sys.stderr)
        return 2
    try:
        check_port(settings.host, settings.port)
    except PortBusy as exc:
        print(f"tacit serve: {exc}", file=sys.stderr)
        return 1
    if not settings.write_tokens:
        log.warning("no operator token configured (TACIT_WRITE_TOKENS): every write will be refused")
    uvicorn.run(create_app(settings), host=settings.host, port=settings.port, log_level="info")
    return 0
