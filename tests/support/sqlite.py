"""A test's own SQLite store, already migrated: the schema is migrated once per test process into a
template file, and each store is a copy of it. Migrating a fresh file costs about a second of fsyncs
(a commit per migration); a copy costs milliseconds, and the app's start-up migration finds it current.
Each test still has its own file: nothing is shared but the empty schema."""

from __future__ import annotations

import atexit
import shutil
import sqlite3
import tempfile
from functools import cache
from pathlib import Path

from server.core.db import migrate


def migrated(path: Path) -> str:
    """The URL of the store at ``path``: a copy of the migrated template, unless a store is there already
    (a test that restarts its shore finds what it stored)."""
    if not path.exists():
        shutil.copyfile(_template(), path)
        path.chmod(0o600)  # as the app makes it: it holds the vehicles' keys
    return f"sqlite:///{path}"


@cache
def _template() -> Path:
    folder = Path(tempfile.mkdtemp(prefix="tacit-schema-"))
    atexit.register(shutil.rmtree, folder, True)
    path = folder / "tacit.db"
    migrate(f"sqlite:///{path}")
    with sqlite3.connect(path) as c:  # everything in the one file: no -wal left to copy
        c.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    return path
