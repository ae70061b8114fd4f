"""Control commands: queue one (the paper's command, distance, angle, depth), list them, follow one."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query, Response

from server.api.deps import CommandsDep, Id, Offset, Writer, require_read
from server.commands.models import CommandRecord, CommandState, CommandStep
from server.commands.schemas import (
    CommandDetail,
    CommandIn,
    CommandListed,
    CommandOut,
    CommandStepOut,
    FleetCommandIn,
    FleetCommandsOut,
)
from server.core import errors
from server.core.errors import Conflict

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
    responses={
        202: {"model": CommandDetail, "description": "cancelling: withdrawn from the gateway that holds it; "
              "its word ends it, cancelled (it had not sent it) or sent (the cancel lost)"},
        **errors.responses(Conflict),
    },
)  # fmt: skip
def cancel_command(command_id: Id, desk: CommandsDep, actor: Writer, response: Response) -> CommandDetail:
    """Take back a queued command: it ends ``cancelled`` (the history says by whom and when) and is never
    sent (200). Through gateways, one a gateway holds already is withdrawn from it (202, ``cancelling``):
    the gateway's word ends it, ``cancelled`` if it had not sent it, else it goes on as sent (the event
    stream and ``GET /commands/{id}`` say which). 409 with the reason when it lost the race with a
    transmission: it goes on as sent."""
    if desk.cancel(command_id, actor.name).status == CommandState.CANCELLING:
        response.status_code = 202
    command, steps = desk.get(command_id)
    return CommandDetail(**_out(command).model_dump(), history=_steps(steps))


def _out(command: CommandRecord) -> CommandOut:
    return CommandOut.model_validate(command, from_attributes=True)


def _steps(steps: list[CommandStep]) -> list[CommandStepOut]:
    return [CommandStepOut.model_validate(e, from_attributes=True) for e in steps]
