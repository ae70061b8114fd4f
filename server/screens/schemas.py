"""What the screens read: response bodies of the form, the estimate, the link's shares and status, and
the browser's configuration."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field

from server.backhaul.access import BrokerMode


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


class LatLon(BaseModel):
    lat: float = Field(description="deg north")
    lon: float = Field(description="deg east")


class FleetVehicle(BaseModel):
    """One vehicle as both screens list it."""

    id: int
    name: str
    address: int
    colour: str = Field(description="#rrggbb: its track and rows on both screens (the fleet's palette)")
    home: list[float] = Field(description="m north, east of the fleet's origin where it starts")
    gateway: str | None = Field(
        description="the gateway its commands go through (a center's; None: not assigned, or one shore)"
    )
    gateway_pinned: bool = Field(description="an operator pinned it to that gateway")
    reported: dict[str, Any] | None = Field(description="its last verified check-point (vehicle clock)")
    heard_at: float | None = Field(description="when the shore received it (shore clock, UNIX s)")
    age_s: float | None
    state_label: str | None
    state_hint: str | None
    predicted: PredictedPose | None
    predicted_latlon: list[float] | None = Field(description="[lat, lon] of the prediction, origin known")
    reported_shore_time: float | None = Field(
        description="the check-point's time on the shore's clock: the latest it can have been made"
    )
    clock_offset_s: float | None = Field(
        description="the vehicle's clock minus the shore's, at least (from its recent check-points)"
    )
    battery_v: float | None
    last_heard: float | None = Field(description="the last frame heard from it (shore clock)")
    snr_in: float | None
    snr_out: float | None
    range_m: float | None
    overdue: bool = Field(description="heard nothing for longer than its place in the schedule allows")
    overdue_after_s: float | None = Field(
        description="the silence that makes it overdue: its report gap (before two check-points, its report "
        "interval) and three of its slot intervals"
    )
    awaited: bool = Field(
        False, description="no check-point heard yet and its first not due yet: starting, not overdue"
    )
    first_report_due: float | None = Field(
        None, description="while awaited: when its first check-point is overdue (shore clock, UNIX s)"
    )
    next_slot: str | None = Field(description="what its next slot carries (GET /link/schedule)")
    share: float
    airtime_s: dict[str, float] = Field(description="its seconds on the air by use, and their total")
    airtime_share: float = Field(description="its part of the fleet's airtime")
    queued: int = Field(
        description="its commands waiting for the link (queued, or sent and not acknowledged)"
    )
    queue_cap: int = Field(description="the most that may wait (max_queued_commands): more are refused, 429")


class Fleet(BaseModel):
    origin: LatLon | None = Field(description="the fleet's one origin (north = east = 0); None: not known")
    palette: list[str] = Field(description="the vehicles' colours, in order of registration")
    vehicles: list[FleetVehicle]


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
        description="packets refused for speaking another protocol version than the vehicle's (version 2, "
        "or samples in a version it is not registered as speaking; logged once)"
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
    map_url: str | None = Field(
        None,
        description="the 3D map's address as browsers reach it (a proxy's); none: the page's host on map_port",
    )
    streams: dict[str, StreamInfo]
    states: dict[str, StateLabel]
    form: CommandForm
    time_scale: float


class Health(BaseModel):
    status: str
    modem: str
    broker: BrokerMode | None = Field(
        None,
        description="a center's broker: accounts (credentials) or insecure (--insecure); none: no broker",
    )


class RoleOut(BaseModel):
    role: str = Field(description="write (operator) or read (observer)")
    name: str = Field(description="who: an operator's name (settings' tokens: config-operator-N, ...)")
