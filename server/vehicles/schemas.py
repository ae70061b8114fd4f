"""Vehicle request and response bodies."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, Field

from server.core.schemas import STRICT
from tacit.limits import Limits
from tacit.packets import NEWEST, VERSIONS, CheckpointPacket
from tacit.packets import ControlPacket as WIRE
from tacit.params import CHECKPOINT_INTERVAL, LostAction, Param

MAX_KEY_HEX = 128  # 64 bytes: twice what HMAC-SHA256 needs
DEFAULT = Limits()


class LimitsIn(BaseModel):
    """Also the body of PUT /limits: only the fields sent are changed (the service dumps with
    ``exclude_unset``), so ``{}`` changes nothing."""

    model_config = STRICT
    # each limit within what the packets can say: a depth a check-point reports, a move a control
    # packet carries, a distance from home a check-point's north/east can hold
    max_depth: float = Field(DEFAULT.max_depth, gt=0, le=WIRE.field("depth").hi, description="m")
    max_distance: float = Field(
        DEFAULT.max_distance, gt=0, le=WIRE.field("distance").hi, description="m, per move"
    )
    max_speed: float = Field(DEFAULT.max_speed, gt=0, le=WIRE.field("speed").hi, description="m/s")
    geofence_radius: float = Field(
        DEFAULT.geofence_radius, gt=0, le=CheckpointPacket.field("north").hi, description="m from home"
    )


NORTH = CheckpointPacket.field("north")  # a position in the fleet's frame a check-point can report
Coordinate = Annotated[float, Field(ge=NORTH.lo, le=NORTH.hi)]


class HomeIn(BaseModel):
    model_config = STRICT
    home: tuple[Coordinate, Coordinate] = Field(
        description="m north, east of the fleet's origin where it starts (its agent's [nav] home)"
    )


class VehicleIn(LimitsIn):
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    address: int = Field(ge=1, le=127, description="the vehicle modem's address")
    key: str | None = Field(
        None, max_length=MAX_KEY_HEX, description="hex, 16 to 64 bytes; generated when absent"
    )
    home: tuple[Coordinate, Coordinate] = Field(
        (0.0, 0.0),
        description="m north, east of the fleet's origin where it starts (its agent's [nav] home): its "
        "mission's waypoints and its return home are relative to it",
    )
    lost_action: LostAction = Field(
        LostAction.HOLD,
        description="what it does when the link is lost (its agent's lost_action; a set_param of parameter "
        f"{int(Param.LOST_ACTION)} changes both): the separation check counts it",
    )
    protocol: int = Field(
        NEWEST,
        ge=min(VERSIONS),
        le=max(VERSIONS),
        description=f"the protocol version its agent speaks (its agent's protocol; {NEWEST} by default): "
        "the shore decodes its packets in it, so a fleet moves to a new version one vehicle at a time",
    )
    report_interval: float = Field(
        CHECKPOINT_INTERVAL,
        gt=0,
        le=86400,
        description="s between its check-points (its agent's checkpoint_interval): until its first is due, "
        "the screens say it is awaited rather than overdue",
    )


class KeyIn(BaseModel):
    model_config = STRICT
    key: str | None = Field(
        None, max_length=MAX_KEY_HEX, description="hex, 16 to 64 bytes; generated when absent"
    )


MAX_SHARE = 100.0  # a vehicle may have up to this many slots for each of another's at share 1


class ShareIn(BaseModel):
    model_config = STRICT
    share: float = Field(
        gt=0, le=MAX_SHARE, description="its weight in the channel's schedule (1: an equal share)"
    )


class KeyRotation(BaseModel):
    """A key rotation waiting for the vehicle's confirmation (``server.vehicles.keys``)."""

    pending_version: int = Field(
        description="the new key's version; commands use the one before until the vehicle holds it"
    )
    since: float = Field(description="when it was staged (UNIX s)")
    held: bool = Field(
        description="the vehicle's last check-point said it holds the new key: commands and SYNCs are "
        "signed with it, and its next check-point signed with it ends the rotation"
    )


class VehicleOut(LimitsIn):
    id: int
    name: str
    address: int
    home: tuple[float, float] = Field(description="m north, east of the fleet's origin where it starts")
    lost_action: LostAction = Field(description="what it does when the link is lost")
    report_interval: float = Field(description="s between its check-points (its agent's checkpoint_interval)")
    key_version: int
    share: float = Field(description="its weight in the channel's schedule")
    protocol: int = Field(description="the protocol version its agent speaks")
    key_rotation: KeyRotation | None = None


class VehicleCreated(VehicleOut):
    key: str = Field(description="the vehicle's key (hex): shown once; put it in the agent's config")
