"""The mission table and a mission's status as the shore last asked the vehicle, defined once."""

from __future__ import annotations

import enum

from sqlalchemy import JSON, Column
from sqlmodel import AutoString, Field, SQLModel

from server.core.db import now


class MissionStatus(enum.StrEnum):
    """A recorded mission, as the shore last asked the vehicle (the vehicle's own state is its
    check-point's ``MissionState``)."""

    CREATED = "created"
    STARTED = "started"
    ABORTED = "aborted"


class Mission(SQLModel, table=True):
    id: int | None = Field(default=None, primary_key=True)
    vehicle_id: int = Field(foreign_key="vehicle.id", index=True)
    name: str = Field(max_length=128)
    number: int = Field(ge=0, le=255)
    plan: dict = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    status: MissionStatus = Field(default=MissionStatus.CREATED, sa_type=AutoString(16))
    created_at: float = Field(default_factory=now)
