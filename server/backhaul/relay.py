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
from dataclasses import dataclass

from sqlalchemy import Engine

from server.backhaul import repository
from server.backhaul.models import RelayedFrame
from server.backhaul.subjects import FrameMessage
from server.core.config import Settings
from server.core.db import Tx, reading, writing
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
    gateway: str = ""

    @classmethod
    def of(cls, m: FrameMessage) -> RelayedIncoming:
        return cls(
            m.src, m.dest, m.data, m.rate, m.snr_in, m.snr_out, m.stats, m.at, id=m.id, gateway=m.gateway
        )


class RelayIngest(Ingest):
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
            repository.add(s, self._row(frame, hashlib.sha256(frame.data).hexdigest(), frame_id, kept=True))
            s.commit()
        self.stats["undecoded"] += 1
        return True

    def heard_by(self, frame_id: int) -> int:
        with reading(self.db) as s:
            return repository.heard_by(s, frame_id)

    def _frame(self, s: Tx, batch: Batch, frame: IncomingFrame) -> list[Event]:
        if not isinstance(frame, RelayedIncoming):
            return super()._frame(s, batch, frame)
        if repository.get(s, frame.id) is not None:
            self.stats["relayed_duplicates"] += 1
            return []
        digest = hashlib.sha256(frame.data).hexdigest()
        twin = repository.twin(s, frame.src, digest, frame.at, self.window)
        if twin is not None and twin.frame_id is not None:
            return self._copy(s, frame, twin.frame_id, digest, better=_snr(frame.snr_in) > _snr(twin.snr_in))
        events = super()._frame(s, batch, frame)  # stores the frame: ``_stored`` records it
        if repository.get(s, frame.id) is None:  # refused before storing: its id is still taken
            repository.add(s, self._row(frame, digest, None, kept=False))
        return events

    def _stored(self, s: Tx, frame: IncomingFrame, frame_id: int) -> None:
        if isinstance(frame, RelayedIncoming):
            repository.add(s, self._row(frame, hashlib.sha256(frame.data).hexdigest(), frame_id, kept=True))

    def _copy(self, s: Tx, frame: RelayedIncoming, frame_id: int, digest: str, better: bool) -> list[Event]:
        """Another gateway's copy of a stored frame: counted, and kept if its SNR is the best."""
        self.stats["diversity_copies"] += 1
        repository.add(s, self._row(frame, digest, frame_id, kept=False))
        if better:
            repository.keep(
                s,
                frame_id,
                frame.id,
                {"snr_in": frame.snr_in, "snr_out": frame.snr_out, "stats": frame.stats, "rate": frame.rate},
            )
        detail = {
            "address": frame.src,
            "gateway": frame.gateway,
            "snr_in": frame.snr_in,
            "heard_by": repository.heard_by(s, frame_id),
            "kept": better,
        }
        return [LinkNotice(event="heard_again", detail=detail)]

    @staticmethod
    def _row(frame: RelayedIncoming, digest: str, frame_id: int | None, kept: bool) -> RelayedFrame:
        return RelayedFrame(
            id=frame.id,
            frame_id=frame_id,
            gateway=frame.gateway,
            src=frame.src,
            digest=digest,
            snr_in=frame.snr_in,
            at=frame.at,
            kept=kept,
        )


def _snr(value: float | None) -> float:
    return value if value is not None and math.isfinite(value) else -math.inf
