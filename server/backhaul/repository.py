"""The backhaul's SQL: the relayed frames' ids, the copies of one frame, the best copy's statistics."""

from __future__ import annotations

from typing import Any

from sqlalchemy import func, update
from sqlmodel import Session, col, select

from server.backhaul.models import RelayedFrame
from server.telemetry.models import Frame


def get(s: Session, message_id: str) -> RelayedFrame | None:
    return s.get(RelayedFrame, message_id)


def add(s: Session, row: RelayedFrame) -> None:
    s.add(row)
    s.flush()


def twin(s: Session, src: int, digest: str, at: float, window: float) -> RelayedFrame | None:
    """The kept copy of the same frame (same source, same bytes) heard within ``window`` s of ``at``."""
    query = (
        select(RelayedFrame)
        .where(RelayedFrame.src == src, RelayedFrame.digest == digest, col(RelayedFrame.kept).is_(True),
               col(RelayedFrame.frame_id).is_not(None), col(RelayedFrame.at) >= at - window,
               col(RelayedFrame.at) <= at + window)
        .order_by(col(RelayedFrame.at).desc())
        .limit(1)
    )  # fmt: skip
    return s.exec(query).first()


def keep(s: Session, frame_id: int, message_id: str, stats: dict[str, Any]) -> None:
    """The copy ``message_id`` is the frame's best: its receive statistics become the frame row's."""
    s.execute(update(RelayedFrame).where(col(RelayedFrame.frame_id) == frame_id).values(kept=False))
    s.execute(update(RelayedFrame).where(col(RelayedFrame.id) == message_id).values(kept=True))
    s.execute(update(Frame).where(col(Frame.id) == frame_id).values(**stats))


def heard_by(s: Session, frame_id: int) -> int:
    """How many gateways' copies the frame row stands for."""
    query = select(func.count()).select_from(RelayedFrame).where(RelayedFrame.frame_id == frame_id)
    return int(s.exec(query).one())


def copies(s: Session, frame_id: int) -> list[RelayedFrame]:
    query = (
        select(RelayedFrame).where(RelayedFrame.frame_id == frame_id).order_by(col(RelayedFrame.received_at))
    )
    return list(s.exec(query).all())
