"""A connection a browser gives up before its request (a tab closed while the 3D map loads) is one line
at INFO, not the three chained tracebacks ``websockets`` logs for a failed opening handshake; a request
that is not HTTP stays an error with its traceback."""

from __future__ import annotations

import logging
import socket
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.map.connections import GIVEN_UP
from tests.support.api import offline_settings
from tests.support.nats import free_port


def handshake_records(caplog: pytest.LogCaptureFixture, count: int) -> list[logging.LogRecord]:
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        found = [
            r for r in caplog.records if r.name == "websockets.server" and "connection open" not in r.msg
        ]
        found = [r for r in found if "handshake" in r.getMessage() or r.getMessage() == GIVEN_UP]
        if len(found) >= count:
            return found
        time.sleep(0.05)
    raise AssertionError(f"{count} handshake records expected: {[r.getMessage() for r in caplog.records]}")


def test_a_connection_given_up_before_its_request_is_one_line(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="websockets.server")
    settings = offline_settings(tmp_path, map_enabled=True, map_port=free_port(), metrics_port=0)
    with TestClient(create_app(settings)):
        address = ("127.0.0.1", settings.map_port)
        socket.create_connection(address).close()  # opened ahead, never used
        with socket.create_connection(address) as partial:  # the tab closed mid-request
            partial.sendall(b"GET / HTTP/1.1\r\nHost: map\r\n")
            time.sleep(0.2)
        given_up = handshake_records(caplog, 2)
        with socket.create_connection(address) as garbage:
            garbage.sendall(b"\x16\x03\x01 not http at all\r\n\r\n")
            time.sleep(0.2)
        records = handshake_records(caplog, 3)
    assert [(r.levelno, r.getMessage(), r.exc_info) for r in given_up] == [(logging.INFO, GIVEN_UP, None)] * 2
    (error,) = records[2:]
    assert (
        error.levelno == logging.ERROR and error.getMessage() == "opening handshake failed" and error.exc_info
    )
