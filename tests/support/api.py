"""The API in one process with no modem and no map, as the API tests run it: its settings and the
headers of its two tokens."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from server.core.config import Settings
from tests.support.sqlite import migrated

OP = {"Authorization": "Bearer operator-token"}
OBSERVER = {"Authorization": "Bearer observer-token"}


def offline_settings(tmp_path: Path, **overrides: Any) -> Settings:
    """A shore on a database file in ``tmp_path`` (migrated: ``tests.support.sqlite``), no modem, no map,
    an operator's and an observer's token; ``overrides`` for the rest."""
    defaults: dict[str, Any] = {
        "database_url": overrides.get("database_url") or migrated(tmp_path / "tacit.db"),
        "modem_url": "",
        "map_enabled": False,
        "write_tokens": ["operator-token"],
        "read_tokens": ["observer-token"],
    }
    return Settings(**{**defaults, **overrides})
