"""Typed route dependencies: the database sessions and the shore's parts (``server.shore.Shore``)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from functools import partial
from typing import Annotated

from fastapi import Depends, Path, Query, Request
from sqlmodel import Session

from server.db import writing
from server.events import EventBus
from server.link.engine import LinkEngine
from server.link.ingest import Ingest
from server.services.commands import CommandDesk
from server.settings import Settings
from server.shore import Shore


def shore(request: Request) -> Shore:
    return request.app.state.shore


ShoreDep = Annotated[Shore, Depends(shore)]


def db(shore: ShoreDep) -> Iterator[Session]:
    """A session for reading."""
    with Session(shore.db, expire_on_commit=False) as s:
        yield s


def writer(shore: ShoreDep) -> Writer:
    """Opens short write transactions inside the route (``with write() as s``). Not a yielded session:
    a write lock held across a dependency's enter and exit can wait on the very thread pool the route
    needs, and a busy server then deadlocks."""
    return partial(writing, shore.db)


def settings(shore: ShoreDep) -> Settings:
    return shore.settings


def command_desk(shore: ShoreDep) -> CommandDesk:
    return shore.commands


def link(shore: ShoreDep) -> LinkEngine:
    return shore.link


def ingest(shore: ShoreDep) -> Ingest:
    return shore.ingest


def bus(shore: ShoreDep) -> EventBus:
    return shore.bus


ReadSession = Annotated[Session, Depends(db)]
Writer = Callable[[], AbstractContextManager[Session]]
WriteDep = Annotated[Writer, Depends(writer)]
SettingsDep = Annotated[Settings, Depends(settings)]
CommandsDep = Annotated[CommandDesk, Depends(command_desk)]
LinkDep = Annotated[LinkEngine, Depends(link)]
IngestDep = Annotated[Ingest, Depends(ingest)]
BusDep = Annotated[EventBus, Depends(bus)]

DB_INT_MAX = 2**31 - 1  # what every database's INTEGER holds: larger ids cannot exist, say 422 not 500
Id = Annotated[int, Path(ge=1, le=DB_INT_MAX)]
QueryId = Annotated[int, Query(ge=1, le=DB_INT_MAX)]
OptionalId = Annotated[int | None, Query(ge=1, le=DB_INT_MAX)]
Offset = Annotated[int, Query(ge=0, le=DB_INT_MAX)]
