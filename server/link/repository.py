"""The link's SQL: its events and each vehicle's saved link state."""

from __future__ import annotations

from typing import Any

from sqlalchemy import delete, insert
from sqlalchemy.dialects import postgresql, sqlite
from sqlmodel import Session, col, select

from server.core.db import now
from server.link.models import LinkEvent, SavedLinkState


def add_events(s: Session, rows: list[dict[str, Any]]) -> None:
    if rows:
        s.execute(insert(LinkEvent), rows)


def drop_events(s: Session, kind: str, n: int) -> None:
    """Delete the ``n`` oldest events of ``kind``."""
    ids = s.exec(
        select(LinkEvent.id).where(LinkEvent.kind == kind).order_by(col(LinkEvent.id)).limit(n)
    ).all()
    if ids:
        s.execute(delete(LinkEvent).where(col(LinkEvent.id).in_(ids)))


def add(s: Session, *rows: object) -> None:
    """Insert ORM rows (frames, events) as they are."""
    s.add_all(rows)


def saved_state(s: Session, vehicle_id: int) -> dict[str, Any] | None:
    row = s.get(SavedLinkState, vehicle_id)
    return None if row is None else row.state


def save_states(s: Session, states: dict[int, dict[str, Any]]) -> None:
    """Several vehicles' states (by vehicle id), inserted or replaced in one statement."""
    if not states:
        return
    upsert = postgresql.insert if s.get_bind().dialect.name == "postgresql" else sqlite.insert
    query = upsert(SavedLinkState)
    query = query.on_conflict_do_update(
        index_elements=[col(SavedLinkState.vehicle_id)],
        set_={"state": query.excluded.state, "updated_at": query.excluded.updated_at},
    )
    at = now()
    s.execute(query, [{"vehicle_id": i, "state": state, "updated_at": at} for i, state in states.items()])


def save_state(s: Session, vehicle_id: int, state: dict[str, Any]) -> None:
    row = s.get(SavedLinkState, vehicle_id)
    if row is None:
        s.add(SavedLinkState(vehicle_id=vehicle_id, state=state))
    else:
        row.state, row.updated_at = state, now()
        s.add(row)
    s.flush()
