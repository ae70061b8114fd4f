"""What the screens read: response bodies of the form, the estimate, the link's shares and status, and
the browser's configuration."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field


class CommandSpec(BaseModel):
    hint: str
    fields: list[dict[str, Any]] = Field(
        description="label, unit, min, max, step, required, hint; the angle "
        "field has one spec per mode (relative, bearing)"
    )


class CommandForm(BaseModel):
    commands: dict[str, CommandSpec]
    angle_modes: list[str]
    defaults: dict[str, float]


class PredictedPose(BaseModel):
    north: float
    east: float
    depth: float
    radius_m: float = Field(description="the uncertainty: it grows with silence")
    age_s: float
    target: list[float] | None


class VehicleEstimate(BaseModel):
    reported: dict[str, Any] | None = Field(description="the last verified check-point")
    heard_at: float | None = Field(description="shore time it was received, UNIX s")
    age_s: float | None
    state_label: str | None = None
    state_hint: str | None = None
    speed_mps: float | None = None
    drift_mps: float | None = None
    predicted: PredictedPose | None


class LinkShares(BaseModel):
    airtime_s: dict[str, float]
    shares: dict[str, float]
    counts: dict[str, int]
    bits: dict[str, float | int | None]


class VehicleLinkStatus(BaseModel):
    address: int
    last_heard: float | None
    snr_in: float | None
    snr_out: float | None
    range_m: float | None
    frames: int
    packets: int
    duplicates: int
    packets_per_hour: float
    bytes_saved: int
    checkpoint: dict[str, Any] | None
    old_protocol: int = Field(
        description="packets refused for speaking the previous protocol version (its agent needs "
        "updating; logged once)"
    )


class LinkStatus(BaseModel):
    modem: str
    address: int
    counters: dict[str, int]
    ingest: dict[str, int]
    strangers: dict[str, int] = Field(
        description="frames from unknown modem addresses: kept (the newest "
        "stranger_frames_kept) and dropped since the start"
    )
    vehicles: dict[str, VehicleLinkStatus]


class StreamInfo(BaseModel):
    channels: list[str]
    eps: list[float]
    period: float
    units: list[str]


class StateLabel(BaseModel):
    label: str
    hint: str


class ScreenConfig(BaseModel):
    map_port: int | None
    streams: dict[str, StreamInfo]
    states: dict[str, StateLabel]
    form: CommandForm
    time_scale: float


class Health(BaseModel):
    status: str
    modem: str


class RoleOut(BaseModel):
    role: str = Field(description="write (operator) or read (observer)")
    name: str = Field(description="who: an operator's name (settings' tokens: config-operator-N, ...)")
