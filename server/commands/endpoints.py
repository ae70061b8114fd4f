"""Control commands: queue one (the paper's command, distance, angle, depth), list them, follow one."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query

from server.api.deps import CommandsDep, Id, Offset, Writer, require_read
from server.commands.models import CommandRecord, CommandStep
from server.commands.schemas import (
    CommandDetail,
    CommandIn,
    CommandListed,
    CommandOut,
    CommandStepOut,
    FleetCommandIn,
    FleetCommandsOut,
)

router = APIRouter(prefix="/api/v1", tags=["commands"])


@router.post("/vehicles/{vehicle_id}/commands", status_code=202, response_model=CommandOut)
def send_command(vehicle_id: Id, body: CommandIn, desk: CommandsDep, actor: Writer) -> CommandOut:
    """Queue a control packet (the paper's command, distance, angle, depth). Refused with 422 and the
    field at fault when outside the packet's ranges or the vehicle's limits; follow its status at
    ``GET /api/v1/commands/{id}`` or on the event stream."""
    return _out(desk.submit(vehicle_id, body, actor.name))


@router.post("/fleet/commands", status_code=202, response_model=FleetCommandsOut)
def send_fleet_command(body: FleetCommandIn, desk: CommandsDep, actor: Writer) -> FleetCommandsOut:
    """One operator action for the fleet (abort all, return all home, hold all): the command queued for
    each vehicle (``vehicle_ids``, default every one), each with its own status to follow. 404 naming an
    unknown vehicle; nothing is queued unless every vehicle's command is."""
    queued = desk.submit_fleet(body.vehicle_ids, CommandIn(command=body.command), actor.name)
    return FleetCommandsOut(commands=[_out(c) for c in queued])


@router.get(
    "/vehicles/{vehicle_id}/commands",
    response_model=list[CommandListed],
    dependencies=[Depends(require_read)],
)
def list_commands(
    vehicle_id: Id,
    desk: CommandsDep,
    limit: int = Query(100, ge=1, le=1000),
    offset: Offset = 0,
    history: bool = Query(False, description="include each command's history"),
) -> list[CommandListed]:
    """The vehicle's commands, newest first; with ``history=true`` each one's steps as well."""
    return [
        CommandListed(**_out(c).model_dump(), history=None if steps is None else _steps(steps))
        for c, steps in desk.page(vehicle_id, limit, offset, history)
    ]


@router.get("/commands/{command_id}", response_model=CommandDetail, dependencies=[Depends(require_read)])
def get_command(command_id: Id, desk: CommandsDep) -> CommandDetail:
    """One command with its history: the time of each state, each attempt, the vehicle's reason, and
    for the states the vehicle reported, the check-point's time and pose (``report``)."""
    command, steps = desk.get(command_id)
    return CommandDetail(**_out(command).model_dump(), history=_steps(steps))


@router.post(
    "/commands/{command_id}/cancel",
    response_model=CommandDetail,
    responses={409: {"description": "too late: it was signed for transmission, or is past queued; the "
                     "detail says which, and the command goes on as sent"}},
)  # fmt: skip
def cancel_command(command_id: Id, desk: CommandsDep, actor: Writer) -> CommandDetail:
    """Take back a queued command: it ends ``cancelled`` (the history says by whom and when) and is never
    sent. 409 with the reason when it lost the race with a transmission (signed for one already: on the
    air, or handed to a gateway): it goes on as sent, and its status says how it went."""
    desk.cancel(command_id, actor.name)
    command, steps = desk.get(command_id)
    return CommandDetail(**_out(command).model_dump(), history=_steps(steps))


def _out(command: CommandRecord) -> CommandOut:
    return CommandOut.model_validate(command, from_attributes=True)


def _steps(steps: list[CommandStep]) -> list[CommandStepOut]:
    return [CommandStepOut.model_validate(e, from_attributes=True) for e in steps]
