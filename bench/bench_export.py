"""Peak memory of the telemetry exports: a month of one stream at 4 Hz (the IMU's nine channels, the
fastest stream), exported as CSV, Parquet and NetCDF, each by a fresh process whose peak resident set
(``ru_maxrss``) is what the export cost; the same for one day, as a baseline. Each export is counted back
from its file (CSV lines, Parquet's row count, NetCDF's record count), so a peak is only reported for an
export that held every sample: the check is that the month's peak is within ``--slack`` MB of the day's.

    cd bench && ../.venv/bin/python bench_export.py [--days 30] [--baseline-days 1] [--formats nc ...]

The database is a SQLite file built here (a few minutes for a month: 10.4 million rows, about 1.5 GB);
the files go to ``--dir`` too and are deleted once counted.
"""

from __future__ import annotations

import argparse
import json
import resource
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tqdm import tqdm

from server.core.db import make_engine, migrate
from server.telemetry import export
from server.telemetry.metadata import About
from server.telemetry.service import TelemetryReader, Window
from server.vehicles.schemas import VehicleIn
from server.vehicles.service import Vehicles
from tacit.streams import IMU_PERIOD, default_streams

T0 = 1_780_000_000.0  # the month's first sample (UNIX s)
DAY = 86_400.0
BATCH = 100_000  # rows per insert
FORMATS = ("csv", "parquet", "nc")


def build(db: Path, days: float) -> int:
    """A migrated database holding one vehicle and ``days`` of its IMU stream at 4 Hz; the row count."""
    migrate(f"sqlite:///{db}")
    Vehicles(make_engine(f"sqlite:///{db}")).create(VehicleIn(name="rov1", address=2))
    rows = int(days * DAY / IMU_PERIOD)
    values = json.dumps([12.5, -3.25, 1000.0, 0.5, -0.25, 1.0, 220.0, -35.0, 410.0])
    with sqlite3.connect(db) as c:
        first = int(T0 / IMU_PERIOD)
        with tqdm(total=rows, unit="row", desc="samples", disable=None) as bar:
            for start in range(0, rows, BATCH):
                batch = [
                    (1, "imu", first + k, (first + k) * IMU_PERIOD, values, 1, None, 1)
                    for k in range(start, min(rows, start + BATCH))
                ]
                c.executemany(
                    'INSERT INTO telemetry (vehicle_id, stream, tick, time, "values", certain, packet_id, '
                    "verified) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                    batch,
                )
                bar.update(len(batch))
    return rows


def counted(path: Path, fmt: str) -> int:
    """The rows in an export file, read back from it."""
    if fmt == "csv":
        with path.open("rb") as f:
            return sum(1 for _ in f) - 1  # the header row
    if fmt == "parquet":
        import pyarrow.parquet as pq

        return int(pq.ParquetFile(path).metadata.num_rows)
    with path.open("rb") as f:
        head = f.read(8)
    assert head[:4] == b"CDF\x02", head
    return int.from_bytes(head[4:8], "big")  # numrecs


def child(db: Path, fmt: str, until: float, out: Path) -> None:
    """One export in this process, written to ``out``; prints its peak resident set (MB) and time."""
    reader = TelemetryReader(make_engine(f"sqlite:///{db}"), default_streams(), About())
    started = time.perf_counter()
    exported = reader.export(1, "imu", Window(None, until))
    d = exported.dataset
    chunks = {
        "csv": lambda: (line.encode() for line in export.csv_lines(d, exported.samples)),
        "parquet": lambda: export.parquet(d, exported.samples),
        "nc": lambda: export.netcdf(d, exported.samples, exported.fixes),
    }[fmt]()
    with out.open("wb") as f:
        for chunk in chunks:
            f.write(chunk)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"peak_mb": round(peak, 1), "seconds": round(time.perf_counter() - started, 1)}))


def measure(db: Path, fmt: str, until: float, out: Path) -> dict:
    done = subprocess.run(
        [sys.executable, __file__, "--child", fmt, str(db), str(until), str(out)],
        capture_output=True,
        text=True,
        check=True,
    )
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result["rows"] = counted(out, fmt)
    result["file_mb"] = round(out.stat().st_size / 1e6, 1)
    out.unlink()
    return dict(result)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--days", type=float, default=30.0, help="the long window (days of 4 Hz samples)")
    parser.add_argument("--baseline-days", type=float, default=1.0, help="the short window")
    parser.add_argument("--slack", type=float, default=64.0, help="MB the long window's peak may exceed")
    parser.add_argument("--dir", type=Path, default=None, help="where the database and files go")
    parser.add_argument("--formats", nargs="+", choices=FORMATS, default=list(FORMATS), help="the exports")
    parser.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        fmt, db, until, out = args.child
        child(Path(db), fmt, float(until), Path(out))
        return 0
    with tempfile.TemporaryDirectory(dir=args.dir, prefix="bench-export-") as scratch:
        db = Path(scratch) / "month.db"
        total = build(db, args.days)
        short = int(args.baseline_days * DAY / IMU_PERIOD)
        ok = True
        print(
            f"{total} samples ({args.days:g} days at 4 Hz, 9 channels); baseline {short} ({args.baseline_days:g} d)"
        )
        print(f"{'format':8} {'window':>7} {'rows':>10} {'file MB':>8} {'peak MB':>8} {'s':>7}")
        for fmt in args.formats:
            results = {}
            for label, rows, until in (
                ("day", short, T0 + short * IMU_PERIOD - IMU_PERIOD / 2),
                ("month", total, T0 + DAY * args.days),
            ):
                r = measure(db, fmt, until, Path(scratch) / f"export.{fmt}")
                print(
                    f"{fmt:8} {label:>7} {r['rows']:>10} {r['file_mb']:>8} {r['peak_mb']:>8} {r['seconds']:>7}"
                )
                if r["rows"] != rows:
                    print(f"  {fmt} {label}: {r['rows']} rows exported, {rows} stored: not what was measured")
                    ok = False
                results[label] = r
            growth = results["month"]["peak_mb"] - results["day"]["peak_mb"]
            if growth > args.slack:
                print(
                    f"  {fmt}: the month's peak is {growth:.0f} MB above the day's: memory grows with the window"
                )
                ok = False
        print("PASS" if ok else "FAIL")
        return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
