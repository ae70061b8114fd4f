"""Shared route dependencies: the database session and the app's engines."""

from __future__ import annotations

from collections.abc import Iterator

from fastapi import Request
from sqlmodel import Session

from server.db import writing


def db(request: Request) -> Iterator[Session]:
    """A session for reading."""
    with Session(request.app.state.db, expire_on_commit=False) as s:
        yield s


def db_write(request: Request) -> Iterator[Session]:
    """A session whose transaction writes: it holds the write lock from its first statement."""
    with writing(request.app.state.db) as s:
        yield s
