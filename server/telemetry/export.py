"""One stream's samples as files a data user opens: CSV, Apache Parquet (typed columns) and NetCDF
following the CF and ACDD conventions (xarray, the IOOS tools, Panoply), each saying what its values mean
(``server.telemetry.metadata``). Each streams: the rows are read from the database a page at a time, and
a file whose header needs them all (Parquet's footer, NetCDF's counts and coverage) is written to a
spooled file first, so memory stays bounded whatever the window."""

from __future__ import annotations

import csv
import io
import math
import struct
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from typing import BinaryIO, cast

import numpy as np

from server.telemetry import metadata, netcdf3
from server.telemetry.metadata import Dataset
from server.telemetry.models import SampleTrust
from server.telemetry.service import Fix, Sample
from tacit.codec import StreamSpec
from tacit.navigation import Origin

PARQUET = "application/vnd.apache.parquet"
NETCDF = "application/x-netcdf"
ROW_GROUP = 5000  # rows per Parquet row group
SPOOL_BYTES = 8 << 20  # an export's file is kept in memory up to this size, then on disk until sent
CHUNK_BYTES = 1 << 20  # what is sent at a time
FLAGS = list(SampleTrust)  # a sample's NetCDF verification flag is its trust's index here
# NetCDF's attributes beside ``metadata.columns``': the flags of ``certain`` and ``verification``; the
# channels' fill value (``_variable_attributes`` adds each value's coordinates)
NETCDF_EXTRA: dict[str, dict[str, object]] = {
    "certain": {"flag_values": np.array([0, 1], "i1"), "flag_meanings": "uncertain certain"},
    "verification": {
        "flag_values": np.arange(len(FLAGS), dtype="i1"),
        "flag_meanings": " ".join(trust.value for trust in FLAGS),
    },
}
CHANNEL_EXTRA = {"_FillValue": np.float64(np.nan), "ancillary_variables": "certain verification"}

Row = tuple[float, int, int, bool, SampleTrust, list[float | None]]


def rows(spec: StreamSpec, samples: Iterator[Sample]) -> Iterator[Row]:
    """(time, tick, its place among the samples of its time, certain, trust, one value per channel: None
    where the sample is absent). A tick may hold several samples (``tacit.codec.grid``), all dated at its
    time: each is a row, numbered in the order the vehicle measured them (``samples`` come in time and
    then id order), so a second sample of a tick never reads as a copy of the first."""
    n = len(spec.channels)
    last, place = None, 0
    for sample, trust in samples:
        place = place + 1 if sample.time == last else 0
        last = sample.time
        values = list(sample.values or [])[:n]
        yield sample.time, sample.tick, place, sample.certain, trust, values + [None] * (n - len(values))


def csv_lines(d: Dataset, samples: Iterator[Sample]) -> Iterator[str]:
    """The header row names each column with its units (``metadata.csv_header``); an absent value is an
    empty cell."""
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(metadata.csv_header(d.spec))
    for n, (at, tick, place, certain, trust, values) in enumerate(rows(d.spec, samples)):
        writer.writerow([at, tick, place, int(certain), trust.value, *values])
        if n % 1000 == 999:
            yield out.getvalue()
            out.seek(0)
            out.truncate()
    yield out.getvalue()


def parquet(d: Dataset, samples: Iterator[Sample]) -> Iterator[bytes]:
    """Null where a value is absent; the attributes as field metadata, the file's as schema metadata.
    Written row group by row group to a spooled file (memory holds one group), then streamed."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    types = {
        "time": pa.float64(),
        "tick": pa.int64(),
        "in_tick": pa.int32(),
        "certain": pa.bool_(),
        "verification": pa.string(),
    }
    schema = pa.schema(
        [
            pa.field(name, types.get(name, pa.float64()), metadata=_strings(attrs))
            for name, attrs in metadata.columns(d.spec).items()
        ],  # fmt: skip
        metadata=_strings(metadata.attributes(d)),
    )
    with _spool() as sink:
        with pq.ParquetWriter(sink, schema, compression="zstd") as writer:
            for chunk in _chunks(rows(d.spec, samples), ROW_GROUP):
                columns = list(
                    zip(
                        *(
                            (at, tick, place, certain, trust.value, *values)
                            for at, tick, place, certain, trust, values in chunk
                        ),
                        strict=True,
                    )
                )
                arrays = [pa.array(c, f.type) for c, f in zip(columns, schema, strict=True)]
                writer.write_table(pa.Table.from_arrays(arrays, schema=schema))
        yield from _read_back(sink)


def _strings(attrs: metadata.Attributes) -> dict[str, str]:
    return {key: str(value) for key, value in attrs.items()}


def netcdf(d: Dataset, samples: Iterator[Sample], fixes: Iterator[Fix]) -> Iterator[bytes]:
    """A CF-1.8 single trajectory (the vehicle's name its id) with ACDD-1.3 discovery attributes, along
    the record dimension ``obs``, not ``time``: a forged sample may share a genuine one's time, and a CF
    coordinate variable must not repeat. NetCDF3 with 64-bit offsets (``netcdf3``): channels are doubles
    with NaN as ``_FillValue``, ``certain`` and ``verification`` byte flags (``flag_values`` /
    ``flag_meanings``), ``tick`` a double: it counts the stream's periods since 1970 (over 2^32 at 4 Hz),
    NetCDF3 has no 64-bit integer, and a double holds every integer up to 2^53 exactly. With the fleet's
    origin known, each row carries the vehicle's ``lat`` and ``lon`` (and ``depth`` where the stream has
    none) interpolated between its verified check-points (``fixes``, in the order heard). The rows go to a
    spooled file as they are read (memory holds a few), and the header, which counts them and says their
    coverage, is written before them when all are in."""
    origin = None if d.about.origin is None else Origin(*d.about.origin)
    columns = metadata.columns(d.spec)
    track = [] if origin is None else ["lat", "lon"]
    if origin is not None and "depth" not in columns:
        track.append("depth")
    names = [*columns, *track]
    kinds = {"in_tick": "i4", "certain": "i1", "verification": "i1"}
    record = struct.Struct(">" + "".join(netcdf3.PACKED[kinds.get(n, "f8")] for n in names))
    coverage = Coverage(names)
    place = Track(fixes)
    with _spool() as sink:
        count = 0
        for at, tick, order, certain, trust, values in rows(d.spec, samples):
            where = place.at(at)
            n, e, z = where if where is not None else (math.nan,) * 3
            lat, lon = origin.to_global(n, e) if origin is not None and where is not None else (math.nan,) * 2
            row = [at, float(tick), order, int(certain), FLAGS.index(trust), *(_nan(v) for v in values)]
            row += [lat, lon, z][: len(track)]
            coverage.add(row)
            sink.write(record.pack(*row))
            count += 1
        variables = [
            netcdf3.Variable(
                name,
                kinds.get(name, "f8"),
                _variable_attributes(name, columns, track),
            )
            for name in names
        ]
        header = netcdf3.header(
            count,
            d.vehicle.encode(),
            {"cf_role": "trajectory_id", "long_name": "vehicle name", "_Encoding": "utf-8"},
            {"Conventions": "CF-1.8, ACDD-1.3", "featureType": "trajectory", **metadata.attributes(d),
             **coverage.attributes(d, origin is not None)},
            variables,
        )  # fmt: skip
        yield header
        yield from _read_back(sink)


def _variable_attributes(
    name: str, columns: dict[str, metadata.Attributes], track: list[str]
) -> dict[str, object]:
    """A variable's attributes: a value's coordinates are the time, the tick and its place in it (which
    tell its samples apart), and where the vehicle was."""
    if name in track:
        return {**metadata.TRACK[name], "coverage_content_type": "coordinate", "_FillValue": math.nan,
                "comment": metadata.TRACK_COMMENT}  # fmt: skip
    if name in ("time", "tick", "in_tick"):
        return dict(columns[name])
    depth = ["depth"] if "depth" in columns and name != "depth" else []
    where = " ".join(["time", "tick", "in_tick", *track, *depth])
    return {**columns[name], "coordinates": where, **NETCDF_EXTRA.get(name, CHANNEL_EXTRA)}


def _nan(value: float | None) -> float:
    return math.nan if value is None else value


class Track:
    """The vehicle's position at each row's time, interpolated between its verified check-points (read in
    the order heard, which is their order in time but for a late one, dropped); None outside them."""

    def __init__(self, fixes: Iterator[Fix]) -> None:
        self.fixes = fixes
        self.before: Fix | None = None
        self.after: Fix | None = next(fixes, None)

    def at(self, t: float) -> tuple[float, float, float] | None:
        while self.after is not None and self.after[0] < t:
            if self.before is None or self.after[0] > self.before[0]:
                self.before = self.after
            self.after = next(self.fixes, None)
        a, b = self.before, self.after
        if b is not None and b[0] == t:
            return b[1], b[2], b[3]
        if a is None or b is None or b[0] <= a[0]:
            return None
        k = (t - a[0]) / (b[0] - a[0])
        return a[1] + k * (b[1] - a[1]), a[2] + k * (b[2] - a[2]), a[3] + k * (b[3] - a[3])


class Coverage:
    """The rows' extent in time and space, kept as they are written (the header's ACDD coverage)."""

    def __init__(self, names: list[str]) -> None:
        self.index = {name: k for k, name in enumerate(names)}
        self.low: dict[str, float] = {}
        self.high: dict[str, float] = {}

    def add(self, row: list[float]) -> None:
        for name in ("time", "lat", "lon", "depth"):
            k = self.index.get(name)
            if k is not None and not math.isnan(row[k]):
                self.low[name] = min(self.low.get(name, math.inf), row[k])
                self.high[name] = max(self.high.get(name, -math.inf), row[k])

    def attributes(self, d: Dataset, placed: bool) -> metadata.Attributes:
        out: metadata.Attributes = {
            "time_coverage_resolution": _duration(d.spec.period),
            "geospatial_vertical_positive": "down",
            "geospatial_vertical_units": "m",
        }
        if "time" in self.low:
            start, end = self.low["time"], self.high["time"]
            out |= {
                "time_coverage_start": _iso(start),
                "time_coverage_end": _iso(end),
                "time_coverage_duration": _duration(end - start),
                "id": f"{d.about.deployment}-{d.vehicle}-{d.spec.name}-{int(start)}",
            }
        if "depth" in self.low:
            out |= {
                "geospatial_vertical_min": self.low["depth"],
                "geospatial_vertical_max": self.high["depth"],
            }
        if placed and "lat" in self.low:
            south, north, west, east = self.low["lat"], self.high["lat"], self.low["lon"], self.high["lon"]
            corners = [(west, south), (east, south), (east, north), (west, north), (west, south)]
            out |= {
                "geospatial_lat_min": south,
                "geospatial_lat_max": north,
                "geospatial_lon_min": west,
                "geospatial_lon_max": east,
                "geospatial_lat_units": "degrees_north",
                "geospatial_lon_units": "degrees_east",
                "geospatial_bounds": "POLYGON ((" + ", ".join(f"{x:.7f} {y:.7f}" for x, y in corners) + "))",
                "geospatial_bounds_crs": "EPSG:4326",
                "geospatial_bounds_vertical_crs": "EPSG:5831",  # depth below mean sea level
            }
        return out


def _iso(at: float) -> str:
    return datetime.fromtimestamp(at, UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _duration(seconds: float) -> str:
    """An ISO 8601 duration: ``PT0.25S``, ``PT3600S``."""
    return f"PT{seconds:g}S"


@contextmanager
def _spool() -> Iterator[BinaryIO]:
    with tempfile.SpooledTemporaryFile(SPOOL_BYTES, prefix="tacit-export-") as sink:
        yield cast(BinaryIO, sink)


def _read_back(sink: BinaryIO) -> Iterator[bytes]:
    sink.seek(0)
    while chunk := sink.read(CHUNK_BYTES):
        yield chunk


def _chunks(items: Iterator[Row], size: int) -> Iterator[list[Row]]:
    chunk: list[Row] = []
    for item in items:
        chunk.append(item)
        if len(chunk) == size:
            yield chunk
            chunk = []
    if chunk:
        yield chunk
