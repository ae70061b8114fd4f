"""The routing tables: the gateways the center knows, each vehicle's gateway, and each command's
dispatches (one per gateway it was sent through)."""

from __future__ import annotations

import enum

from sqlalchemy import JSON, Column
from sqlmodel import AutoString, Field, SQLModel

from server.core.db import now


class DispatchState(enum.StrEnum):
    """Where one gateway's try of a command stands: ``published`` to the broker, ``stored`` by the
    gateway (its receipt came), ``sent`` (an attempt went on the air), then final: ``acked``, ``failed``
    (no ACK after its attempts), ``expired`` (it came after ``start_by``), ``unanswered`` (no receipt or
    no outcome in time: the gateway is taken for down), ``superseded`` (signed before a SYNC that answered
    the vehicle's challenge: the vehicle would refuse its frame, so it went again, signed anew; not the
    gateway's failure, and what the gateway reports of it is ignored), ``refuted`` (acked by its gateway,
    but a later check-point of the vehicle shows the command never arrived: the gateway lied or erred),
    ``withdrawn`` (its command was cancelled before it was signed: never published)."""

    PUBLISHED = "published"
    STORED = "stored"
    SENT = "sent"
    ACKED = "acked"
    FAILED = "failed"
    EXPIRED = "expired"
    UNANSWERED = "unanswered"
    SUPERSEDED = "superseded"
    REFUTED = "refuted"
    WITHDRAWN = "withdrawn"

    @property
    def final(self) -> bool:
        return self in (
            DispatchState.ACKED,
            DispatchState.FAILED,
            DispatchState.EXPIRED,
            DispatchState.UNANSWERED,
            DispatchState.SUPERSEDED,
            DispatchState.REFUTED,
            DispatchState.WITHDRAWN,
        )


class GatewayRecord(SQLModel, table=True):
    """A gateway the center has heard from (a heartbeat or any event), on the center's clock, and what
    its last heartbeat said (``server.backhaul.subjects.Heartbeat``): kept in the database, so that every
    process serving the API shows the same."""

    __tablename__ = "gateway"

    name: str = Field(primary_key=True, max_length=64)
    first_seen: float = Field(default_factory=now)
    last_seen: float = Field(default_factory=now)
    beating_since: float | None = None  # its first heartbeat after a silence of gateway_timeout
    north: float | None = None  # its modem's place: m north, east of the fleet's origin, depth (m)
    east: float | None = None
    depth: float | None = None
    address: int | None = None  # its modem's address
    modem: str = Field(default="", max_length=32, sa_column_kwargs={"server_default": ""})  # its state
    outbox: int | None = None  # messages not yet published, at its last heartbeat
    outage_s: float | None = None  # how long its last backhaul outage lasted (its own account)
    outage_ended: float | None = None  # when it ended (the gateway's clock)
    outage_backlog: int | None = None  # messages its outbox held when the backhaul came back
    faulty: str = Field(default="", max_length=256, sa_column_kwargs={"server_default": ""})  # why, if
    # what the center can check refuted its word (``Routing.audit``): routed around for a while
    faulty_at: float | None = None  # when (the center's clock)
    foreign_reports: int = Field(default=0, sa_column_kwargs={"server_default": "0"})  # reports of
    # commands that went through another gateway: ignored, counted
    mac: dict | None = Field(default=None, sa_column=Column(JSON, nullable=True))  # gateway.mac.Mac.detail


class Assignment(SQLModel, table=True):
    """A vehicle's gateway: chosen by what the gateways hear, or pinned by an operator; and why."""

    __tablename__ = "assignment"

    vehicle_id: int = Field(primary_key=True, foreign_key="vehicle.id")
    gateway: str = Field(max_length=64)
    pinned: bool = False
    since: float = Field(default_factory=now)  # when the vehicle came to this gateway
    reason: str = Field(default="", max_length=256)


class Dispatch(SQLModel, table=True):
    """One gateway's try of a command: its message id is the command message's (``cmd-<command>-<n>``),
    so a publish retried is the same message, kept once by the gateway's store."""

    __tablename__ = "dispatch"

    id: str = Field(primary_key=True, max_length=128)
    command_id: int = Field(foreign_key="command.id", index=True)
    gateway: str = Field(max_length=64)
    state: DispatchState = Field(default=DispatchState.PUBLISHED, sa_type=AutoString(16))
    start_by: float  # the gateway sends it only if it has it by then (its receipt is due by then)
    deadline: float  # its final outcome is due by then (its frame's age), else the gateway is taken for down
    attempts: int = 0  # the highest attempt number the gateway reported (a redelivered event counts once)

    @property
    def final(self) -> bool:
        return DispatchState(self.state).final  # the column reads back as a plain string

    created_at: float = Field(default_factory=now)
    updated_at: float = Field(default_factory=now)
