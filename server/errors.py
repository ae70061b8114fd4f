"""The server's one error type, mapped to HTTP once (in ``server.app``): services raise these, routes
do not catch them. The body is always ``{"detail": ..., "field": ...}``, naming the field at fault."""

from __future__ import annotations


class ApiError(Exception):
    """A request the server refuses; ``status`` is its HTTP status code."""

    status = 400

    def __init__(self, detail: str, field: str | None = None) -> None:
        super().__init__(detail)
        self.detail = detail
        self.field = field


class NotFound(ApiError):
    status = 404


class Conflict(ApiError):
    status = 409


class Refused(ApiError):
    """Well-formed but not allowed: out of a range or a limit, an unknown stream."""

    status = 422
