"""The database: engine with SQLite's pragmas, schema by alembic migrations applied at start-up, and the
two kinds of session the services open (``reading``, ``writing``). Only repositories run SQL on them."""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
import weakref
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Protocol

from alembic import command
from alembic.config import Config
from sqlalchemy import Connection, Engine, event
from sqlmodel import Session, create_engine

IMMEDIATE = "tacit_begin_immediate"
MIGRATIONS = (
    Path(__file__).resolve().parents[1] / "migrations"
)  # top-level migrations/, shipped in the package
Tx = Session  # what services hold and hand to repositories; they never build a query themselves


def now() -> float:
    """Times are UNIX seconds (float), so SQLite and PostgreSQL agree without zones."""
    return time.time()


class _Stored(Protocol):
    id: int | None


def saved_id(row: _Stored) -> int:
    """A stored row's primary key; a row not yet flushed has none, and asking for it is a bug."""
    if row.id is None:
        raise ValueError(f"{type(row).__name__} is not stored yet")
    return row.id


def make_engine(url: str) -> Engine:
    """An engine; for a SQLite file: WAL, synchronous=NORMAL, foreign keys, busy timeout. Sessions
    opened with ``writing`` begin IMMEDIATE: a deferred transaction that reads, then writes, fails at
    once with SQLITE_BUSY if another connection wrote in between (busy_timeout cannot help it), while
    IMMEDIATE takes the write lock up front and waits its turn. Reads stay deferred and, in WAL mode,
    never wait for a writer."""
    if url.startswith("sqlite:///") and url != "sqlite:///:memory:":
        path = Path(url.removeprefix("sqlite:///"))
        path.parent.mkdir(parents=True, exist_ok=True)
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT, 0o600))  # owner-only: it holds the vehicle keys
        os.chmod(path, 0o600)  # SQLite gives its -wal and -shm files the database file's mode
    engine = create_engine(url, connect_args={"check_same_thread": False} if url.startswith("sqlite") else {})
    if url.startswith("sqlite"):

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_connection: Any, _record: object) -> None:
            dbapi_connection.isolation_level = None  # SQLAlchemy's "begin" event below opens transactions
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.execute("PRAGMA foreign_keys=ON")
            cursor.execute("PRAGMA busy_timeout=5000")
            cursor.close()

        @event.listens_for(engine, "begin")
        def _begin(connection: Connection) -> None:
            immediate = connection.get_execution_options().get(IMMEDIATE, False)
            connection.exec_driver_sql("BEGIN IMMEDIATE" if immediate else "BEGIN")

    return engine


def alembic_config(url: str) -> Config:
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    config.set_main_option("sqlalchemy.url", url)
    return config


def migrate(url: str, revision: str = "head") -> None:
    logging.getLogger("alembic").setLevel(logging.WARNING)  # its plugin chatter is not for operators
    command.upgrade(alembic_config(url), revision)


_WRITERS: weakref.WeakKeyDictionary[Engine, threading.Lock] = weakref.WeakKeyDictionary()
_WRITERS_GUARD = threading.Lock()


def _writer_lock(engine: Engine) -> contextlib.AbstractContextManager[object]:
    """SQLite has one writer at a time; the server's own writers queue on a lock in this process
    (woken at once when it is free) instead of in SQLite's busy handler, which sleeps and retries and,
    with many waiters, starves some past the busy timeout. PostgreSQL needs no such lock."""
    if engine.dialect.name != "sqlite":
        return contextlib.nullcontext()
    with _WRITERS_GUARD:
        return _WRITERS.setdefault(engine, threading.Lock())


@contextmanager
def writing(engine: Engine) -> Iterator[Session]:
    """A session for a transaction that writes (IMMEDIATE on SQLite; ordinary elsewhere). Keep it
    short: on SQLite it holds the process's write lock until the session closes."""
    with _writer_lock(engine), Session(engine, expire_on_commit=False) as s:
        s.connection(execution_options={IMMEDIATE: True})
        yield s


@contextmanager
def reading(engine: Engine) -> Iterator[Session]:
    """A session for reads (deferred: in WAL mode it never waits for a writer)."""
    with Session(engine, expire_on_commit=False) as s:
        yield s
