"""The shore's tables. Times are UNIX seconds (float) so SQLite and PostgreSQL agree without zones."""

from __future__ import annotations

import time
from typing import Protocol

from sqlalchemy import JSON, Column, Index, LargeBinary
from sqlmodel import Field, SQLModel


def now() -> float:
    return time.time()


class _Stored(Protocol):
    id: int | None


def saved_id(row: _Stored) -> int:
    """A stored row's primary key; a row not yet flushed has none, and asking for it is a bug."""
    if row.id is None:
        raise ValueError(f"{type(row).__name__} is not stored yet")
    return row.id


class Vehicle(SQLModel, table=True):
    id: int | None = Field(default=None, primary_key=True)
    name: str = Field(unique=True, max_length=64)
    address: int = Field(unique=True, ge=1, le=127)
    key_hex: str = Field(max_length=128)
    key_version: int = Field(default=1, sa_column_kwargs={"server_default": "1"})
    # During a staged rotation: the last key the vehicle confirmed (version key_version - 1); commands
    # are signed with it until a check-point signed with the new key arrives. None: nothing staged.
    previous_key_hex: str | None = Field(default=None, max_length=128)
    next_seq: int = Field(default=1)
    max_depth: float = 100.0
    max_distance: float = 500.0
    max_speed: float = 1.0
    geofence_radius: float = 1000.0
    created_at: float = Field(default_factory=now)


class Mission(SQLModel, table=True):
    id: int | None = Field(default=None, primary_key=True)
    vehicle_id: int = Field(foreign_key="vehicle.id", index=True)
    name: str = Field(max_length=128)
    number: int = Field(ge=0, le=255)
    plan: dict = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    status: str = Field(default="created", max_length=16)  # services.commands.MissionStatus
    created_at: float = Field(default_factory=now)


class Command(SQLModel, table=True):
    id: int | None = Field(default=None, primary_key=True)
    vehicle_id: int = Field(foreign_key="vehicle.id", index=True)
    seq: int
    command: str = Field(max_length=32)
    distance: float = 0.0
    angle: float = 0.0
    depth: float = 0.0
    speed: float = 0.0
    param_id: int = 0
    param_value: float = 0.0
    absolute_angle: bool = False
    delay_sensitive: bool = False
    frame: bytes = Field(sa_column=Column(LargeBinary, nullable=False))
    status: str = Field(default="queued", max_length=16, index=True)
    reason: str = Field(default="", max_length=64)
    attempts: int = 0
    created_at: float = Field(default_factory=now)
    updated_at: float = Field(default_factory=now)

    __table_args__ = (Index("ix_command_vehicle_seq", "vehicle_id", "seq", unique=True),)


class CommandEvent(SQLModel, table=True):
    """One step of a command's life: when the shore learnt it, and, for the steps the vehicle reports,
    the check-point that said so (its vehicle time, mission state and pose: where and when)."""

    id: int | None = Field(default=None, primary_key=True)
    command_id: int = Field(foreign_key="command.id", index=True)
    status: str = Field(max_length=16)
    detail: str = Field(default="", max_length=256)
    at: float = Field(default_factory=now)
    report: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))


class Frame(SQLModel, table=True):
    """Every frame as the modem delivered it, with its receive statistics: the raw record."""

    id: int | None = Field(default=None, primary_key=True)
    direction: str = Field(max_length=3)  # "in" / "out"
    src: int
    dest: int
    rate: int = 0
    data: bytes = Field(sa_column=Column(LargeBinary, nullable=False))
    snr_in: float | None = None
    snr_out: float | None = None
    stats: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))
    at: float = Field(default_factory=now, index=True)


class Packet(SQLModel, table=True):
    """A decoded vehicle packet (duplicates of a retransmission are not stored twice)."""

    id: int | None = Field(default=None, primary_key=True)
    frame_id: int = Field(foreign_key="frame.id", index=True)
    vehicle_id: int = Field(foreign_key="vehicle.id", index=True)
    type: str = Field(max_length=16, index=True)
    seq: int
    priority: int = 0
    body: dict = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    at: float = Field(default_factory=now, index=True)
    # "verified" (a check-point's MAC vouched for it), "pending" (no check-point covered it yet),
    # "forged" (its MAC failed, or a verified check-point vouched for another packet with its seq)
    auth: str = Field(default="pending", max_length=16, sa_column_kwargs={"server_default": "pending"})


class Telemetry(SQLModel, table=True):
    """One reconstructed tick of a stream: values within eps of the truth when ``certain``."""

    id: int | None = Field(default=None, primary_key=True)
    vehicle_id: int = Field(foreign_key="vehicle.id")
    stream: str = Field(max_length=16)
    tick: int
    time: float
    values: list = Field(default_factory=list, sa_column=Column(JSON, nullable=False))
    certain: bool = True
    packet_id: int | None = Field(default=None, foreign_key="packet.id", index=True)
    verified: bool = Field(default=False, sa_column_kwargs={"server_default": "0"})  # its packet's MAC held

    __table_args__ = (Index("ix_telemetry_vehicle_stream_time", "vehicle_id", "stream", "time"),)


class LinkEvent(SQLModel, table=True):
    id: int | None = Field(default=None, primary_key=True)
    vehicle_id: int | None = Field(default=None, foreign_key="vehicle.id", index=True)
    kind: str = Field(max_length=32)
    detail: dict = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    at: float = Field(default_factory=now, index=True)


class LinkState(SQLModel, table=True):
    """Per-vehicle link state the shore needs to go on after a restart (``server.link.ingest``)."""

    vehicle_id: int = Field(foreign_key="vehicle.id", primary_key=True)
    state: dict = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    updated_at: float = Field(default_factory=now)
