"""The shore control center: ``create_app`` and ``tacit serve``.

At start-up (FastAPI lifespan) the database is migrated to the latest schema, the link engine opens
the shore modem, and the operator's 3D map starts beside uvicorn. Everything stops cleanly on exit.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import Depends, FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from server.api import commands, data, missions, vehicles
from server.auth import require_read
from server.db import make_engine, migrate
from server.events import EventBus
from server.link.engine import LinkEngine
from server.link.ingest import Ingest
from server.schemas import json_safe
from server.settings import Settings, SettingsError
from tacit.streams import default_streams

log = logging.getLogger("tacit.server")
WEB = Path(__file__).resolve().parent.parent / "web"

DESCRIPTION = """
Tacit's shore control center. Writes (vehicles, commands, missions) need an operator's bearer token,
reads an observer's or an operator's: click **Authorize** and paste the token, or send
`Authorization: Bearer <token>`. Errors are JSON: `{"detail": ..., "field": ...}` names the field at fault.
"""


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    settings: Settings = app.state.settings
    await asyncio.to_thread(migrate, settings.database_url)
    app.state.bus.bind(asyncio.get_running_loop())
    await app.state.link.start()
    map_server = None
    if settings.map_enabled:
        from server.map.scene import OperatorMap  # viser is heavy: imported only when the map runs

        map_server = OperatorMap(app, settings.host, settings.map_port)
        map_server.start()
        app.state.map = map_server
    log.info("tacit server ready: API http://%s:%d/docs", settings.host, settings.port)
    try:
        yield
    finally:
        if map_server:
            map_server.stop()
        await app.state.link.stop()


def create_app(settings: Settings) -> FastAPI:
    app = FastAPI(title="Tacit", version="1", description=DESCRIPTION, lifespan=lifespan)
    app.state.settings = settings
    app.state.db = make_engine(settings.database_url)
    app.state.bus = EventBus()
    app.state.ingest = Ingest(app.state.db, app.state.bus, default_streams())
    app.state.link = LinkEngine(settings, app.state.db, app.state.bus, app.state.ingest)
    app.state.map = None
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["*"],
                           allow_headers=["Authorization", "Content-Type"])  # fmt: skip
    for module in (vehicles, commands, missions, data):
        app.include_router(module.router)

    @app.get("/api/v1/health", tags=["data"])
    def health() -> dict:
        return {"status": "ok", "modem": app.state.link.status()["modem"]}

    @app.get("/api/v1/whoami", tags=["data"])
    def whoami(found: str = Depends(require_read)) -> dict:
        """The caller's role: ``write`` (operator) or ``read`` (observer)."""
        return {"role": found}

    @app.get("/api/v1/config", tags=["data"])
    def config() -> dict:
        """What the browser needs: the map's port and the streams' channels (no secrets)."""
        streams = {s.name: {"channels": list(s.channels), "eps": list(s.eps), "period": s.period}
                   for s in app.state.ingest.streams.values()}  # fmt: skip
        port = app.state.map.port if app.state.map else None
        return {"map_port": port, "streams": streams}

    @app.exception_handler(RequestValidationError)
    async def invalid(_: Request, exc: RequestValidationError) -> JSONResponse:
        first = exc.errors()[0] if exc.errors() else {"loc": ["body"], "msg": "invalid request"}
        loc = [str(p) for p in first.get("loc", ["body"])]
        field = "body" if first.get("type") == "json_invalid" else ".".join(loc[1:]) or loc[0]
        return JSONResponse({"detail": first.get("msg", "invalid request"), "field": field,
                             "errors": jsonable(exc.errors())}, status_code=422)  # fmt: skip

    @app.exception_handler(HTTPException)
    async def http_error(_: Request, exc: HTTPException) -> JSONResponse:
        body = exc.detail if isinstance(exc.detail, dict) else {"detail": exc.detail, "field": None}
        return JSONResponse(body, status_code=exc.status_code, headers=exc.headers)

    if WEB.is_dir():
        app.mount("/", StaticFiles(directory=WEB, html=True), name="web")
    return app


def jsonable(errors: list) -> list:
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
    if not settings.write_tokens:
        log.warning("no operator token configured (TACIT_WRITE_TOKENS): every write will be refused")
    uvicorn.run(create_app(settings), host=settings.host, port=settings.port, log_level="info")
    return 0
