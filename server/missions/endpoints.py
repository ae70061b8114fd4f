"""Missions: recorded on the shore, started and aborted by a control packet naming their number."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from server.api.deps import Id, MissionsDep, Writer, require_read, require_write
from server.commands.schemas import CommandOut
from server.missions.models import Mission
from server.missions.schemas import MissionIn, MissionOut

router = APIRouter(prefix="/api/v1", tags=["missions"])


def _out(mission: Mission) -> MissionOut:
    return MissionOut.model_validate(mission, from_attributes=True)


@router.post(
    "/vehicles/{vehicle_id}/missions",
    status_code=201,
    response_model=MissionOut,
    dependencies=[Depends(require_write)],
)
def create_mission(vehicle_id: Id, body: MissionIn, missions: MissionsDep) -> MissionOut:
    """Record a mission (the same JSON as the agent's mission file: the vehicle holds the plan; the
    link only says which mission number to start)."""
    return _out(missions.create(vehicle_id, body))


@router.get(
    "/vehicles/{vehicle_id}/missions", response_model=list[MissionOut], dependencies=[Depends(require_read)]
)
def list_missions(vehicle_id: Id, missions: MissionsDep) -> list[MissionOut]:
    return [_out(m) for m in missions.of_vehicle(vehicle_id)]


@router.post("/missions/{mission_id}/start", status_code=202, response_model=CommandOut)
def start_mission(mission_id: Id, missions: MissionsDep, actor: Writer) -> CommandOut:
    return CommandOut.model_validate(missions.start(mission_id, actor.name), from_attributes=True)


@router.post("/missions/{mission_id}/abort", status_code=202, response_model=CommandOut)
def abort_mission(mission_id: Id, missions: MissionsDep, actor: Writer) -> CommandOut:
    return CommandOut.model_validate(missions.abort(mission_id, actor.name), from_attributes=True)
