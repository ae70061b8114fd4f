"""What the shore heard: every frame as the modem delivered it, the vehicle packets in it with their
trust, and the reconstructed samples (``PacketTrust``, defined once)."""

from __future__ import annotations

import enum
from typing import NamedTuple

from sqlalchemy import JSON, BigInteger, Column, Index, LargeBinary
from sqlmodel import AutoString, Field, SQLModel

from server.core.db import now


class PacketTrust(enum.StrEnum):
    """How far the shore believes a vehicle packet (``server.link.verify``)."""

    PENDING = "pending"  # no check-point covered it yet
    VERIFIED = "verified"  # a check-point's MAC vouched for it (a check-point: its own MAC held)
    FORGED = "forged"  # its MAC failed, or a verified check-point vouched for another packet with its seq
    REPLAYED = "replayed"  # a check-point older than the last one applied
    UNVERIFIABLE = "unverifiable"  # a check-point covering a packet never received; a packet out of reach


class SampleTrust(enum.StrEnum):
    """How far an exported sample may be believed, from the packet it came in: the exports'
    ``verification`` column (the meanings: ``server.telemetry.metadata.TRUST_MEANINGS``; the members'
    order gives the NetCDF flag values 0..3)."""

    VERIFIED = "verified"
    PENDING = "pending"
    UNVERIFIABLE = "unverifiable"
    FORGED = "forged"

    @classmethod
    def of(cls, verified: bool, auth: PacketTrust | None) -> SampleTrust:
        """A sample's trust from its ``Telemetry.verified`` and its packet's ``auth`` (None: no packet on
        record, which nothing can vouch for). An uncertain lost span keeps its packet's status."""
        if verified:
            return cls.VERIFIED
        if auth == PacketTrust.FORGED:
            return cls.FORGED
        if auth == PacketTrust.PENDING:
            return cls.PENDING
        return cls.UNVERIFIABLE  # vouched for with its data untrusted, no packet, or not a priority packet


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
    """A decoded vehicle packet (duplicates of a retransmission are not stored twice). ``origin`` is the
    packet whose decoder state a priority packet was decoded on; ``trusted``: its data may be believed
    (verified, and decoded along a chain of verified packets)."""

    id: int | None = Field(default=None, primary_key=True)
    frame_id: int = Field(foreign_key="frame.id", index=True)
    vehicle_id: int = Field(foreign_key="vehicle.id", index=True)
    type: str = Field(max_length=16, index=True)
    seq: int
    priority: int = 0
    body: dict = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    at: float = Field(default_factory=now, index=True)
    auth: PacketTrust = Field(
        default=PacketTrust.PENDING,
        sa_type=AutoString(16),
        sa_column_kwargs={"server_default": PacketTrust.PENDING.value},
    )
    origin: int | None = Field(default=None)
    trusted: bool = Field(default=False, sa_column_kwargs={"server_default": "0"})


class Telemetry(SQLModel, table=True):
    """One reconstructed tick of a stream: values within eps of the truth when ``certain``."""

    id: int | None = Field(default=None, primary_key=True)
    vehicle_id: int = Field(foreign_key="vehicle.id")
    stream: str = Field(max_length=16)
    tick: int = Field(sa_column=Column(BigInteger, nullable=False))  # UNIX time / period: beyond 2**31
    time: float
    values: list = Field(default_factory=list, sa_column=Column(JSON, nullable=False))
    certain: bool = True
    packet_id: int | None = Field(default=None, foreign_key="packet.id", index=True)
    verified: bool = Field(default=False, sa_column_kwargs={"server_default": "0"})  # its packet's MAC held
    # the rest of the row before it (the same tick, the channels that row lacks), sent in the next packet
    part: bool = Field(default=False, sa_column_kwargs={"server_default": "0"})

    __table_args__ = (Index("ix_telemetry_vehicle_stream_time", "vehicle_id", "stream", "time"),)


class SampleRow(NamedTuple):
    """What an export reads of a ``Telemetry`` row (a tuple: a month of samples is millions of them)."""

    time: float
    tick: int
    values: list[float | None]
    certain: bool
    verified: bool
    part: bool  # the rest of the row before it (``Telemetry.part``)
