from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, Request
from sqlmodel import Session, select

from server.api.commands import queue_command
from server.api.deps import Id, db, db_write
from server.api.vehicles import _get
from server.auth import require_read, require_write
from server.models import Mission
from server.schemas import CommandIn, CommandOut, MissionIn, MissionOut

router = APIRouter(prefix="/api/v1", tags=["missions"])


@router.post("/vehicles/{vehicle_id}/missions", status_code=201, response_model=MissionOut,
             dependencies=[Depends(require_write)])  # fmt: skip
def create_mission(vehicle_id: Id, body: MissionIn, s: Session = Depends(db_write)) -> Mission:
    """Record a mission (the same JSON as the agent's mission file: the vehicle holds the plan; the
    link only says which mission number to start)."""
    _get(s, vehicle_id)
    mission = Mission(vehicle_id=vehicle_id, name=body.name, number=body.number,
                      plan=body.model_dump(include={"waypoints", "duration_s"}))  # fmt: skip
    s.add(mission)
    s.commit()
    s.refresh(mission)
    return mission


@router.get(
    "/vehicles/{vehicle_id}/missions", response_model=list[MissionOut], dependencies=[Depends(require_read)]
)
def list_missions(vehicle_id: Id, s: Session = Depends(db)) -> list[Mission]:
    _get(s, vehicle_id)
    return list(s.exec(select(Mission).where(Mission.vehicle_id == vehicle_id).order_by(Mission.id)))


def _transition(request: Request, s: Session, mission_id: Id, command: str, status: str) -> CommandOut:
    mission = s.get(Mission, mission_id)
    if mission is None:
        raise HTTPException(404, {"detail": f"no mission {mission_id}", "field": "mission_id"})
    queued = queue_command(
        request, s, mission.vehicle_id, CommandIn(command=command, param_id=mission.number)
    )
    mission.status = status
    s.add(mission)
    s.commit()
    return CommandOut.model_validate(queued, from_attributes=True)


@router.post("/missions/{mission_id}/start", status_code=202, response_model=CommandOut,
             dependencies=[Depends(require_write)])  # fmt: skip
def start_mission(mission_id: Id, request: Request, s: Session = Depends(db_write)) -> CommandOut:
    return _transition(request, s, mission_id, "start_mission", "started")


@router.post("/missions/{mission_id}/abort", status_code=202, response_model=CommandOut,
             dependencies=[Depends(require_write)])  # fmt: skip
def abort_mission(mission_id: Id, request: Request, s: Session = Depends(db_write)) -> CommandOut:
    return _transition(request, s, mission_id, "abort_mission", "aborted")
