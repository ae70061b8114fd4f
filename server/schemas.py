"""Request and response bodies of the REST API (v1).

Every request body refuses NaN and +-Infinity (JSON has no such numbers, but Python's parser reads
``NaN``, ``Infinity`` and ``1e999`` into them): a 422 names the field. Strings and lists are bounded.
``json_safe`` makes anything echoed back in an error body encodable (non-finite floats as text).
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

from tacit.navigation import wrap180
from tacit.packets import FLOAT32_MAX, CheckpointPacket
from tacit.packets import ControlPacket as WIRE

# Request bodies: unknown fields and non-finite numbers are errors.
STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)
MAX_KEY_HEX = 128  # 64 bytes: twice what HMAC-SHA256 needs

CommandName = Literal["move", "goto_depth", "hold", "resume", "start_mission", "abort_mission", "return_home",
                      "set_param", "request_checkpoint"]  # fmt: skip


class Limits(BaseModel):
    """Also the body of PUT /limits: only the fields sent are changed (the service dumps with
    ``exclude_unset``), so ``{}`` changes nothing."""

    model_config = STRICT
    # each limit within what the packets can say: a depth a check-point reports, a move a control
    # packet carries, a distance from home a check-point's north/east can hold
    max_depth: float = Field(100.0, gt=0, le=WIRE.field("depth").hi, description="m")
    max_distance: float = Field(500.0, gt=0, le=WIRE.field("distance").hi, description="m, per move")
    max_speed: float = Field(1.0, gt=0, le=WIRE.field("speed").hi, description="m/s")
    geofence_radius: float = Field(
        1000.0, gt=0, le=CheckpointPacket.field("north").hi, description="m from home"
    )


class VehicleIn(Limits):
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    address: int = Field(ge=1, le=127, description="the vehicle modem's address")
    key: str | None = Field(
        None, max_length=MAX_KEY_HEX, description="hex, 16 to 64 bytes; generated when absent"
    )


class KeyIn(BaseModel):
    model_config = STRICT
    key: str | None = Field(
        None, max_length=MAX_KEY_HEX, description="hex, 16 to 64 bytes; generated when absent"
    )


class VehicleOut(Limits):
    id: int
    name: str
    address: int
    key_version: int


class VehicleCreated(VehicleOut):
    key: str = Field(description="the vehicle's key (hex): shown once; put it in the agent's config")


class CommandIn(BaseModel):
    model_config = STRICT
    command: CommandName
    absolute_angle: bool = Field(False, description="angle is a true bearing (0 .. 360), not a turn")
    distance: float = Field(0.0, ge=0, le=WIRE.field("distance").hi, description="m")
    angle: float = Field(
        0.0,
        ge=-180,
        le=360,
        description="deg; heading change (-180 .. 180, + clockwise), or true bearing "
        "(0 .. 360) if absolute_angle; stored and sent as the same direction in -180 .. 180",
    )
    depth: float = Field(0.0, ge=WIRE.field("depth").lo, le=WIRE.field("depth").hi,
                         description="m; depth change (move) or target (goto_depth)")  # fmt: skip
    speed: float = Field(0.0, ge=0, le=WIRE.field("speed").hi, description="m/s; 0 = vehicle default")
    param_id: int = Field(0, ge=0, le=int(WIRE.field("param_id").hi))
    param_value: float = Field(0.0, ge=-FLOAT32_MAX, le=FLOAT32_MAX, description="a float32")
    delay_sensitive: bool = False

    @field_validator("angle")
    @classmethod
    def _one_turn(cls, angle: float, info: ValidationInfo) -> float:
        """A turn is -180 .. 180; a bearing 0 .. 360, and a bearing of 270 is the direction -90 (the
        packet's angle field holds -180 .. 180)."""
        if not info.data.get("absolute_angle") and angle > 180:
            raise ValueError("a turn from the heading is -180 .. 180 deg; for a bearing set absolute_angle")
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


class CommandReport(BaseModel):
    """What the vehicle's check-point said with a status: when (its clock) and where."""

    time: float = Field(description="vehicle time, UNIX s (whole seconds): when the status changed on board")
    state: str = Field(description="the vehicle's mission state then")
    north: float = Field(description="m from home")
    east: float = Field(description="m from home")
    depth: float = Field(description="m, positive down")
    heading: float = Field(description="deg from north")


class CommandEventOut(BaseModel):
    """One step of a command's life, oldest first: queued; sent (one row per attempt, detail
    "attempt N"); acknowledged (the vehicle's modem ACKed); executing, executed, refused (with the vehicle's
    reason), superseded (from the vehicle's check-points, with ``report``); failed (detail: why)."""

    status: str
    detail: str = Field(
        description="attempt number for sent, the vehicle's reason for refused, why for failed"
    )
    at: float = Field(description="shore time, UNIX s: when the shore learnt it")
    report: CommandReport | None = Field(
        None, description="for the steps a check-point reported: the vehicle's time and pose then"
    )


class CommandDetail(CommandOut):
    history: list[CommandEventOut]


class CommandListed(CommandOut):
    history: list[CommandEventOut] | None = Field(
        None, description="with ?history=true: as GET /commands/{id}"
    )


class Waypoint(BaseModel):
    model_config = STRICT
    north: float = Field(ge=-3276, le=3276)
    east: float = Field(ge=-3276, le=3276)
    depth: float = Field(ge=0, le=327)


class MissionIn(BaseModel):
    model_config = STRICT
    name: str = Field(min_length=1, max_length=128)
    number: int = Field(ge=0, le=255, description="the mission id the vehicle knows it by")
    waypoints: list[Waypoint] = Field(default_factory=list, max_length=255)
    duration_s: float = Field(1800, gt=0, le=30 * 86400, description="T_mission, s (at most 30 days)")


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
    auth: str = Field(
        "pending",
        description="verified / pending (no check-point covered it yet) / forged / replayed / unverifiable (covers a "
        "packet this shore never received)",
    )


class TelemetryOut(BaseModel):
    vehicle_id: int
    stream: str
    tick: int
    time: float
    values: list
    certain: bool
    verified: bool = Field(False, description="a check-point's MAC covered the packet it came in")


class Page(BaseModel):
    total: int
    limit: int
    offset: int
    items: list


class Problem(BaseModel):
    detail: str
    field: str | None = None


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float as text and anything else JSON cannot hold as ``str``."""
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, (str, int, bool, type(None))):
        return value
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return str(value)
