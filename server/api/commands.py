"""Control commands: queue one (the paper's command, distance, angle, depth), list them, follow one."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query
from sqlmodel import col, select

from server.api.deps import CommandsDep, Id, Offset, ReadSession
from server.auth import require_read, require_write
from server.errors import NotFound
from server.models import Command, CommandEvent, saved_id
from server.schemas import CommandDetail, CommandEventOut, CommandIn, CommandListed, CommandOut
from server.services import commands, vehicles

router = APIRouter(prefix="/api/v1", tags=["commands"])


@router.post("/vehicles/{vehicle_id}/commands", status_code=202, response_model=CommandOut,
             dependencies=[Depends(require_write)])  # fmt: skip
def send_command(vehicle_id: Id, body: CommandIn, desk: CommandsDep) -> Command:
    """Queue a control packet (the paper's command, distance, angle, depth). Refused with 422 and the
    field at fault when outside the packet's ranges or the vehicle's limits; follow its status at
    ``GET /api/v1/commands/{id}`` or on the event stream."""
    return desk.submit(vehicle_id, body)


@router.get(
    "/vehicles/{vehicle_id}/commands",
    response_model=list[CommandListed],
    dependencies=[Depends(require_read)],
)
def list_commands(vehicle_id: Id, s: ReadSession, limit: int = Query(100, ge=1, le=1000), offset: Offset = 0,
                  history: bool = Query(False, description="include each command's history")) -> list[CommandListed]:  # fmt: skip
    """The vehicle's commands, newest first; with ``history=true`` each one's steps as well."""
    vehicles.get(s, vehicle_id)
    query = select(Command).where(Command.vehicle_id == vehicle_id).order_by(col(Command.id).desc())
    rows = list(s.exec(query.offset(offset).limit(limit)))
    steps = commands.histories(s, [saved_id(c) for c in rows]) if history else {}
    return [CommandListed(**_out(c).model_dump(), history=_events(steps.get(saved_id(c), [])) if history else None)
            for c in rows]  # fmt: skip


@router.get("/commands/{command_id}", response_model=CommandDetail, dependencies=[Depends(require_read)])
def get_command(command_id: Id, s: ReadSession) -> CommandDetail:
    """One command with its history: the time of each state, each attempt, the vehicle's reason, and
    for the states the vehicle reported, the check-point's time and pose (``report``)."""
    command = s.get(Command, command_id)
    if command is None:
        raise NotFound(f"no command {command_id}", "command_id")
    return CommandDetail(**_out(command).model_dump(), history=_events(commands.history(s, command_id)))


def _out(command: Command) -> CommandOut:
    return CommandOut.model_validate(command, from_attributes=True)


def _events(events: list[CommandEvent]) -> list[CommandEventOut]:
    return [CommandEventOut.model_validate(e, from_attributes=True) for e in events]
