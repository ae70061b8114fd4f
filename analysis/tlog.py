"""The one reader of MAVLink telemetry logs (``.tlog``): used by ``tacit eval-compression``, the
replay's summary, the benchmarks and the simulator that streams a real dive."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pymavlink import mavutil


def messages(path: str | Path, kind: str | None = None) -> Iterator[Any]:
    """Every message of ``kind`` (all kinds if None) in the log, in order; each has ``_timestamp``
    (UNIX s, when the ground station logged it). Corrupt bytes are skipped (``BAD_DATA``)."""
    if not Path(path).is_file():  # else pymavlink takes the name for a serial port: "could not open port"
        raise FileNotFoundError(f"{path}: no such file")
    conn = mavutil.mavlink_connection(str(path), robust_parsing=True)
    try:
        while (msg := conn.recv_match(type=kind, blocking=False)) is not None:
            if msg.get_type() != "BAD_DATA":
                yield msg
    finally:
        conn.close()
