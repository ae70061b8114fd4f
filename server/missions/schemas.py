"""Mission request and response bodies (the same JSON as the agent's mission file), and team missions'."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, Field, model_validator

from server.core.schemas import STRICT
from server.missions.models import MemberState, MissionStatus, ProposalStatus, TeamStatus
from tacit.packets import CheckpointPacket, ControlPacket
from tacit.params import LostAction

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


# m in the fleet's frame, within what a check-point can report
Coordinate = Annotated[float, Field(ge=_NORTH.lo, le=_NORTH.hi)]


class AreaIn(BaseModel):
    """The survey area in the fleet's frame: a rectangle (``south``, ``north``, ``west``, ``east``, m) or a
    simple polygon (``polygon``: [north, east] corners, in order)."""

    model_config = STRICT
    south: Coordinate | None = None
    north: Coordinate | None = None
    west: Coordinate | None = None
    east: Coordinate | None = None
    polygon: list[tuple[Coordinate, Coordinate]] | None = Field(None, max_length=64)

    @model_validator(mode="after")
    def _one_form(self) -> AreaIn:
        sides = (self.south, self.north, self.west, self.east)
        if (self.polygon is None) == any(side is None for side in sides):
            raise ValueError("give either south, north, west and east, or a polygon (not both)")
        return self

    def corners(self) -> list[tuple[float, float]]:
        if self.polygon is not None:
            return [(float(n), float(e)) for n, e in self.polygon]
        s, n, w, e = (float(x or 0.0) for x in (self.south, self.north, self.west, self.east))
        return [(s, w), (n, w), (n, e), (s, e)]


class TeamVehicleIn(BaseModel):
    model_config = STRICT
    vehicle: str = Field(min_length=1, max_length=64, description="the vehicle's name")
    lost_action: LostAction | None = Field(
        None,
        description="what it is to do when the link is lost ('return' goes to its registered home); "
        "default its own (the vehicle's lost_action); another is set on the vehicle (set_param) when "
        "the team starts",
    )


class TeamIn(BaseModel):
    model_config = STRICT
    name: str = Field(min_length=1, max_length=128)
    vehicles: list[TeamVehicleIn] = Field(min_length=1, max_length=16, description="west to east")
    area: AreaIn
    spacing: float = Field(ge=1, le=1000, description="m between lanes")
    depth: float = Field(ge=0, le=_DEPTH.hi, description="survey depth, m")


class MemberOut(BaseModel):
    vehicle_id: int
    name: str
    lost_action: LostAction
    home: list[float]
    waypoints: list[list[float]]
    next: int
    command_id: int | None
    state: MemberState
    reason: str
    stopping: bool = Field(
        False,
        description="its current command stops what it did before (abort_mission): its first leg follows",
    )


class LinkCostOut(BaseModel):
    """What the team mission costs on the link at rate 0 (``server.missions.plans.LegCost``)."""

    legs: int
    bits_per_leg_down: int
    bits_per_leg_up: int
    channel_s_per_leg: float
    channel_s: float


class TeamOut(BaseModel):
    id: int
    name: str
    area: list[list[float]]
    spacing: float
    depth: float
    status: TeamStatus
    detail: str = Field(description="why its last start was refused (status refused)")
    members: list[MemberOut]
    link: LinkCostOut
    created_at: float


class WorkOut(BaseModel):
    vehicle_id: int
    name: str
    target: list[float]


class ProposalOut(BaseModel):
    id: int
    team_id: int
    finder: str
    anomaly: list[float]
    work: list[WorkOut]
    status: ProposalStatus
    detail: str
    decided_by: str
    created_at: float
