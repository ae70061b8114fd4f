"""Packet and telemetry response bodies."""

from __future__ import annotations

from pydantic import BaseModel, Field

from server.telemetry.models import PacketTrust


class PacketOut(BaseModel):
    id: int
    vehicle_id: int
    type: str
    seq: int
    priority: int
    body: dict
    at: float
    auth: PacketTrust = Field(
        PacketTrust.PENDING,
        description="verified / pending (no check-point covered it yet) / forged / replayed / unverifiable "
        "(covers a packet this shore never received)",
    )


class TelemetryOut(BaseModel):
    vehicle_id: int
    stream: str
    tick: int
    time: float
    values: list
    certain: bool
    verified: bool = Field(False, description="a check-point's MAC covered the packet it came in")
