"""Time series from files: CSV extracts and MAVLink ``.tlog`` logs, as (times, samples x channels)."""

from __future__ import annotations

import csv
import gzip
import itertools
import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC
from pathlib import Path

import numpy as np
from tqdm import tqdm

from analysis import tlog
from tacit.sampletime import SampleClock, boot_seconds

DEFAULT_TLOG_COLUMNS = tuple(
    f"RAW_IMU.{f}" for f in ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag")
)


MISSING = {"", "nan", "na", "n/a", "null", "none", "missing", "-", "--", "?"}
EPOCH_UNITS = (("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("ns", 1e-9))


@dataclass(frozen=True)
class Series:
    names: tuple[str, ...]
    times: np.ndarray  # seconds, non-decreasing
    values: np.ndarray  # samples x channels, NaN = absent (a blank or missing cell)
    notes: tuple[str, ...] = ()  # what the reader assumed (time unit, zone, skipped columns, sorting)

    @property
    def period(self) -> float:
        """The nominal sample period: the median interval."""
        steps = np.diff(self.times)
        steps = steps[steps > 0]
        if not len(steps):
            raise ValueError("a series needs at least two distinct times")
        return float(np.median(steps))

    @property
    def absent(self) -> int:
        return int(np.isnan(self.values).sum())


def load(
    path: str | Path,
    columns: list[str] | None = None,
    time_column: str | None = None,
    period: float | None = None,
    time_unit: str | None = None,
    progress: bool = False,
) -> Series:
    path = Path(path)
    if path.suffix.lower() == ".tlog":
        return load_tlog(path, columns or list(DEFAULT_TLOG_COLUMNS))
    return load_csv(path, columns, time_column, period, time_unit, progress)


def _number(cell: str) -> float | None:
    """A cell's value: a float, NaN for a missing marker, None for text."""
    text = cell.strip()
    if text.lower() in MISSING:
        return float("nan")
    try:
        return float(text)
    except ValueError:
        return None


def parse_times(cells: list[str], column: str, unit: str | None = None) -> tuple[np.ndarray, list[str]]:
    """Seconds since the UNIX epoch (or since the start) from a column of ISO-8601 or numeric times,
    and notes saying what was assumed. ``unit`` (s, ms, us, ns) overrides the numeric detection."""
    notes: list[str] = []
    numbers = [_number(c) for c in cells]
    if all(n is not None for n in numbers):
        raw = np.array(numbers, dtype=float)
        if np.isnan(raw).any():
            row = int(np.argmax(np.isnan(raw))) + 2
            raise ValueError(f"time column {column!r} is blank at row {row}")
        if unit is None:
            magnitude = float(np.median(np.abs(raw))) if len(raw) else 0.0
            # UNIX time since 2001 in s, ms, us or ns; anything smaller is seconds from a start
            unit = next((u for u, scale in EPOCH_UNITS if 9.8e8 <= magnitude * scale <= 5e9), None)
            if unit is None:
                notes.append(f"time column {column!r}: numbers too small for UNIX time; read as seconds")
                unit = "s"
            else:
                notes.append(f"time column {column!r}: UNIX time in {unit} (from its magnitude)")
        return raw * dict(EPOCH_UNITS)[unit], notes
    if cells and SLASHED.match(cells[0].strip()):
        return _slashed_times(cells, column)
    from datetime import datetime

    out = np.empty(len(cells))
    naive = False
    for i, cell in enumerate(cells):
        text = YEAR_FIRST.sub(r"\1-\2-\3", cell.strip())  # 2020/09/08 as 2020-09-08
        if text.endswith("Z"):
            text = text[:-1] + "+00:00"
        try:
            stamp = datetime.fromisoformat(text)
        except ValueError:
            raise ValueError(
                f"time column {column!r}, row {i + 2}: {cell!r} is neither a number nor ISO-8601"
            ) from None
        if stamp.tzinfo is None:
            naive = True
            stamp = stamp.replace(tzinfo=UTC)
        out[i] = stamp.timestamp()
    notes.append(
        f"time column {column!r}: ISO-8601" + (", no zone given: read as UTC" if naive else " with zone")
    )
    return out, notes


YEAR_FIRST = re.compile(r"^(\d{4})/(\d{2})/(\d{2})")
SLASHED = re.compile(r"(\d{1,2})/(\d{1,2})/(\d{4})[ T](\d{1,2}):(\d{2})(?::(\d{2}(?:\.\d*)?))?$")


def _slashed_times(cells: list[str], column: str) -> tuple[np.ndarray, list[str]]:
    """Times written ``dd/mm/yyyy HH:MM[:SS.fff]`` (as a SeaExplorer glider logs them) or ``mm/dd/yyyy``:
    the order is the one the values allow (a first field over 12 is a day; a second over 12, a day);
    day first when both fit. No zone: read as UTC."""
    from datetime import datetime

    parts = []
    for i, cell in enumerate(cells):
        match = SLASHED.match(cell.strip())
        if match is None:
            raise ValueError(f"time column {column!r}, row {i + 2}: {cell!r} is not dd/mm/yyyy HH:MM:SS")
        parts.append(match.groups())
    month_first = any(int(p[1]) > 12 for p in parts) and not any(int(p[0]) > 12 for p in parts)
    out = np.empty(len(parts))
    try:
        for i, (a, b, year, hour, minute, second) in enumerate(parts):
            day, month = (b, a) if month_first else (a, b)
            stamp = datetime(int(year), int(month), int(day), int(hour), int(minute), tzinfo=UTC)
            out[i] = stamp.timestamp() + float(second or 0.0)
    except ValueError as exc:
        raise ValueError(f"time column {column!r}: {exc}") from None
    order = "mm/dd/yyyy" if month_first else "dd/mm/yyyy"
    ambiguous = not any(int(p[0]) > 12 or int(p[1]) > 12 for p in parts)
    return out, [
        f"time column {column!r}: {order} HH:MM:SS"
        + (" (either order fits: read day first)" if ambiguous else "")
        + ", no zone given: read as UTC"
    ]


TIME_NAMES = ("t_unix_s", "time", "timestamp", "datetime", "date_time", "date", "t", "timeus", "time_us")


def _clock(name: str) -> bool:
    """A column named as a time (a log's other clocks: MAVLink's time_boot_ms, time_usec, TimeUS), by its
    words: ``sample_time`` is one, ``runtime_h`` and ``update_count`` are not."""
    words = re.split(r"[^a-z0-9]+", re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name).lower())  # camelCase too
    return name.lower() in TIME_NAMES or any(
        w in ("time", "date", "datetime", "timestamp", "stamp") for w in words
    )


TIME_OF_DAY = re.compile(r"\d{1,2}:\d{2}(:\d{2}(\.\d*)?)?$")


DATE_ONLY = re.compile(r"(\d{4}[-/]\d{2}[-/]\d{2}|\d{1,2}/\d{1,2}/\d{4})$")


def _date_and_time(header: list[str], rows: list[list[str]], time_column: str) -> tuple[str, str] | None:
    """(the date column, the time-of-day column) when a file splits its time in two and
    ``time_column`` is one of them (judged by the first row's cells)."""
    first = {h: rows[0][j].strip() for j, h in enumerate(header)}
    dates = [h for h in header if DATE_ONLY.match(first[h])]
    clocks = [h for h in header if TIME_OF_DAY.match(first[h])]
    if time_column in dates and clocks:
        return time_column, clocks[0]
    if time_column in clocks and dates:
        return dates[0], time_column
    return None


def load_csv(
    path: Path,
    columns: list[str] | None,
    time_column: str | None,
    period: float | None,
    time_unit: str | None = None,
    progress: bool = False,
) -> Series:
    """One row per sample (a ``.gz`` file is read as gzip). Blank, NaN and ``missing`` cells are absent
    values. Text columns are skipped (with a note) unless asked for by name, when they are refused, naming
    the column and row."""
    opener = gzip.open if path.suffix.lower() == ".gz" else open
    with opener(path, "rt", newline="", encoding="utf-8-sig") as handle:
        lines = (line for line in handle if not line.startswith("#"))
        first = next(lines, "")
        # a glider's payload log separates by semicolons (and ends each line with one)
        delimiter = ";" if first.count(";") > first.count(",") else ","
        reader = csv.reader(itertools.chain([first], lines), delimiter=delimiter)
        header = [h.strip() for h in next(reader, [])]
        # on a terminal only, after a second (a log would keep the bar's first "0 rows"), then cleared
        bar = tqdm(
            reader,
            desc=f"reading {path.name}",
            unit=" rows",
            disable=None if progress else True,
            leave=False,
            delay=1.0,
        )
        rows = list(bar)
    if not header:
        raise ValueError(f"{path.name}: empty file")
    if time_column is None:
        time_column = next((h for h in header if h.lower() in TIME_NAMES), None) or next(
            (h for h in header if _clock(h)), None
        )
    clocks = [] if columns else [h for h in header if h != time_column and _clock(h)]  # not measurements
    wanted = columns or [h for h in header if h and h != time_column and h not in clocks]
    missing = [c for c in [*wanted, *([time_column] if time_column else [])] if c not in header]
    if missing:
        raise ValueError(f"{path.name}: no column(s) {missing}; the file has {header}")
    if not rows:
        raise ValueError(f"{path.name}: no rows")
    notes = [
        f"skipped column {h!r}: another clock, not a measurement (name it in --columns to compress it)"
        for h in clocks
    ]
    width = len(header)
    for i, r in enumerate(rows):
        if len(r) < width:
            rows[i] = r + [""] * (width - len(r))
    names, columns_out = [], []
    for name in wanted:
        j = header.index(name)
        cells = [r[j] for r in rows]
        numbers = [_number(c) for c in cells]
        text = next((i for i, n in enumerate(numbers) if n is None), None)
        if text is not None:
            where = f"column {name!r}, row {text + 2}: {cells[text]!r} is not a number"
            if columns:
                raise ValueError(f"{path.name}: {where}")
            notes.append(f"skipped text {where}")
            continue
        names.append(name)
        columns_out.append(numbers)
    if not names:
        raise ValueError(f"{path.name}: no numeric column")
    values = np.array(columns_out, dtype=float).T
    if time_column:
        cells = [r[header.index(time_column)] for r in rows]
        partner = _date_and_time(header, rows, time_column)
        if partner is not None:  # a date column and a time-of-day column (a ship's logger's)
            date, clock = partner
            cells = [f"{r[header.index(date)].strip()} {r[header.index(clock)].strip()}" for r in rows]
            notes.append(f"times: the date in column {date!r}, the time of day in column {clock!r}")
        times, time_notes = parse_times(cells, time_column, time_unit)
        notes.extend(time_notes)
    else:
        times = np.arange(len(rows)) * (period or 1.0)
        notes.append(f"no time column: one row every {period or 1.0} s")
    if np.any(np.diff(times) < 0):
        order = np.argsort(times, kind="stable")
        times, values = times[order], values[order]
        notes.append("rows were not in time order: sorted by time")
    return Series(tuple(names), times, values, tuple(notes))


def load_tlog(path: Path, columns: list[str]) -> Series:
    """One sample per message of the columns' message type (all columns from one type)."""
    kinds = {c.split(".", 1)[0] for c in columns}
    if len(kinds) != 1 or any("." not in c for c in columns):
        raise ValueError("tlog columns are MESSAGE.field, all of one message type, e.g. RAW_IMU.xacc")
    kind = kinds.pop()
    fields = [c.split(".", 1)[1] for c in columns]
    times, values = [], []
    for msg in tlog.messages(path, kind):
        try:
            values.append([float(getattr(msg, f)) for f in fields])
        except AttributeError as exc:
            raise ValueError(f"{kind} has no field {exc.name!r}") from None
        times.append(msg._timestamp)
    if not values:
        raise ValueError(f"{path.name}: no {kind} messages")
    times_array = np.array(times)
    order = np.argsort(times_array, kind="stable")
    return Series(tuple(columns), times_array[order], np.array(values)[order])


@dataclass(frozen=True)
class Measured:
    """What a vehicle measured (from its own log), in time order, to check the shore's reconstruction."""

    times: np.ndarray
    values: np.ndarray  # samples x fields

    def near(self, at: float, within: float) -> list[list[float]]:
        """The samples taken within ``within`` seconds of ``at``: the ones a reconstruction the shore
        dated at ``at`` may be of (the codec dates a sample within half a tick)."""
        lo, hi = np.searchsorted(self.times, [at - within - 1e-6, at + within + 1e-6])
        return [list(row) for row in self.values[lo:hi]]


def measured_samples(folder: Path, kind: str, fields: Sequence[str], scale: float = 1.0) -> Measured:
    """Every sample of ``kind`` in the tlogs of ``folder`` (the codec keeps them all), fields times ``scale``,
    each dated as the agent that logged it dated it (``tacit.sampletime``: one clock per agent run)."""
    times, rows = [], []
    for path in sorted(folder.glob("*.tlog")):
        clock = SampleClock()
        for msg in tlog.messages(path, kind):
            times.append(clock.date(boot_seconds(msg), msg._timestamp))
            rows.append([float(getattr(msg, f)) * scale for f in fields])
    order = np.argsort(np.array(times), kind="stable")
    return Measured(np.array(times)[order], np.array(rows).reshape(len(rows), len(fields))[order])


def error_ratios(
    values: Sequence[float | None], samples: Sequence[Sequence[float]], eps: Sequence[float]
) -> list[float]:
    """|reconstruction - measured| / eps per channel, against the one of ``samples`` (those taken within
    half a tick of the reconstruction's time: ``Measured.near``) that fits best; absent channels are
    skipped."""

    def ratios(sample: Sequence[float]) -> list[float]:
        return [abs(v - m) / e for v, m, e in zip(values, sample, eps, strict=True) if v is not None]

    return min((ratios(sample) for sample in samples), key=lambda r: max(r, default=0.0))
