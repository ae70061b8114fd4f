from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, Query, Request
from sqlmodel import Session, select

from server.api.deps import Id, Offset, db, db_write
from server.api.vehicles import _get
from server.auth import require_read, require_write
from server.models import Command
from server.schemas import CommandDetail, CommandEventOut, CommandIn, CommandOut
from server.services import commands
from tacit.navigation import Pose

router = APIRouter(prefix="/api/v1", tags=["commands"])


def queue_command(request: Request, s: Session, vehicle_id: Id, body: CommandIn) -> Command:
    vehicle = _get(s, vehicle_id)
    state = request.app.state.ingest.vehicles.get(vehicle.address)
    pose = Pose.from_checkpoint(state.checkpoint if state else None)
    try:
        command = commands.queue(s, vehicle, body, pose)
    except commands.CommandRefused as exc:
        raise HTTPException(422, {"detail": str(exc), "field": exc.field}) from None
    request.app.state.bus.publish("command", id=command.id, seq=command.seq, status="queued",
                                  vehicle=vehicle.name, command=command.command)  # fmt: skip
    request.app.state.link.wake()
    return command


@router.post("/vehicles/{vehicle_id}/commands", status_code=202, response_model=CommandOut,
             dependencies=[Depends(require_write)])  # fmt: skip
def send_command(
    vehicle_id: Id, body: CommandIn, request: Request, s: Session = Depends(db_write)
) -> Command:
    """Queue a control packet (the paper's command, distance, angle, depth). Refused with 422 and the
    field at fault when outside the packet's ranges or the vehicle's limits; follow its status at
    ``GET /api/v1/commands/{id}`` or on the event stream."""
    return queue_command(request, s, vehicle_id, body)


@router.get(
    "/vehicles/{vehicle_id}/commands", response_model=list[CommandOut], dependencies=[Depends(require_read)]
)
def list_commands(vehicle_id: Id, s: Session = Depends(db), limit: int = Query(100, ge=1, le=1000),
                  offset: Offset = 0) -> list[Command]:  # fmt: skip
    _get(s, vehicle_id)
    query = select(Command).where(Command.vehicle_id == vehicle_id).order_by(Command.id.desc())  # type: ignore[union-attr]
    return list(s.exec(query.offset(offset).limit(limit)))


@router.get("/commands/{command_id}", response_model=CommandDetail, dependencies=[Depends(require_read)])
def get_command(command_id: Id, s: Session = Depends(db)) -> CommandDetail:
    command = s.get(Command, command_id)
    if command is None:
        raise HTTPException(404, {"detail": f"no command {command_id}", "field": "command_id"})
    history = [
        CommandEventOut.model_validate(e, from_attributes=True) for e in commands.history(s, command_id)
    ]
    return CommandDetail(
        **CommandOut.model_validate(command, from_attributes=True).model_dump(), history=history
    )
