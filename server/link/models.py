"""The link's own tables: its events (modem states, ranges, refusals) and each vehicle's saved link
state (``server.link.state``), which a restarted shore carries on from."""

from __future__ import annotations

from sqlalchemy import JSON, Column
from sqlmodel import Field, SQLModel

from server.core.db import now


class LinkEvent(SQLModel, table=True):
    id: int | None = Field(default=None, primary_key=True)
    vehicle_id: int | None = Field(default=None, foreign_key="vehicle.id", index=True)
    kind: str = Field(max_length=32)
    detail: dict = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    at: float = Field(default_factory=now, index=True)


class SavedLinkState(SQLModel, table=True):
    """Per-vehicle link state the shore needs to go on after a restart (``server.link.state``)."""

    __tablename__ = "linkstate"

    vehicle_id: int = Field(foreign_key="vehicle.id", primary_key=True)
    state: dict = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    updated_at: float = Field(default_factory=now)
