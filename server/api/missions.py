"""Missions: recorded on the shore, started and aborted by a control packet naming their number."""

from __future__ import annotations

from fastapi import APIRouter, Depends
from sqlmodel import col, select

from server.api.deps import CommandsDep, Id, ReadSession, WriteDep
from server.auth import require_read, require_write
from server.errors import NotFound
from server.models import Mission
from server.schemas import CommandIn, CommandOut, MissionIn, MissionOut
from server.services import vehicles
from server.services.commands import MissionStatus

router = APIRouter(prefix="/api/v1", tags=["missions"])


@router.post("/vehicles/{vehicle_id}/missions", status_code=201, response_model=MissionOut,
             dependencies=[Depends(require_write)])  # fmt: skip
def create_mission(vehicle_id: Id, body: MissionIn, write: WriteDep) -> Mission:
    """Record a mission (the same JSON as the agent's mission file: the vehicle holds the plan; the
    link only says which mission number to start)."""
    with write() as s:
        vehicles.get(s, vehicle_id)
        mission = Mission(vehicle_id=vehicle_id, name=body.name, number=body.number,
                          plan=body.model_dump(include={"waypoints", "duration_s"}))  # fmt: skip
        s.add(mission)
        s.commit()
    return mission


@router.get(
    "/vehicles/{vehicle_id}/missions", response_model=list[MissionOut], dependencies=[Depends(require_read)]
)
def list_missions(vehicle_id: Id, s: ReadSession) -> list[Mission]:
    vehicles.get(s, vehicle_id)
    return list(s.exec(select(Mission).where(Mission.vehicle_id == vehicle_id).order_by(col(Mission.id))))


def _transition(
    desk: CommandsDep, s: ReadSession, mission_id: int, command: str, status: MissionStatus
) -> CommandOut:
    """The control packet that starts or aborts a mission, queued with the mission's new status."""
    mission = s.get(Mission, mission_id)
    if mission is None:
        raise NotFound(f"no mission {mission_id}", "mission_id")
    body = CommandIn(command=command, param_id=mission.number)
    queued = desk.submit(mission.vehicle_id, body, mission_id=mission_id, mission_status=status)
    return CommandOut.model_validate(queued, from_attributes=True)


@router.post("/missions/{mission_id}/start", status_code=202, response_model=CommandOut,
             dependencies=[Depends(require_write)])  # fmt: skip
def start_mission(mission_id: Id, desk: CommandsDep, s: ReadSession) -> CommandOut:
    return _transition(desk, s, mission_id, "start_mission", MissionStatus.STARTED)


@router.post("/missions/{mission_id}/abort", status_code=202, response_model=CommandOut,
             dependencies=[Depends(require_write)])  # fmt: skip
def abort_mission(mission_id: Id, desk: CommandsDep, s: ReadSession) -> CommandOut:
    return _transition(desk, s, mission_id, "abort_mission", MissionStatus.ABORTED)
