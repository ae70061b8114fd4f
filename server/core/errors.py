"""The server's one error type, mapped to HTTP once (``install``): services raise these, routes do not
catch them. The body is always ``{"detail": ..., "field": ...}``, naming the field at fault."""

from __future__ import annotations

import logging
import math

from fastapi import FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import OperationalError

from server.core.schemas import json_safe

log = logging.getLogger("tacit.server")


class ApiError(Exception):
    """A request the server refuses; ``status`` is its HTTP status code."""

    status = 400
    headers: dict[str, str] | None = None

    def __init__(self, detail: str, field: str | None = None) -> None:
        super().__init__(detail)
        self.detail = detail
        self.field = field


class Unauthorized(ApiError):
    """A bearer token that is no longer accepted (expired or revoked): the detail says which and when."""

    status = 401
    headers = {"WWW-Authenticate": "Bearer"}


class NotFound(ApiError):
    status = 404


class Conflict(ApiError):
    status = 409


class Refused(ApiError):
    """Well-formed but not allowed: out of a range or a limit, an unknown stream, an inverted window."""

    status = 422


class TooMany(ApiError):
    """A bounded queue is full, or a client tried too often: try again after ``retry_after`` seconds."""

    status = 429

    def __init__(self, detail: str, retry_after: float, field: str | None = None) -> None:
        super().__init__(detail, field)
        self.headers = {"Retry-After": str(max(1, math.ceil(retry_after)))}


def install(app: FastAPI) -> None:
    """Every error the API answers, as ``{"detail", "field"}`` with its status."""

    @app.exception_handler(RequestValidationError)
    async def invalid(_: Request, exc: RequestValidationError) -> JSONResponse:
        first = exc.errors()[0] if exc.errors() else {"loc": ["body"], "msg": "invalid request"}
        loc = [str(p) for p in first.get("loc", ["body"])]
        field = "body" if first.get("type") == "json_invalid" else ".".join(loc[1:]) or loc[0]
        return JSONResponse(
            {
                "detail": first.get("msg", "invalid request"),
                "field": field,
                "errors": json_safe(exc.errors()),
            },
            status_code=422,
        )

    @app.exception_handler(ApiError)
    async def refused(_: Request, exc: ApiError) -> JSONResponse:
        return JSONResponse(
            {"detail": exc.detail, "field": exc.field}, status_code=exc.status, headers=exc.headers
        )

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
        return JSONResponse(
            {"detail": "the database is busy; nothing was changed, try again", "field": None},
            status_code=503,
            headers={"Retry-After": "1"},
        )

    @app.exception_handler(HTTPException)
    async def http_error(_: Request, exc: HTTPException) -> JSONResponse:
        body = exc.detail if isinstance(exc.detail, dict) else {"detail": exc.detail, "field": None}
        return JSONResponse(body, status_code=exc.status_code, headers=exc.headers)
