"""The operations' SQL: pruning the relayed frames' records."""

from __future__ import annotations

from sqlalchemy import delete
from sqlmodel import Session, col

from server.backhaul.models import RelayedFrame


def prune_relayed(s: Session, before: float) -> int:
    """Delete the records of frames relayed (stored by the center) before ``before``; how many."""
    result = s.execute(delete(RelayedFrame).where(col(RelayedFrame.received_at) < before))
    return int(result.rowcount or 0)  # type: ignore[attr-defined]
