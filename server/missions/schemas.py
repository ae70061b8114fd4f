"""Mission request and response bodies (the same JSON as the agent's mission file)."""

from __future__ import annotations

from pydantic import BaseModel, Field

from server.core.schemas import STRICT
from server.missions.models import MissionStatus
from tacit.packets import CheckpointPacket, ControlPacket

_NORTH = CheckpointPacket.field("north")
_DEPTH = ControlPacket.field("depth")  # a waypoint's depth is one a control packet can command


class Waypoint(BaseModel):
    model_config = STRICT
    north: float = Field(ge=_NORTH.lo, le=_NORTH.hi)
    east: float = Field(ge=_NORTH.lo, le=_NORTH.hi)
    depth: float = Field(ge=0, le=_DEPTH.hi)


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
    status: MissionStatus
    created_at: float
