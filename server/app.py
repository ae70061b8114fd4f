"""The shore control center: ``create_app`` and ``tacit serve``.

At start-up (FastAPI lifespan) the database is migrated to the latest schema, the link engine opens
the shore modem, and the operator's 3D map starts beside uvicorn. Everything stops cleanly on exit.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import re
import socket
import sys
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from contextlib import asynccontextmanager
from pathlib import Path
from urllib.parse import urlsplit

from fastapi import FastAPI, Request, Response
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.types import Receive, Scope, Send

from server.api import system
from server.commands import endpoints as commands
from server.core import errors
from server.core.config import Settings, SettingsError
from server.core.db import make_engine, migrate
from server.link import endpoints as link
from server.link.ingest import Ingest
from server.missions import endpoints as missions
from server.operators import endpoints as operators
from server.routing import endpoints as routing
from server.safety import endpoints as safety
from server.screens import endpoints as screens
from server.shore import Shore
from server.telemetry import endpoints as telemetry
from server.vehicles import endpoints as vehicles

log = logging.getLogger("tacit.server")
WEB = Path(__file__).resolve().parent / "web"  # top-level web/, shipped inside the package
DOCS_ASSETS = "/docs-assets"

DESCRIPTION = """
Tacit's shore control center. Writes (vehicles, commands, missions) need an operator's bearer token,
reads an observer's or an operator's: click **Authorize** and paste the token, or send
`Authorization: Bearer <token>`. Errors are JSON: `{"detail": ..., "field": ...}` names the field at fault.
"""
#: Every page: never framed by another site, no guessed content types, nothing loaded from elsewhere but
#: the 3D map in its frame (``frame-src``: ``map_origin``).
SECURITY_HEADERS = {
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}
CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
    "connect-src 'self'; frame-src {frame}; frame-ancestors 'none'; base-uri 'none'; form-action 'self'"
)
HOST = re.compile(r"^[A-Za-z0-9.\-]+$|^\[[0-9A-Fa-f:.]+\]$")  # a name, an IPv4 or a bracketed IPv6 address
DOCS_CSP = "default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; frame-ancestors 'none'"  # Swagger UI starts from an inline script


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    shore: Shore = app.state.shore
    settings = shore.settings
    await asyncio.to_thread(migrate, settings.database_url)
    shore.bus.bind(asyncio.get_running_loop())
    shore.watcher.start()
    await shore.link.start()
    tasks = [asyncio.create_task(run(shore)) for run in app.state.background]
    operator_map = None
    if settings.map_enabled:
        from server.map.connections import quiet_given_up_connections
        from server.map.scene import OperatorMap  # viser is heavy: imported only when the map runs

        quiet_given_up_connections()
        operator_map = OperatorMap(
            shore.screens,
            shore.commands,
            shore.bus,
            settings,
            shore.operators.actor,
            shore.safety.paths,
            shore.teams.every,
        )
        operator_map.start()
        shore.screens.map_port = lambda: operator_map.port if operator_map else None
        app.state.map = operator_map
    log.info("tacit server ready: API http://%s:%d/docs", settings.host, settings.port)
    try:
        yield
    finally:
        if operator_map:
            operator_map.stop()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await shore.link.stop()
        await asyncio.to_thread(shore.watcher.stop)


class Pages(StaticFiles):
    """The dashboard's files; any method but GET and HEAD on a path that is not a route is a 404 (a
    mistyped API URL says "not found", not "method not allowed")."""

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] not in ("GET", "HEAD"):
            response = JSONResponse({"detail": f"no route {scope['path']}", "field": None}, status_code=404)
            await response(scope, receive, send)
            return
        await super().__call__(scope, receive, send)


def create_app(
    settings: Settings,
    ingest_type: type[Ingest] = Ingest,
    background: Sequence[Callable[[Shore], Awaitable[None]]] = (),
) -> FastAPI:
    """The API on a shore built from ``settings``; ``ingest_type`` and ``background`` (tasks run for the
    app's life, e.g. the center's consumers and dispatcher) make it a center."""
    app = FastAPI(
        title="Tacit", version="1", description=DESCRIPTION, lifespan=lifespan, docs_url=None, redoc_url=None
    )
    app.state.shore = Shore.build(settings, make_engine(settings.database_url), ingest_type)
    app.state.background = list(background)
    app.state.map = None
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["*"],
            allow_headers=["Authorization", "Content-Type"],
        )

    @app.middleware("http")
    async def security_headers(
        request: Request, call_next: Callable[[Request], Awaitable[Response]]
    ) -> Response:
        response: Response = await call_next(request)
        response.headers.update(SECURITY_HEADERS)
        frame = map_origin(settings, request, app.state.shore.screens.map_port())
        csp = DOCS_CSP if request.url.path == "/docs" else CSP.format(frame=frame or "'none'")
        response.headers["Content-Security-Policy"] = csp
        return response

    for module in (
        system,
        operators,
        vehicles,
        commands,
        missions,
        telemetry,
        link,
        screens,
        safety,
        routing,
    ):
        app.include_router(module.router)
    errors.install(app)
    _offline_docs(app)
    if WEB.is_dir():
        app.mount("/", Pages(directory=WEB, html=True), name="web")
    return app


def map_origin(settings: Settings, request: Request, port: int | None) -> str | None:
    """Where the dashboard's frame may load the 3D map from: ``map_url``'s origin when set (the map
    behind a proxy), else the host the browser asked for on the map's port; None while no map runs (or
    the host is not one: nothing from a request header reaches the header unchecked)."""
    if port is None:
        return None
    if settings.map_url:
        url = urlsplit(settings.map_url)
        return f"{url.scheme}://{url.netloc}"
    host = request.url.netloc.rsplit(":", 1)[0] if request.url.port else request.url.netloc
    return f"{request.url.scheme}://{host}:{port}" if HOST.match(host) else None


def shore_app(settings: Settings) -> FastAPI:
    """The app of a shore with its own modem (``tacit serve``, the demo), with its ``/metrics`` listener
    on ``metrics_port`` (``server.ops``)."""
    from server.ops.process import expose

    return create_app(settings, background=[expose])


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
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title="Tacit API",
            swagger_js_url=f"{DOCS_ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{DOCS_ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{DOCS_ASSETS}/favicon.png",
        )


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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="a TOML settings file (TACIT_* environment variables override it)")
    parser.add_argument("--host", help="bind address (default 127.0.0.1: only this machine)")
    parser.add_argument("--port", type=int, help="API and dashboard port (default 8000)")
    parser.add_argument("--map-port", type=int, help="3D map port (default 8080)")
    parser.add_argument(
        "--metrics-port",
        type=int,
        help="serve /metrics (Prometheus) on this port of TACIT_METRICS_HOST; 0: none (default 9464)",
    )
    parser.add_argument("--database-url", help="e.g. sqlite:///data/tacit.db or postgresql+psycopg://...")
    parser.add_argument("--modem-url", help="the shore modem: /dev/ttyUSB0, a pty, socket://host:port")
    parser.add_argument("--no-map", action="store_true", help="do not start the 3D map")


def settings_from(args: argparse.Namespace) -> Settings:
    settings = Settings.load(args.config)
    for name in ("host", "port", "map_port", "metrics_port", "database_url", "modem_url"):
        value = getattr(args, name, None)
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
        if settings.metrics_port:
            check_port(settings.metrics_host, settings.metrics_port, "--metrics-port (0: none)")
    except PortBusy as exc:
        print(f"tacit serve: {exc}", file=sys.stderr)
        return 1
    if not settings.write_tokens:
        log.warning("no operator token configured (TACIT_WRITE_TOKENS): every write will be refused")
    uvicorn.run(shore_app(settings), host=settings.host, port=settings.port, log_level="info")
    return 0
