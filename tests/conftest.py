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
from hypothesis import HealthCheck, settings

from launch.processes import stop
from launch.split import throwaway_database as postgres_database
from tests.support.sqlite import migrated

# Property tests check behaviour, not speed: no per-example deadline (on a loaded machine one made a
# round-trip test fail on time alone). Every property test inherits this profile.
settings.register_profile("tacit", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("tacit")

# Real logs kept in the repository (tests/data/README.md says where from): no test reads outside it.
DATA = Path(__file__).resolve().parent / "data"


@contextmanager
def tacit_process(
    *args: str, cwd: Path | None = None
) -> Iterator[tuple[subprocess.Popen[str], dict[str, Any]]]:
    """Run ``tacit ARGS --json``; yield the process and the JSON object of its first line."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "tacit.cli", *args, "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=cwd,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        line = proc.stdout.readline()  # type: ignore[union-attr]
        if not line:
            raise RuntimeError(f"tacit {args[0]} exited: {proc.stderr.read()}")  # type: ignore[union-attr]
        yield proc, json.loads(line)
    finally:
        stop(proc)


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[str]:
    """The PostgreSQL server the tests use: TACIT_TEST_POSTGRES (default postgres@127.0.0.1:5432) if it
    answers, else a throwaway cluster for this session (tests/support/postgres.py). Exported as
    TACIT_TEST_POSTGRES for the processes the tests start."""
    from tests.support.postgres import postgres_server as server

    with server() as url:
        before = os.environ.get("TACIT_TEST_POSTGRES")
        os.environ["TACIT_TEST_POSTGRES"] = url
        try:
            yield url
        finally:
            if before is None:
                os.environ.pop("TACIT_TEST_POSTGRES", None)
            else:
                os.environ["TACIT_TEST_POSTGRES"] = before


TIERS = ("unit", "integration", "system")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark each test with its tier, the folder under tests/ it lives in."""
    here = Path(__file__).resolve().parent
    for item in items:
        path = item.path.resolve()
        parts = path.relative_to(here).parts if path.is_relative_to(here) else ()
        if parts and parts[0] in TIERS:
            item.add_marker(getattr(pytest.mark, parts[0]))


@pytest.fixture(scope="session")
def postgres_template(postgres_server: str) -> Iterator[str]:
    """A database migrated once per session on ``postgres_server``, to copy (``CREATE DATABASE ...
    TEMPLATE``): a copy costs a fraction of a second, a migration a second or more. Its name."""
    from server.core.db import migrate

    with postgres_database(postgres_server, prefix="tacit_template") as url:
        migrate(url)  # alembic's connections are closed when it returns: the template is free to copy
        yield url.rsplit("/", 1)[1]


@pytest.fixture(params=["sqlite", "postgresql"])
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The same tests on the embedded default (a SQLite file) and on a real PostgreSQL server, each a
    migrated store of the test's own (copies of a template migrated once: the migration test migrates
    down to empty and up again)."""
    if request.param == "sqlite":
        yield migrated(tmp_path / "tacit.db")
    else:
        from tests.support.postgres import copied_database

        server = request.getfixturevalue("postgres_server")
        with copied_database(server, request.getfixturevalue("postgres_template")) as url:
            yield url


@pytest.fixture(scope="session")
def real_data() -> Path:
    """The folder of real data files (``real_data / "ardusub" / "small.tlog"``), inside the repository."""
    return DATA
