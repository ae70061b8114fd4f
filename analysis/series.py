"""Time series from files: CSV extracts and MAVLink ``.tlog`` logs, as (times, samples x channels)."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from tacit.codec import StreamSpec

DEFAULT_TLOG_COLUMNS = tuple(f"RAW_IMU.{f}" for f in
                             ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag"))  # fmt: skip


@dataclass(frozen=True)
class Series:
    names: tuple[str, ...]
    times: np.ndarray  # seconds, increasing
    values: np.ndarray  # samples x channels

    @property
    def period(self) -> float:
        """The nominal sample period: the median interval."""
        steps = np.diff(self.times)
        steps = steps[steps > 0]
        if not len(steps):
            raise ValueError("a series needs at least two distinct times")
        return float(np.median(steps))


def load(path: str | Path, columns: list[str] | None = None, time_column: str | None = None,
         period: float | None = None) -> Series:  # fmt: skip
    path = Path(path)
    if path.suffix.lower() == ".tlog":
        return load_tlog(path, columns or list(DEFAULT_TLOG_COLUMNS))
    return load_csv(path, columns, time_column, period)


def load_csv(path: Path, columns: list[str] | None, time_column: str | None, period: float | None) -> Series:
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        header = reader.fieldnames or []
        if time_column is None and "t_unix_s" in header:
            time_column = "t_unix_s"
        wanted = columns or [h for h in header if h != time_column]
        missing = [c for c in [*wanted, *([time_column] if time_column else [])] if c not in header]
        if missing:
            raise ValueError(f"{path.name}: no column(s) {missing}; the file has {header}")
        rows = list(reader)
    if not rows:
        raise ValueError(f"{path.name}: no rows")
    try:
        values = np.array([[float(r[c]) for c in wanted] for r in rows])
    except ValueError as exc:
        raise ValueError(f"{path.name}: a value is not a number ({exc})") from None
    if time_column:
        times = np.array([float(r[time_column]) for r in rows])
    else:
        times = np.arange(len(rows)) * (period or 1.0)
    return Series(tuple(wanted), times, values)


def load_tlog(path: Path, columns: list[str]) -> Series:
    """One sample per message of the columns' message type (all columns from one type)."""
    from pymavlink import mavutil

    kinds = {c.split(".", 1)[0] for c in columns}
    if len(kinds) != 1 or any("." not in c for c in columns):
        raise ValueError("tlog columns are MESSAGE.field, all of one message type, e.g. RAW_IMU.xacc")
    kind = kinds.pop()
    fields = [c.split(".", 1)[1] for c in columns]
    if not Path(path).is_file():  # else pymavlink takes the name for a serial port: "could not open port"
        raise FileNotFoundError(f"{path}: no such file")
    conn = mavutil.mavlink_connection(str(path), robust_parsing=True)
    times, values = [], []
    try:
        while (msg := conn.recv_match(type=kind, blocking=False)) is not None:
            try:
                values.append([float(getattr(msg, f)) for f in fields])
            except AttributeError as exc:
                raise ValueError(f"{kind} has no field {exc.name!r}") from None
            times.append(msg._timestamp)
    finally:
        conn.close()
    if not values:
        raise ValueError(f"{path.name}: no {kind} messages")
    return Series(tuple(columns), np.array(times), np.array(values))


def measured_per_tick(folder: Path, kind: str, fields: Sequence[str], spec: StreamSpec,
                      scale: float = 1.0) -> dict[int, list[float]]:  # fmt: skip
    """What a vehicle measured, from the agent's tlogs in ``folder``: per codec tick, the first sample
    of ``kind`` (the one the encoder kept; later duplicates of a tick are dropped), fields times ``scale``."""
    from pymavlink import mavutil

    measured: dict[int, list[float]] = {}
    for tlog in sorted(folder.glob("*.tlog")):
        conn = mavutil.mavlink_connection(str(tlog))
        try:
            while (msg := conn.recv_match(type=kind, blocking=False)) is not None:
                measured.setdefault(
                    spec.tick(msg._timestamp), [float(getattr(msg, f)) * scale for f in fields]
                )
        finally:
            conn.close()
    return measured
