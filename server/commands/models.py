"""The command tables and the command's status on the shore (``CommandState``), defined once."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from sqlalchemy import JSON, Column, Index, LargeBinary
from sqlmodel import AutoString, Field, SQLModel

from server.core.db import now


class CommandState(enum.StrEnum):
    """Where a command is in its life on the shore (``server.commands.lifecycle`` moves it)."""

    QUEUED = "queued"
    SENT = "sent"
    ACKNOWLEDGED = "acknowledged"
    EXECUTING = "executing"
    EXECUTED = "executed"
    REFUSED = "refused"
    SUPERSEDED = "superseded"
    FAILED = "failed"
    CANCELLING = "cancelling"  # an operator's cancel of a command a gateway holds: withdrawn from it,
    # waiting for its word (cancelled if it had not sent it; else it goes on as sent)
    CANCELLED = "cancelled"  # by an operator while queued: never sent


class StepSource(enum.StrEnum):
    """Where a step of a command's history came from: what the shore decided itself, what a modem or a
    gateway claims, or what the vehicle's authenticated check-point says (the only source of
    ``executing``, ``executed`` and ``refused``)."""

    OPERATOR = "operator"  # an operator's action: queued, cancelled (``via``: the operator's name)
    SHORE = "shore"  # the shore's own decision: failed for want of a gateway, superseded by an abort
    MODEM = "modem"  # the single shore's own modem: an attempt, its hardware ACK
    GATEWAY = "gateway"  # a gateway's report of its attempt (``via``: the gateway), checked as the
    # dispatch's gateway (``server.routing``)
    VEHICLE = "vehicle"  # a check-point whose MAC verified


@dataclass(frozen=True)
class Origin:
    """Who said a step: its source, and the operator or gateway it came by ("" when none)."""

    source: StepSource
    via: str = ""


class CommandRecord(SQLModel, table=True):
    """A control packet queued for a vehicle, and where it stands."""

    __tablename__ = "command"

    id: int | None = Field(default=None, primary_key=True)
    vehicle_id: int = Field(foreign_key="vehicle.id", index=True)
    seq: int
    command: str = Field(max_length=32)  # tacit.packets.Command's name, lower case
    distance: float = 0.0
    angle: float = 0.0
    depth: float = 0.0
    speed: float = 0.0
    param_id: int = 0
    param_value: float = 0.0
    absolute_angle: bool = False
    delay_sensitive: bool = False
    frame: bytes = Field(sa_column=Column(LargeBinary, nullable=False))
    status: CommandState = Field(default=CommandState.QUEUED, sa_type=AutoString(16), index=True)
    reason: str = Field(default="", max_length=64)
    attempts: int = 0
    issued_by: str = Field(  # the operator's name ("": sent before commands recorded one)
        default="", max_length=64, sa_column_kwargs={"server_default": ""}
    )
    created_at: float = Field(default_factory=now)
    updated_at: float = Field(default_factory=now)

    __table_args__ = (Index("ix_command_vehicle_seq", "vehicle_id", "seq", unique=True),)


class CommandStep(SQLModel, table=True):
    """One step of a command's life: when the shore learnt it, and, for the steps the vehicle reports,
    the check-point that said so (its vehicle time, mission state and pose: where and when)."""

    __tablename__ = "commandevent"

    id: int | None = Field(default=None, primary_key=True)
    command_id: int = Field(foreign_key="command.id", index=True)
    status: CommandState = Field(sa_type=AutoString(16))
    detail: str = Field(default="", max_length=256)
    at: float = Field(default_factory=now)
    report: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))
    source: StepSource = Field(
        default=StepSource.SHORE, sa_type=AutoString(16), sa_column_kwargs={"server_default": "shore"}
    )
    via: str = Field(default="", max_length=64, sa_column_kwargs={"server_default": ""})
