"""Packet and telemetry response bodies."""

from __future__ import annotations

from pydantic import BaseModel, Field

from server.telemetry.models import PacketTrust


class Copy(BaseModel):
    """One gateway's copy of a packet's frame."""

    gateway: str
    snr: float | None = Field(description="SNR in (dB) of its copy")
    kept: bool = Field(description="the copy with the best SNR: its receive statistics are the frame's")


class PacketOut(BaseModel):
    id: int
    frame_id: int = Field(description="the frame it came in")
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
    snr: float | None = Field(
        None, description="SNR in (dB) of its frame: the shore modem's, or the best gateway's copy"
    )
    heard: list[Copy] = Field(
        default_factory=list,
        description="a center's gateways that heard its frame, in the order their copies came (empty: "
        "the shore's own modem)",
    )


class TelemetryOut(BaseModel):
    vehicle_id: int
    stream: str
    tick: int
    time: float
    values: list
    certain: bool
    verified: bool = Field(False, description="a check-point's MAC covered the packet it came in")
