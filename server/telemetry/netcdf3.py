"""The header of a NetCDF-3 file (the classic format with 64-bit offsets, "CDF-2": Unidata's "NetCDF
Classic and 64-bit Offset Format" specification), for a writer that streams its records after it.

The layout the exports need: two dimensions, the record dimension ``obs`` and ``name_strlen``; one
character variable on ``name_strlen`` (the trajectory's name), written right after the header; record
variables on ``obs`` of doubles (``f8``), 32-bit integers (``i4``) and bytes (``i1``). A record holds one
value of each record variable in turn, each padded to 4 bytes (``PACKED``), big-endian.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

MAGIC = b"CDF\x02"  # classic format, 64-bit offsets
NC_BYTE, NC_CHAR, NC_INT, NC_DOUBLE = 1, 2, 4, 6
NC_DIMENSION, NC_VARIABLE, NC_ATTRIBUTE = 10, 11, 12
ABSENT = bytes(8)
TYPES = {"i1": NC_BYTE, "i4": NC_INT, "f8": NC_DOUBLE}
PACKED = {"f8": "d", "i4": "i", "i1": "b3x"}  # one value in a record (``struct``), padded to 4 bytes
RECORD_BYTES = {"f8": 8, "i4": 4, "i1": 4}


@dataclass(frozen=True)
class Variable:
    """A record variable: its name, kind (``f8``, ``i4``, ``i1``) and attributes."""

    name: str
    kind: str
    attrs: dict[str, Any]


def _padded(data: bytes) -> bytes:
    return data + bytes(-len(data) % 4)


def _name(name: str) -> bytes:
    raw = name.encode()
    return struct.pack(">i", len(raw)) + _padded(raw)


def _values(value: Any) -> tuple[int, int, bytes]:
    """An attribute's NetCDF type, count and bytes: text as characters, an int as a 32-bit integer, a
    float as a double, an array as its type."""
    if isinstance(value, str):
        raw = value.encode()
        return NC_CHAR, len(raw), raw
    if isinstance(value, np.ndarray):
        kind = value.dtype.str[1:]
        return TYPES[kind], len(value), value.astype(">" + kind).tobytes()
    if isinstance(value, int | np.integer):
        return NC_INT, 1, struct.pack(">i", int(value))
    return NC_DOUBLE, 1, struct.pack(">d", float(value))


def _attributes(attrs: dict[str, Any]) -> bytes:
    if not attrs:
        return ABSENT
    out = [struct.pack(">ii", NC_ATTRIBUTE, len(attrs))]
    for name, value in attrs.items():
        kind, count, raw = _values(value)
        out.append(_name(name) + struct.pack(">ii", kind, count) + _padded(raw))
    return b"".join(out)


def _variable(name: str, dims: list[int], attrs: dict[str, Any], kind: int, size: int, begin: int) -> bytes:
    head = _name(name) + struct.pack(">i", len(dims)) + b"".join(struct.pack(">i", d) for d in dims)
    return head + _attributes(attrs) + struct.pack(">iiq", kind, size, begin)


def header(
    records: int,
    trajectory: bytes,
    trajectory_attrs: dict[str, Any],
    attrs: dict[str, Any],
    variables: list[Variable],
) -> bytes:
    """The file up to its first record: the header for ``records`` records of ``variables``, and the
    trajectory's name (``trajectory``, with ``trajectory_attrs``) after it."""

    def build(start: int) -> bytes:
        dims = struct.pack(">ii", NC_DIMENSION, 2) + _name("obs") + struct.pack(">i", 0)
        dims += _name("name_strlen") + struct.pack(">i", len(trajectory))
        first = start + len(_padded(trajectory))
        parts = [_variable("trajectory", [1], trajectory_attrs, NC_CHAR, len(_padded(trajectory)), start)]
        for v in variables:
            parts.append(_variable(v.name, [0], v.attrs, TYPES[v.kind], RECORD_BYTES[v.kind], first))
            first += RECORD_BYTES[v.kind]
        listed = struct.pack(">ii", NC_VARIABLE, len(parts)) + b"".join(parts)
        return MAGIC + struct.pack(">i", records) + dims + _attributes(attrs) + listed

    size = len(build(0))  # the offsets are fixed-size fields: the header's length does not depend on them
    return build(size) + _padded(trajectory)
