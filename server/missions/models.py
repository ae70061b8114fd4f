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


class TeamStatus(enum.StrEnum):
    """A team mission as the shore runs it: legs are queued only while it is ``started``."""

    CREATED = "created"
    REFUSED = "refused"  # its start was refused: ``detail`` says why; it may be started again or deleted
    STARTED = "started"
    ABORTED = "aborted"
    FINISHED = "finished"


class MemberState(enum.StrEnum):
    """One vehicle's part of a team mission."""

    WAITING = "waiting"  # the team has not started
    RUNNING = "running"  # a leg is queued or under way
    DONE = "done"  # its last waypoint was reached
    STOPPED = "stopped"  # a leg was refused, failed or replaced: ``reason`` says which and why


class TeamMission(SQLModel, table=True):
    """A survey area split among vehicles. ``members`` (JSON, in lane order, west to east): each one's
    ``vehicle_id``, ``name``, ``lost_action``, ``home``, ``waypoints`` ([north, east, depth]), the index
    of the waypoint its current leg goes to (``next``), that leg's ``command_id``, ``state``, ``reason``;
    ``stopping`` while its command is the abort that takes it over at the start."""

    id: int | None = Field(default=None, primary_key=True)
    name: str = Field(max_length=128)
    area: list = Field(default_factory=list, sa_column=Column(JSON, nullable=False))  # [[north, east], ...]
    spacing: float
    depth: float
    members: list = Field(default_factory=list, sa_column=Column(JSON, nullable=False))
    status: TeamStatus = Field(default=TeamStatus.CREATED, sa_type=AutoString(16))
    detail: str = Field(default="", max_length=1024, sa_column_kwargs={"server_default": ""})
    created_at: float = Field(default_factory=now)


class ProposalStatus(enum.StrEnum):
    PROPOSED = "proposed"  # waits for an operator (Settings.restructure_auto is off)
    APPLIED = "applied"
    DISMISSED = "dismissed"


class TeamProposal(SQLModel, table=True):
    """New work the shore proposes when a team vehicle reports a time-sensitive anomaly (the
    restructuring rule, ``server.missions.plans.restructure``). ``work``: [{vehicle_id, name, target}]."""

    id: int | None = Field(default=None, primary_key=True)
    team_id: int = Field(foreign_key="teammission.id", index=True)
    finder: str = Field(max_length=64)  # the vehicle that reported the anomaly
    anomaly: list = Field(
        default_factory=list, sa_column=Column(JSON, nullable=False)
    )  # [north, east, depth]
    work: list = Field(default_factory=list, sa_column=Column(JSON, nullable=False))
    status: ProposalStatus = Field(default=ProposalStatus.PROPOSED, sa_type=AutoString(16))
    detail: str = Field(default="", max_length=1024)  # when applied: what was queued or refused
    decided_by: str = Field(default="", max_length=64)
    created_at: float = Field(default_factory=now)
