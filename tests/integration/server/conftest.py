"""Fixtures the backhaul's tests share."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import TypeVar

import pytest

from tests.support.nats import NatsServer, Secured
from tests.support.sqlite import migrated

Server = TypeVar("Server", bound=NatsServer)


def running(server: Server) -> Iterator[Server]:
    """The server started for the test, stopped afterwards."""
    server.start()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[NatsServer]:
    """A nats-server of the test's own (JetStream, its own port and folder), stopped afterwards."""
    yield from running(NatsServer(tmp_path))


@pytest.fixture
def secured(tmp_path: Path) -> Iterator[Secured]:
    """A nats-server with the accounts ``tacit broker-config`` writes for the gateways ``ship`` and
    ``buoy`` (and the center), its monitoring on (``Secured.received``)."""
    yield from running(Secured(tmp_path / "broker", ["ship", "buoy"], monitor=True))


@pytest.fixture
def sqlite_url(tmp_path: Path) -> str:
    """A center's store: a migrated SQLite file of the test's own."""
    return migrated(tmp_path / "center.db")
