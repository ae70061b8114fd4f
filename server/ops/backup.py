"""Backup and restore of a center's database: ``tacit database backup FILE`` and ``tacit database
restore FILE``.

PostgreSQL: ``pg_dump --format=custom`` (a consistent snapshot of a running database) and
``pg_restore`` into an empty database, in one transaction. SQLite (the embedded default): SQLite's
online backup API, consistent while the server writes. The file is one JSON line (the format, the kind of
database, the payload's size and SHA-256) and the payload: restore checks both before it writes anything
(a flipped byte inside a value passes SQLite's own integrity check). A backup holds every vehicle's key:
it is written readable by its owner only (mode 600). A restored database is brought to the running
version's schema by the server's migrations at its next start.

Standard library only (``pg_dump`` and ``pg_restore`` from the PostgreSQL client programs).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import sqlite3
import subprocess
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import BinaryIO

DEFAULT_URL = "sqlite:///data/tacit.db"
FORMAT = "tacit-backup"
VERSION = 1
MAX_HEADER = 4096  # bytes: a header line is about 150
CHUNK = 1 << 20


class BackupError(RuntimeError):
    """A backup or restore that did not complete; the message says why."""


@dataclass(frozen=True)
class Header:
    """The backup file's first line: what follows it (the payload: a SQLite file or a ``pg_dump`` archive),
    its length and its SHA-256, which restore checks before anything is written."""

    kind: str  # "sqlite" or "postgresql"
    sha256: str
    size: int

    def line(self) -> bytes:
        fields = {"format": FORMAT, "version": VERSION, **asdict(self)}
        return json.dumps(fields, separators=(",", ":")).encode() + b"\n"

    @classmethod
    def read(cls, f: BinaryIO, path: Path) -> Header:
        line = f.readline(MAX_HEADER)
        try:
            fields = json.loads(line)
            if fields.pop("format") != FORMAT or fields.pop("version") != VERSION:
                raise ValueError
            return cls(str(fields["kind"]), str(fields["sha256"]), int(fields["size"]))
        except (ValueError, KeyError, TypeError, AttributeError):
            raise BackupError(
                f"{path}: not a Tacit backup (no checksummed header): nothing restored"
            ) from None


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
    except sqlite3.Error as exc:
        raise BackupError(f"{source}: {exc}") from None
    finally:
        src.close()
        dst.close()


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(CHUNK):
            h.update(chunk)
    return h.hexdigest()


def _parts(path: Path) -> tuple[Path, Path]:
    """Where a file is built beside ``path`` before it takes its name: the whole and the payload."""
    return path.with_name(path.name + ".part"), path.with_name(path.name + ".payload")


def backup(url: str, path: Path) -> None:
    """Write a backup of the database at ``url`` to ``path``: a header with the payload's size and SHA-256,
    then the payload (replaced only once the backup is whole)."""
    part, payload = _parts(path)
    _private(part)
    _private(payload)
    try:
        source = _sqlite_path(url)
        if source is not None:
            if not source.exists():
                raise BackupError(f"{source}: no such database")
            _copy(source, payload)
        else:
            _run("pg_dump", "--format=custom", f"--file={payload}", _libpq(url))
        header = Header(
            "sqlite" if source is not None else "postgresql", _digest(payload), payload.stat().st_size
        )
        with part.open("wb") as out, payload.open("rb") as f:
            out.write(header.line())
            shutil.copyfileobj(f, out, CHUNK)
        part.replace(path)
    finally:
        part.unlink(missing_ok=True)
        payload.unlink(missing_ok=True)


def _extract(path: Path, into: Path) -> Header:
    """Check the backup at ``path`` against its header and write its payload to ``into`` (``BackupError``
    naming what is wrong: not a backup, truncated, or a checksum that does not match)."""
    if not path.exists():
        raise BackupError(f"{path}: no such backup")
    h = hashlib.sha256()
    size = 0
    with path.open("rb") as f, into.open("wb") as out:
        header = Header.read(f, path)
        while chunk := f.read(CHUNK):
            h.update(chunk)
            size += len(chunk)
            out.write(chunk)
    if size != header.size:
        raise BackupError(
            f"{path}: truncated or padded ({size} bytes after the header, it says {header.size}): nothing restored"
        )
    if h.hexdigest() != header.sha256:
        raise BackupError(
            f"{path}: corrupt (its SHA-256 is {h.hexdigest()[:16]}..., the header says "
            f"{header.sha256[:16]}...): nothing restored"
        )
    return header


def restore(path: Path, url: str) -> None:
    """Restore the backup at ``path`` into the database at ``url``, which must be empty (a SQLite file
    that does not exist yet, or a PostgreSQL database just created). The backup's size and SHA-256 are
    checked first: a corrupt or truncated one restores nothing and leaves no file behind."""
    target = _sqlite_path(url)
    if target is None:
        _libpq(url)
        with tempfile.TemporaryDirectory(prefix="tacit-restore-") as scratch:
            payload = Path(scratch) / "payload"
            _checked(path, payload, "postgresql")
            _run("pg_restore", "--exit-on-error", "--single-transaction", "--no-owner", "--no-privileges",
                 f"--dbname={_libpq(url)}", str(payload))  # fmt: skip
        return
    if target.exists() and target.stat().st_size:
        raise BackupError(f"{target} exists: restore into a new file, then move it in place")
    made = [p for p in (target.parent, *target.parent.parents) if not p.exists()]
    part, payload = _parts(target)
    try:
        _private(payload)
        _checked(path, payload, "sqlite")
        _private(part)
        _copy(payload, part)
        part.replace(target)
    except BaseException:
        for folder in made:  # the folders it made for the file, innermost first
            shutil.rmtree(folder, ignore_errors=True)
        raise
    finally:
        part.unlink(missing_ok=True)
        payload.unlink(missing_ok=True)


def _checked(path: Path, payload: Path, kind: str) -> None:
    """The backup's payload, checked, in ``payload``; refused if it is not a backup of a ``kind`` database."""
    found = _extract(path, payload).kind
    if found != kind:
        raise BackupError(f"{path} is a {found} backup: restore it into a {found} database")


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
    except (BackupError, OSError) as exc:  # OSError: a folder that cannot be written, a full disk
        print(f"tacit database {args.action}: {exc}", file=sys.stderr)
        return 2
    print(f"{args.action}: {args.file}")
    return 0
