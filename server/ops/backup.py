"""Backup and restore of a center's database: ``tacit database backup FILE`` and ``tacit database
restore FILE``.

PostgreSQL: ``pg_dump --format=custom`` (a consistent snapshot of a running database) and
``pg_restore`` into an empty database, in one transaction. SQLite (the embedded default): SQLite's
online backup API, consistent while the server writes. A backup holds every vehicle's key: it is written
readable by its owner only (mode 600). A restored database is brought to the running version's schema
by the server's migrations at its next start.

Standard library only (``pg_dump`` and ``pg_restore`` from the PostgreSQL client programs).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

DEFAULT_URL = "sqlite:///data/tacit.db"


class BackupError(RuntimeError):
    """A backup or restore that did not complete; the message says why."""


def _sqlite_path(url: str) -> Path | None:
    return Path(url.removeprefix("sqlite:///")) if url.startswith("sqlite:///") else None


def _libpq(url: str) -> str:
    """A PostgreSQL URL as libpq reads it (SQLAlchemy's driver name removed)."""
    if not url.startswith(("postgresql://", "postgresql+")):
        raise BackupError(f"not a SQLite file or PostgreSQL database: {url.split('://')[0]}://")
    return "postgresql://" + url.split("://", 1)[1]


def _private(path: Path) -> None:
    """``path`` exists, empty, readable by its owner only."""
    path.parent.mkdir(parents=True, exist_ok=True)
    os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600))
    path.chmod(0o600)


def _run(program: str, *args: str) -> None:
    found = shutil.which(program)
    if found is None:
        raise BackupError(f"{program} is not installed (PostgreSQL's client programs)")
    done = subprocess.run([found, *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise BackupError(f"{program} failed: {done.stderr.strip()}")


def _copy(source: Path, target: Path) -> None:
    """SQLite's online backup: page by page, consistent while another connection writes."""
    src, dst = sqlite3.connect(source), sqlite3.connect(target)
    try:
        src.backup(dst)
    finally:
        src.close()
        dst.close()


def backup(url: str, path: Path) -> None:
    """Write a backup of the database at ``url`` to ``path`` (replaced only once the backup is whole)."""
    part = path.with_name(path.name + ".part")
    _private(part)
    try:
        source = _sqlite_path(url)
        if source is not None:
            if not source.exists():
                raise BackupError(f"{source}: no such database")
            _copy(source, part)
        else:
            _run("pg_dump", "--format=custom", f"--file={part}", _libpq(url))
        part.replace(path)
    finally:
        part.unlink(missing_ok=True)


def restore(path: Path, url: str) -> None:
    """Restore the backup at ``path`` into the database at ``url``, which must be empty (a SQLite file
    that does not exist yet, or a PostgreSQL database just created)."""
    if not path.exists():
        raise BackupError(f"{path}: no such backup")
    target = _sqlite_path(url)
    if target is None:
        _run("pg_restore", "--exit-on-error", "--single-transaction", "--no-owner", "--no-privileges",
             f"--dbname={_libpq(url)}", str(path))  # fmt: skip
        return
    if target.exists() and target.stat().st_size:
        raise BackupError(f"{target} exists: restore into a new file, then move it in place")
    _private(target)
    _copy(path, target)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Back up the center's database, or restore a backup into an empty one (PostgreSQL: pg_dump and "
        "pg_restore; SQLite: its online backup). The backup holds the vehicles' keys: it is mode 600."
    )
    parser.add_argument("action", choices=["backup", "restore"])
    parser.add_argument("file", type=Path, help="the backup file")
    parser.add_argument(
        "--database-url",
        default=os.environ.get("TACIT_DATABASE_URL", DEFAULT_URL),
        help="the database (default TACIT_DATABASE_URL or %(default)s)",
    )


def run(args: argparse.Namespace) -> int:
    try:
        if args.action == "backup":
            backup(args.database_url, args.file)
        else:
            restore(args.file, args.database_url)
    except BackupError as exc:
        print(f"tacit database {args.action}: {exc}", file=sys.stderr)
        return 2
    print(f"{args.action}: {args.file}")
    return 0
