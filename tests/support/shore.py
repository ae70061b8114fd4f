"""A shore in one process on a database file, its link engine driven slot by slot by a scripted modem (the
tests of the MAC): simulated time runs 1000x and no SYNC falls due unless a test asks."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from server.core.config import Settings
from server.core.db import make_engine, migrate, writing
from server.shore import Shore
from server.vehicles.models import Vehicle


def scripted_shore(tmp_path: Path, keys: list[str], **overrides: Any) -> Shore:
    """The shore with one vehicle per key (``rov1`` at modem address 2, ``rov2`` at 3, ...), loaded."""
    defaults: dict[str, Any] = {
        "database_url": f"sqlite:///{tmp_path}/tacit.db",
        "modem_url": "",
        "time_scale": 1000.0,
        "sync_interval": 1e6,
    }
    settings = Settings(**{**defaults, **overrides})
    migrate(settings.database_url)
    db = make_engine(settings.database_url)
    with writing(db) as s:
        for i, key in enumerate(keys):
            s.add(Vehicle(name=f"rov{i + 1}", address=2 + i, key_hex=key))
        s.commit()
    shore = Shore.build(settings, db)
    shore.ingest.load_vehicles()
    return shore
