"""The server's one error type, mapped to HTTP once (``install``): services raise these, routes do not
catch them. The body is always ``{"detail": ..., "field": ...}`` (``Problem``), naming the field at fault.

The OpenAPI document says the same, derived from these classes: each operation lists the errors it may
answer, with the ``Problem`` schema and the class's description. A route declares its own
(``responses=errors.responses(Conflict)``), a dependency the ones it raises (``@errors.raises(...)``:
the bearer-token checks); every operation answers ``Busy``, one with parameters or a body ``Invalid``,
and one with an id in its path ``NotFound``."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from fastapi import FastAPI, HTTPException, Request, routing
from fastapi.dependencies.models import Dependant
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from sqlalchemy.exc import OperationalError

from server.core.schemas import Problem, json_safe

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
    """No bearer token, or one not accepted here (mistyped, expired, revoked): the detail says which."""

    status = 401
    headers = {"WWW-Authenticate": "Bearer"}


class Forbidden(ApiError):
    """A valid token that may not do this: an observer's token where an operator's is needed."""

    status = 403


class NotFound(ApiError):
    """No such object: the id in the path (or the one the field names) is not known here."""

    status = 404


class Conflict(ApiError):
    """The request clashes with what is stored: a name, address or key taken, or a state that forbids it."""

    status = 409


class Refused(ApiError):
    """Well-formed but not allowed: out of a range or a limit, an unknown stream, an inverted window."""

    status = 422


class Invalid(ApiError):
    """Parameters or a body the request's schema refuses (the body's ``errors`` lists every fault)."""

    status = 422


class TooMany(ApiError):
    """A bounded queue is full, or a client tried too often: try again after ``retry_after`` seconds."""

    status = 429

    def __init__(self, detail: str, retry_after: float, field: str | None = None) -> None:
        super().__init__(detail, field)
        self.headers = {"Retry-After": str(max(1, math.ceil(retry_after)))}


class Busy(ApiError):
    """Another process held the database's write lock too long: nothing was changed, try again."""

    status = 503
    headers = {"Retry-After": "1"}


Errors = tuple[type[ApiError], ...]
F = TypeVar("F", bound=Callable[..., Any])
_RAISED_BY: dict[Callable[..., Any], Errors] = {}  # the dependencies ``raises`` was told of


def raises(*errors: type[ApiError]) -> Callable[[F], F]:
    """Declare the errors a dependency raises: every operation that depends on it lists them."""

    def declare(dependency: F) -> F:
        _RAISED_BY[dependency] = errors
        return dependency

    return declare


def responses(*errors: type[ApiError]) -> dict[int | str, dict[str, Any]]:
    """A route's ``responses=`` for the errors it raises itself: each status, the ``Problem`` schema and
    what the classes of that status mean."""
    by_status: dict[int | str, dict[str, Any]] = {}
    for error in errors:
        entry = by_status.setdefault(error.status, {"model": Problem, "description": ""})
        entry["description"] = " ".join(filter(None, (entry["description"], _meaning(error))))
    return by_status


def _meaning(error: type[ApiError]) -> str:
    return (error.__doc__ or error.__name__).split("\n\n")[0].replace("\n", " ").strip()


def _dependencies(dependant: Dependant) -> Iterator[Dependant]:
    for sub in dependant.dependencies:
        yield sub
        yield from _dependencies(sub)


def _raised(route: APIRoute, validated: bool) -> Errors:
    """The errors ``route`` may answer besides those it declares (the module's docstring says which);
    ``validated``: it has parameters or a body to refuse."""
    found: list[type[ApiError]] = [Invalid, Refused, Busy] if validated else [Busy]
    if route.dependant.path_params:
        found.append(NotFound)
    for dependency in _dependencies(route.dependant):
        if dependency.call is not None:
            found.extend(_RAISED_BY.get(dependency.call, ()))
    return tuple(dict.fromkeys(found))


def _operations(app: FastAPI) -> Iterator[tuple[str, APIRoute]]:
    """Each route in the document and its path (routers included: FastAPI 0.16x keeps them nested)."""
    nested = getattr(routing, "iter_route_contexts", None)
    if nested is None:  # an older FastAPI: every route is the app's own
        for route in app.routes:
            if isinstance(route, APIRoute):
                yield route.path_format, route
        return
    for context in nested(app.routes):
        if isinstance(context.original_route, APIRoute) and context.path_format:
            yield context.path_format, context.original_route


def _document(app: FastAPI, schema: dict[str, Any]) -> None:
    """Each operation's error responses in ``schema`` (FastAPI's document), all with ``Problem``."""
    problem = {"application/json": {"schema": {"$ref": "#/components/schemas/Problem"}}}
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    components["Problem"] = Problem.model_json_schema(ref_template="#/components/schemas/{model}")
    for path, route in _operations(app):
        if not route.include_in_schema:
            continue
        for method in route.methods or ():
            answers = schema["paths"][path][method.lower()].setdefault("responses", {})
            validated = answers.pop("422", None) is not None  # FastAPI's body for it is not this server's
            for status, entry in responses(*_raised(route, validated)).items():
                documented = answers.setdefault(str(status), {"description": "", "content": problem})
                documented["description"] = " ".join(
                    filter(None, (documented["description"], entry["description"]))
                )
                documented["content"] = problem
    for unused in ("HTTPValidationError", "ValidationError"):
        components.pop(unused, None)


def install(app: FastAPI) -> None:
    """Every error the API answers, as ``{"detail", "field"}`` with its status; and in the app's OpenAPI
    document (its routes included first)."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            _document(app, generate())  # FastAPI's document, cached in app.openapi_schema
        assert app.openapi_schema is not None
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]  # FastAPI's way to extend its document

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
            status_code=Invalid.status,
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
            status_code=Busy.status,
            headers=Busy.headers,
        )

    @app.exception_handler(HTTPException)
    async def http_error(_: Request, exc: HTTPException) -> JSONResponse:
        body = exc.detail if isinstance(exc.detail, dict) else {"detail": exc.detail, "field": None}
        return JSONResponse(body, status_code=exc.status_code, headers=exc.headers)
