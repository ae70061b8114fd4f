"""The chain of states both ends hold, and how the shore saves it across restarts.

Each packet continues from the state a packet before it left (``tacit.codec.format``): per stream, the
predictor's snapshot, the adaptive models and where the stream stood (cursor, grid phase). The shore
persists the states packets may continue from with ``PacketDecoder.to_bytes()`` / ``load()`` /
``from_bytes()``: zlib-compressed JSON (``save`` / ``restore`` here), floats round-tripping exactly.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tacit.codec.format import FORMAT, SEQS, CodecError
from tacit.codec.grid import PHASES
from tacit.codec.models import Coder
from tacit.codec.prediction import Dual
from tacit.codec.spec import StreamSpec
from tacit.codec.versions import Coding


@dataclass
class Position:
    """One stream's state after a packet: predictor snapshot, models, cursor (last coded tick)."""

    predictor: object
    coder: Coder
    cursor: int | None
    phase: int = 0  # the grid phase START set (sixteenths of a tick)


@dataclass
class Chain:
    id: int  # 0: the initial state; else the packet that ended here (version 3: 1..63; 4: 1 + its seq)
    streams: list[Position]

    @classmethod
    def initial(cls, specs: Sequence[StreamSpec], predictors: Sequence[Dual], coding: Coding) -> Chain:
        """The state before a vehicle run's first packet (``predictors`` freshly made)."""
        streams = zip(predictors, specs, strict=True)
        return cls(0, [Position(p.state(), Coder.new(len(s.channels), coding), None) for p, s in streams])


def save(specs: Sequence[StreamSpec], chains: Sequence[Chain]) -> bytes:
    """``chains`` of a decoder of ``specs``, for ``restore``."""
    doc = {
        "format": FORMAT,
        "specs": _fingerprint(specs),
        "chains": [
            [c.id, [[_dump(p.predictor), p.coder.dump(), p.cursor, p.phase] for p in c.streams]]
            for c in chains
        ],
    }
    return zlib.compress(json.dumps(doc, separators=(",", ":")).encode(), 6)


def restore(specs: Sequence[StreamSpec], data: bytes, coding: Coding) -> dict[int, Chain]:
    """The chains ``save`` saved, by id; ``CodecError`` if ``data`` is not such a state or was saved for
    other streams or another payload version's coding."""
    try:
        doc = json.loads(zlib.decompress(data))
        if doc["format"] != FORMAT or doc["specs"] != _fingerprint(specs):
            raise CodecError("saved decoder state is for another format or other streams")
        chains = {}
        for chain_id, streams in doc["chains"]:
            if not (isinstance(chain_id, int) and 1 <= chain_id <= SEQS and len(streams) == len(specs)):
                raise CodecError("saved decoder state is malformed")
            positions = [Position(_load(p), Coder.load(c), _cursor(k), _phase(f)) for p, c, k, f in streams]
            if any((p.coder.timing is None) == coding.timing for p in positions):
                raise CodecError("saved decoder state is for another payload version")
            chains[chain_id] = Chain(chain_id, positions)
    except CodecError:
        raise
    except (ValueError, KeyError, IndexError, TypeError, OverflowError, RecursionError, zlib.error) as exc:
        raise CodecError(f"saved decoder state is malformed ({exc})") from None
    return chains


def _fingerprint(specs: Sequence[StreamSpec]) -> list:
    return [
        [
            s.name,
            int(s.stream),
            list(s.channels),
            list(s.eps),
            s.period,
            s.method,
            None if s.initial is None else list(s.initial),
            s.cross,
            *([] if s.depth is None else [s.depth]),
        ]
        for s in specs
    ]


def _cursor(value: object) -> int | None:
    if value is None or (isinstance(value, int) and not isinstance(value, bool)):
        return value
    raise ValueError(f"cursor {value!r}")


def _phase(value: object) -> int:
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < PHASES:
        return value
    raise ValueError(f"phase {value!r}")


def _dump(state: object) -> object:
    """A predictor snapshot (tuples, lists, arrays, numbers) as JSON-able data."""
    if isinstance(state, np.ndarray):
        return {"a": state.tolist(), "d": str(state.dtype)}
    if isinstance(state, tuple):
        return {"t": [_dump(x) for x in state]}
    if isinstance(state, list):
        return [_dump(x) for x in state]
    if isinstance(state, np.generic):
        return state.item()
    return state


def _load(data: object) -> object:
    if isinstance(data, dict):
        if "a" in data:
            return np.array(data["a"], dtype=np.dtype(data["d"]))
        return tuple(_load(x) for x in data["t"])
    if isinstance(data, list):
        return [_load(x) for x in data]
    return data
