"""One stream's samples as files a data user opens: CSV (streamed), Apache Parquet (typed columns) and
NetCDF following the CF conventions (xarray, the IOOS tools, Panoply), each saying what its values mean
(``server.telemetry.metadata``)."""

from __future__ import annotations

import csv
import io
from collections.abc import Iterator, Mapping

import numpy as np

from server.telemetry import metadata
from server.telemetry.metadata import Dataset
from server.telemetry.models import SampleTrust
from server.telemetry.service import Sample
from tacit.codec import StreamSpec

PARQUET = "application/vnd.apache.parquet"
NETCDF = "application/x-netcdf"
ROW_GROUP = 5000  # rows per Parquet row group
FLAGS = list(SampleTrust)  # a sample's NetCDF verification flag is its trust's index here
# NetCDF's attributes beside ``metadata.columns``' (each variable but ``time`` also names it as its
# coordinate): the flags of ``certain`` and ``verification``; the channels' fill value
NETCDF_EXTRA: dict[str, dict[str, object]] = {
    "tick": {},
    "in_tick": {},
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


def parquet(d: Dataset, samples: Iterator[Sample]) -> bytes:
    """Null where a value is absent; the attributes as field metadata, the file's as schema metadata."""
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
    sink = io.BytesIO()
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
    return sink.getvalue()


def _strings(attrs: metadata.Attributes) -> dict[str, str]:
    return {key: str(value) for key, value in attrs.items()}


def netcdf(d: Dataset, samples: Iterator[Sample]) -> bytes:
    """A CF-1.8 single trajectory (the vehicle's name its id) along dimension ``obs``, not ``time``: a
    forged sample may share a genuine one's time, and a CF coordinate variable must not repeat. NetCDF3
    (scipy's writer, no extra library): channels are doubles with NaN as ``_FillValue``, ``certain`` and
    ``verification`` byte flags (``flag_values``/``flag_meanings``), ``tick`` a double: it counts the
    stream's periods since 1970 (over 2^32 at 4 Hz), NetCDF3 has no 64-bit integer, and a double holds
    every integer up to 2^53 exactly."""
    from scipy.io import netcdf_file

    table = list(rows(d.spec, samples))
    sink = io.BytesIO()
    f = netcdf_file(sink, "w", version=2)  # 64-bit offsets: files over 2 GiB
    f.createDimension("obs", len(table))
    f.createDimension("name_strlen", len(d.vehicle.encode()))
    trajectory = f.createVariable("trajectory", "c", ("name_strlen",))
    trajectory[:] = np.frombuffer(d.vehicle.encode(), "S1")
    _attributes(trajectory, {"cf_role": "trajectory_id", "long_name": "vehicle name", "_Encoding": "utf-8"})
    arrays = _arrays(d.spec, table)
    for name, attrs in metadata.columns(d.spec).items():
        variable = f.createVariable(name, arrays[name].dtype, ("obs",))
        variable[:] = arrays[name]
        extra = {} if name == "time" else {"coordinates": "time", **NETCDF_EXTRA.get(name, CHANNEL_EXTRA)}
        _attributes(variable, {**attrs, **extra})
    _attributes(f, {"Conventions": "CF-1.8", "featureType": "trajectory", **metadata.attributes(d)})
    f.flush()
    return sink.getvalue()


def _attributes(target: object, attrs: Mapping[str, object]) -> None:
    """Set NetCDF attributes; a float as a double (scipy would write a Python float as a 32-bit float:
    0.05 would read back as 0.0500000007, and a double's ``_FillValue`` must be a double)."""
    for key, value in attrs.items():
        setattr(target, key, np.float64(value) if isinstance(value, float) else value)


def _arrays(spec: StreamSpec, table: list[Row]) -> dict[str, np.ndarray]:
    """The columns as NetCDF3 types (NaN where a value is absent)."""
    values = np.array([[np.nan if v is None else v for v in r[5]] for r in table], "f8")
    values = values.reshape(len(table), len(spec.channels))
    return {
        "time": np.array([r[0] for r in table], "f8"),
        "tick": np.array([r[1] for r in table], "f8"),
        "in_tick": np.array([r[2] for r in table], "i4"),
        "certain": np.array([r[3] for r in table], "i1"),
        "verification": np.array([FLAGS.index(r[4]) for r in table], "i1"),
        **{channel: values[:, i] for i, channel in enumerate(spec.channels)},
    }


def _chunks(items: Iterator[Row], size: int) -> Iterator[list[Row]]:
    chunk: list[Row] = []
    for item in items:
        chunk.append(item)
        if len(chunk) == size:
            yield chunk
            chunk = []
    if chunk:
        yield chunk
