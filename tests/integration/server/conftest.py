"""Fixtures the backhaul's tests share."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from server.core.db import migrate
from tests.support.nats import NatsServer, Secured


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[NatsServer]:
    """A nats-server of the test's own (JetStream, its own port and folder), stopped afterwards."""
    server = NatsServer(tmp_path)
    server.start()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def secured(tmp_path: Path) -> Iterator[Secured]:
    """A nats-server with the users and permissions ``tacit broker-config`` writes for the gateways
    ``ship`` and ``buoy`` (and the center)."""
    server = Secured(tmp_path / "broker", ["ship", "buoy"])
    server.start()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def sqlite_url(tmp_path: Path) -> str:
    """A center's store: a migrated SQLite file of the test's own."""
    url = f"sqlite:///{tmp_path}/center.db"
    migrate(url)
    return url
