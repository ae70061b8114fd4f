"""Files only their owner may read or write: the demo's data folder, logs, tlogs and keys.

The one place such files and folders are created: a log or a tlog holds every frame and every
measurement of a dive, a data folder the database, tokens and keys. Created with the narrow mode at
once (``os.open`` with 0o600), never widened later, whatever the umask; an existing file is narrowed.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import IO, Any

FILE_MODE = 0o600
DIR_MODE = 0o700


def private_dir(path: str | Path, narrow: bool = False) -> Path:
    """``path`` as a folder, created owner-only if missing (missing parents too); an existing one is
    narrowed only with ``narrow`` (a folder this program owns, such as the demo's data folder, not a
    shared one a log happens to be put in)."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True, mode=DIR_MODE)
    if narrow:
        os.chmod(path, DIR_MODE)
    return path


def open_private(path: str | Path, mode: str = "a", **kwargs: Any) -> IO[Any]:
    """Open ``path`` for writing (``mode`` "a", "w", "ab" or "wb"; ``kwargs`` as for ``open``), created
    owner-only; an existing file is narrowed to the owner."""
    if mode not in ("a", "w", "ab", "wb"):
        raise ValueError(f"open_private writes only: mode {mode!r}")
    flags = os.O_WRONLY | os.O_CREAT | (os.O_APPEND if mode.startswith("a") else os.O_TRUNC)
    fd = os.open(path, flags, FILE_MODE)
    os.fchmod(fd, FILE_MODE)
    return os.fdopen(fd, mode, **kwargs)
