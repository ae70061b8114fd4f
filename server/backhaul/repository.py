"""The backhaul's SQL: the relayed frames' ids, the copies of one frame, the best copy's statistics."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import func, insert, update
from sqlmodel import Session, col, select

from server.backhaul.models import RelayedFrame
from server.telemetry.models import Frame


def get(s: Session, message_id: str) -> RelayedFrame | None:
    return s.get(RelayedFrame, message_id)


def stored_ids(s: Session, message_ids: Sequence[str]) -> set[str]:
    """Of the message ids, those stored already."""
    if not message_ids:
        return set()
    return set(s.exec(select(RelayedFrame.id).where(col(RelayedFrame.id).in_(message_ids))).all())


def frame_ids(s: Session, message_ids: Sequence[str], chunk: int = 500) -> dict[str, int | None]:
    """Of the message ids, those stored, with the frame row each stands for."""
    out: dict[str, int | None] = {}
    for i in range(0, len(message_ids), chunk):
        query = select(RelayedFrame.id, RelayedFrame.frame_id).where(
            col(RelayedFrame.id).in_(message_ids[i : i + chunk])
        )
        out.update(dict(s.exec(query).all()))
    return out


def copy_counts(s: Session, frame_ids: Sequence[int], chunk: int = 500) -> dict[int, int]:
    """How many gateways' copies each frame row stands for."""
    out: dict[int, int] = {}
    for i in range(0, len(frame_ids), chunk):
        query = (
            select(RelayedFrame.frame_id, func.count())
            .where(col(RelayedFrame.frame_id).in_(frame_ids[i : i + chunk]))
            .group_by(col(RelayedFrame.frame_id))
        )
        out.update({int(f): int(n) for f, n in s.exec(query).all() if f is not None})
    return out


def add_rows(s: Session, rows: list[dict[str, Any]]) -> None:
    """Relayed frames' records, in one statement."""
    if rows:
        s.execute(insert(RelayedFrame), rows)


def kept_copies(s: Session, frames: Sequence[tuple[int, str]]) -> list[dict[str, Any]]:
    """The kept copies of frames (source, SHA-256 of their bytes) that became frame rows: their ``src``,
    ``digest``, ``at``, ``frame_id``, ``snr_in``, ``kept`` and ``verified``."""
    if not frames:
        return []
    query = select(RelayedFrame).where(
        col(RelayedFrame.src).in_({src for src, _ in frames}),
        col(RelayedFrame.digest).in_({digest for _, digest in frames}), col(RelayedFrame.kept).is_(True),
        col(RelayedFrame.frame_id).is_not(None),
    )  # fmt: skip
    return [
        {
            "src": r.src,
            "digest": r.digest,
            "at": r.at,
            "frame_id": r.frame_id,
            "snr_in": r.snr_in,
            "kept": True,
            "verified": r.verified,
        }
        for r in s.exec(query).all()
    ]


def keep(s: Session, frame_id: int, stats: dict[str, Any]) -> None:
    """A new copy of the frame is its best (recorded kept): the stored copies are not, and its receive
    statistics become the frame row's."""
    s.execute(update(RelayedFrame).where(col(RelayedFrame.frame_id) == frame_id).values(kept=False))
    s.execute(update(Frame).where(col(Frame.id) == frame_id).values(**stats))


def heard_by(s: Session, frame_id: int) -> int:
    """How many gateways' copies the frame row stands for."""
    query = select(func.count()).select_from(RelayedFrame).where(RelayedFrame.frame_id == frame_id)
    return int(s.exec(query).one())


def copies_of(s: Session, frame_ids: Sequence[int]) -> dict[int, list[RelayedFrame]]:
    """Each frame's copies from the gateways that heard it (none for a frame of a shore's own modem),
    in the order they came."""
    if not frame_ids:
        return {}
    query = (
        select(RelayedFrame)
        .where(col(RelayedFrame.frame_id).in_(frame_ids))
        .order_by(col(RelayedFrame.received_at))
    )
    found: dict[int, list[RelayedFrame]] = {}
    for row in s.exec(query).all():
        found.setdefault(row.frame_id or 0, []).append(row)
    return found


def copies(s: Session, frame_id: int) -> list[RelayedFrame]:
    query = (
        select(RelayedFrame).where(RelayedFrame.frame_id == frame_id).order_by(col(RelayedFrame.received_at))
    )
    return list(s.exec(query).all())
