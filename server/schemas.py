"""Request and response bodies of the REST API (v1)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from tacit.navigation import wrap180
from tacit.packets import Command as CommandKind

COMMANDS = tuple(c.name.lower() for c in CommandKind)
CommandName = Literal["move", "goto_depth", "hold", "resume", "start_mission", "abort_mission", "return_home",
                      "set_param", "request_checkpoint"]  # fmt: skip


class Limits(BaseModel):
    model_config = ConfigDict(extra="forbid")
    max_depth: float = Field(100.0, gt=0, le=327, description="m")
    max_distance: float = Field(500.0, gt=0, le=6553.5, description="m, per move")
    max_speed: float = Field(1.0, gt=0, le=2.55, description="m/s")
    geofence_radius: float = Field(1000.0, gt=0, le=3276, description="m from home")


class VehicleIn(Limits):
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    address: int = Field(ge=1, le=127, description="the vehicle modem's address")
    key: str | None = Field(None, description="hex, >= 16 bytes; generated when absent")


class VehicleOut(Limits):
    id: int
    name: str
    address: int
    key_version: int


class VehicleCreated(VehicleOut):
    key: str = Field(description="the vehicle's key (hex): shown once; put it in the agent's config")


class CommandIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    command: CommandName
    distance: float = Field(0.0, ge=0, le=6553.5, description="m")
    angle: float = Field(
        0.0,
        ge=-180,
        le=360,
        description="deg; heading change (-180 .. 180, + clockwise), or true bearing "
        "(0 .. 360) if absolute_angle; stored and sent as the same direction in -180 .. 180",
    )
    depth: float = Field(
        0.0, ge=-327.68, le=327.67, description="m; depth change (move) or target (goto_depth)"
    )
    speed: float = Field(0.0, ge=0, le=2.55, description="m/s; 0 = vehicle default")
    param_id: int = Field(0, ge=0, le=255)
    param_value: float = 0.0
    absolute_angle: bool = False
    delay_sensitive: bool = False

    @field_validator("angle")
    @classmethod
    def _one_turn(cls, angle: float) -> float:
        """A bearing of 270 is the direction -90: the packet's angle field holds -180 .. 180."""
        return wrap180(angle) if angle > 180 else angle


class CommandOut(BaseModel):
    id: int
    vehicle_id: int
    seq: int
    command: str
    distance: float
    angle: float
    depth: float
    speed: float
    param_id: int
    param_value: float
    absolute_angle: bool
    status: str
    reason: str
    attempts: int
    created_at: float
    updated_at: float


class CommandEventOut(BaseModel):
    status: str
    detail: str
    at: float


class CommandDetail(CommandOut):
    history: list[CommandEventOut]


class Waypoint(BaseModel):
    model_config = ConfigDict(extra="forbid")
    north: float = Field(ge=-3276, le=3276)
    east: float = Field(ge=-3276, le=3276)
    depth: float = Field(ge=0, le=327)


class MissionIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1, max_length=128)
    number: int = Field(ge=0, le=255, description="the mission id the vehicle knows it by")
    waypoints: list[Waypoint] = Field(default_factory=list, max_length=255)
    duration_s: float = Field(1800, gt=0, description="T_mission")


class MissionOut(BaseModel):
    id: int
    vehicle_id: int
    name: str
    number: int
    plan: dict
    status: str
    created_at: float


class PacketOut(BaseModel):
    id: int
    vehicle_id: int
    type: str
    seq: int
    priority: int
    body: dict
    at: float


class TelemetryOut(BaseModel):
    vehicle_id: int
    stream: str
    tick: int
    time: float
    values: list
    certain: bool


class Page(BaseModel):
    total: int
    limit: int
    offset: int
    items: list


class Problem(BaseModel):
    detail: str
    field: str | None = None
