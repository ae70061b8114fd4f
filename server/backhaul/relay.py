"""The center's ingest of frames that came over the backhaul: the shore's pipeline (``server.link.ingest``)
with the store's own de-duplication in front, in the batch's transaction.

* A message id stored already is dropped (a redelivery after the center died before acking, a gateway's
  retry after JetStream's ``duplicate_window``): no broker window bounds this one.
* Spatial diversity: the same frame (same source, same bytes) heard by another gateway within
  ``window`` s is not stored or decoded again; its copy is counted (``relayedframe`` rows pointing at one
  frame: ``heard_by``) and, if its SNR is better, its receive statistics become the frame row's.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field, fields
from typing import Any

from sqlalchemy import Engine

from server.backhaul import repository
from server.backhaul.subjects import FrameMessage
from server.core.config import Settings
from server.core.db import Tx, now, reading, writing
from server.core.events import Bus, Event, LinkNotice
from server.link.batch import Batch
from server.link.ingest import Ingest, frame_row
from server.link.state import IncomingFrame
from server.telemetry import repository as telemetry
from tacit.codec import StreamSpec
from tacit.packets import Stream

DIVERSITY_WINDOW = 5.0  # s between two gateways' copies of one frame (their clocks, NTP/GPS-disciplined)


@dataclass(frozen=True)
class RelayedIncoming(IncomingFrame):
    """A received frame with the backhaul message it came in."""

    id: str = ""

    @classmethod
    def of(cls, m: FrameMessage) -> RelayedIncoming:
        return cls(
            m.src, m.dest, m.data, m.rate, m.snr_in, m.snr_out, m.stats, m.at, id=m.id, gateway=m.gateway
        )


class RelayIngest(Ingest):
    relayed = True

    def __init__(
        self,
        db: Engine,
        bus: Bus,
        streams: dict[Stream, StreamSpec],
        settings: Settings,
        window: float = DIVERSITY_WINDOW,
    ) -> None:
        super().__init__(db, bus, streams, settings)
        self.window = window
        self.stats.update({"relayed_duplicates": 0, "diversity_copies": 0, "undecoded": 0})

    def keep_undecoded(self, frame: RelayedIncoming) -> bool:
        """A frame the pipeline failed on (``handle_batch`` raised for it alone): its bytes and its relay
        record stored without decoding, in a transaction of its own, so that it is not lost and its id
        not taken again; False if its id was stored already."""
        with writing(self.db) as s:
            if repository.get(s, frame.id) is not None:
                return False
            frame_id = telemetry.add_frame(s, frame_row(frame))
            repository.add_rows(s, [self._row(frame, hashlib.sha256(frame.data).hexdigest(), frame_id, True)])
            s.commit()
        self.stats["undecoded"] += 1
        return True

    def heard_by(self, frame_id: int) -> int:
        with reading(self.db) as s:
            return repository.heard_by(s, frame_id)

    def _open(self, s: Tx, frames: list[IncomingFrame]) -> Batch:
        """The pipeline's batch, with the message ids stored already and the kept copies of its frames'
        bytes (two queries, whatever its length)."""
        relayed = [f for f in frames if isinstance(f, RelayedIncoming)]
        batch = RelayBatch.of(super()._open(s, frames))
        batch.taken = repository.stored_ids(s, [f.id for f in relayed])
        batch.relayed = repository.kept_copies(
            s, [(f.src, hashlib.sha256(f.data).hexdigest()) for f in relayed]
        )
        return batch

    def _frame(self, s: Tx, batch: Batch, frame: IncomingFrame) -> list[Event]:
        if not isinstance(frame, RelayedIncoming) or not isinstance(batch, RelayBatch):
            return super()._frame(s, batch, frame)
        if frame.id in batch.taken:
            self.stats["relayed_duplicates"] += 1
            return []
        digest = hashlib.sha256(frame.data).hexdigest()
        twin = batch.twin(s, frame.src, digest, frame.at, self.window)
        if twin is not None:
            return self._copy(s, batch, frame, twin, digest)
        events = super()._frame(s, batch, frame)  # stores the frame: ``_stored`` records it
        if frame.id not in batch.taken:  # refused before storing: its id is still taken
            batch.record(self._row(frame, digest, None, kept=False))
        elif batch.mine and batch.mine[-1]["id"] == frame.id:  # stored and decoded: did it verify?
            batch.mine[-1]["verified"] = batch.mine[-1]["frame_id"] in batch.verified
        return events

    def _stored(self, s: Tx, batch: Batch, frame: IncomingFrame, frame_id: int) -> None:
        if isinstance(frame, RelayedIncoming) and isinstance(batch, RelayBatch):
            batch.record(self._row(frame, hashlib.sha256(frame.data).hexdigest(), frame_id, kept=True))

    def _copy(self, s: Tx, batch: RelayBatch, frame: RelayedIncoming, twin: Twin, digest: str) -> list[Event]:
        """Another gateway's copy of a stored frame: counted, and kept if its SNR is the best; it verified
        if the frame did."""
        self.stats["diversity_copies"] += 1
        frame_id, better = twin.frame_id, _snr(frame.snr_in) > _snr(twin.snr_in)
        if better:
            batch.keep(s, frame_id, {"snr_in": frame.snr_in, "snr_out": frame.snr_out, "stats": frame.stats,
                                     "rate": frame.rate})  # fmt: skip
        batch.record(self._row(frame, digest, frame_id, kept=better, verified=twin.verified))
        detail = {
            "address": frame.src,
            "frame_id": frame_id,
            "gateway": frame.gateway,
            "snr_in": frame.snr_in,
            "heard_by": batch.heard_by(s, frame_id),
            "kept": better,
        }
        return [LinkNotice(event="heard_again", detail=detail)]

    @staticmethod
    def _row(
        frame: RelayedIncoming, digest: str, frame_id: int | None, kept: bool, verified: bool = False
    ) -> dict[str, Any]:
        return {
            "id": frame.id,
            "frame_id": frame_id,
            "gateway": frame.gateway,
            "src": frame.src,
            "digest": digest,
            "snr_in": frame.snr_in,
            "at": frame.at,
            "received_at": now(),
            "kept": kept,
            "verified": verified,
        }


@dataclass(frozen=True)
class Twin:
    """The stored copy of a frame another gateway heard too: its frame row, SNR, and whether it verified."""

    frame_id: int
    snr_in: float | None
    verified: bool


@dataclass
class RelayBatch(Batch):
    """A batch with the relayed frames' records: the message ids stored before it or taken in it, and the
    records it adds, inserted after its frames."""

    taken: set[str] = field(default_factory=set)
    relayed: list[dict[str, Any]] = field(default_factory=list)  # stored kept copies, then those added
    added: int = 0  # how many of ``relayed`` are this batch's (the last ones)

    @classmethod
    def of(cls, batch: Batch) -> RelayBatch:
        return cls(**{f.name: getattr(batch, f.name) for f in fields(Batch)})

    def record(self, row: dict[str, Any]) -> None:
        self.taken.add(row["id"])
        self.relayed.append(row)
        self.added += 1

    @property
    def mine(self) -> list[dict[str, Any]]:
        return self.relayed[len(self.relayed) - self.added :]

    def twin(self, s: Tx, src: int, digest: str, at: float, window: float) -> Twin | None:
        """The kept copy of the same frame heard within ``window`` s of ``at``."""
        copies = [
            r for r in self.relayed
            if r["kept"] and r["frame_id"] is not None and r["src"] == src and r["digest"] == digest
            and abs(r["at"] - at) <= window
        ]  # fmt: skip
        best = max(copies, key=lambda r: r["at"], default=None)
        return None if best is None else Twin(best["frame_id"], best["snr_in"], bool(best.get("verified")))

    def keep(self, s: Tx, frame_id: int, stats: dict[str, Any]) -> None:
        """The copy recorded next is the frame's best: its receive statistics become the frame row's."""
        for row in self.relayed:
            if row["frame_id"] == frame_id:
                row["kept"] = False
        for row in self.frames:
            if row["id"] == frame_id:
                row.update(stats)
        repository.keep(s, frame_id, stats)

    def heard_by(self, s: Tx, frame_id: int) -> int:
        return repository.heard_by(s, frame_id) + sum(r["frame_id"] == frame_id for r in self.mine)

    def flush(self, s: Tx) -> None:
        super().flush(s)
        repository.add_rows(s, self.mine)


def _snr(value: float | None) -> float:
    return value if value is not None and math.isfinite(value) else -math.inf
