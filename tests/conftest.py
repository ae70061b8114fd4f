"""Shared fixtures: simulator processes started as a user would start them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from launch.processes import stop

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@contextmanager
def tacit_process(
    *args: str, cwd: Path | None = None
) -> Iterator[tuple[subprocess.Popen[str], dict[str, Any]]]:
    """Run ``tacit ARGS --json``; yield the process and the JSON object of its first line."""
    proc = subprocess.Popen([sys.executable, "-m", "tacit.cli", *args, "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=cwd, env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip
    try:
        line = proc.stdout.readline()  # type: ignore[union-attr]
        if not line:
            raise RuntimeError(f"tacit {args[0]} exited: {proc.stderr.read()}")  # type: ignore[union-attr]
        yield proc, json.loads(line)
    finally:
        stop(proc)


POSTGRES = os.environ.get("TACIT_TEST_POSTGRES", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


@contextmanager
def postgres_database() -> Iterator[str]:
    """A fresh, empty PostgreSQL database on the test server, dropped afterwards."""
    import uuid

    import psycopg

    name = f"tacit_{uuid.uuid4().hex[:12]}"
    admin = POSTGRES.replace("postgresql+psycopg://", "postgresql://")
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield POSTGRES.rsplit("/", 1)[0] + "/" + name
    finally:
        with psycopg.connect(admin, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE "{name}" WITH (FORCE)')


@pytest.fixture(params=["sqlite", "postgresql"])
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The same tests on the embedded default (a SQLite file) and on a real PostgreSQL server."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path}/tacit.db"
    else:
        with postgres_database() as url:
            yield url


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not DATA.is_dir():
        raise FileNotFoundError(f"the shared data folder is missing at {DATA}")
    return DATA
