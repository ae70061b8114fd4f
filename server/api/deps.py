"""Shared route dependencies: the database session and the app's engines."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Path, Query, Request
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


DB_INT_MAX = 2**31 - 1  # what every database's INTEGER holds: larger ids cannot exist, say 422 not 500
Id = Annotated[int, Path(ge=1, le=DB_INT_MAX)]
OptionalId = Annotated[int | None, Query(ge=1, le=DB_INT_MAX)]
Offset = Annotated[int, Query(ge=0, le=DB_INT_MAX)]
