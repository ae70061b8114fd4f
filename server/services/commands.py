"""Control commands: checked against the packet's ranges and the vehicle's limits, then queued.

A command is refused here, with the field at fault, before it can reach the modem. Queued commands get
the vehicle's next sequence number (persisted, so a restart never reuses one); the link engine signs
each transmission with the vehicle's key at the time it is sent (a queue that waited out the vehicle's
replay window is still accepted).
"""

from __future__ import annotations

import math
import time

from sqlalchemy import update
from sqlmodel import Session, select

from server.link import keys
from server.models import Command, CommandEvent, Vehicle
from server.schemas import CommandIn
from tacit import auth
from tacit.limits import Limits
from tacit.navigation import Pose
from tacit.packets import Command as Kind
from tacit.packets import ControlFlag, ControlPacket, FieldRangeError


class CommandRefused(ValueError):
    def __init__(self, field: str, message: str) -> None:
        super().__init__(message)
        self.field = field


def limits_of(vehicle: Vehicle) -> Limits:
    """The vehicle's limits as the shore holds them (set through the API)."""
    return Limits(vehicle.max_depth, vehicle.max_distance, vehicle.geofence_radius, vehicle.max_speed)


def check_limits(body: CommandIn, vehicle: Vehicle, pose: Pose | None = None) -> None:
    """Raise ``CommandRefused`` if the command breaks one of the vehicle's limits (``tacit.limits``)."""
    if not math.isfinite(body.param_value):
        raise CommandRefused("param_value", "param_value must be a finite number")
    refused = limits_of(vehicle).check(Kind[body.command.upper()], body.distance, body.angle, body.depth,
                                       body.speed, body.absolute_angle, pose)  # fmt: skip
    if refused is not None:
        raise CommandRefused(refused.field, refused.message)


def packet_for(command: Command, stamp: int | None = None) -> ControlPacket:
    flags = ControlFlag(0)
    if command.absolute_angle:
        flags |= ControlFlag.ABSOLUTE_ANGLE
    if command.delay_sensitive:
        flags |= ControlFlag.DELAY_SENSITIVE
    return ControlPacket(Kind[command.command.upper()], command.seq, int(time.time()) if stamp is None else stamp,
                         command.distance, command.angle, command.depth, command.speed, command.param_id,
                         command.param_value, flags)  # fmt: skip


def sign(command: Command, vehicle: Vehicle) -> bytes:
    """The frame to transmit now: the command signed with the vehicle's current key and a fresh stamp."""
    version, key = keys.for_commands(vehicle)  # the last key the vehicle confirmed (staged rotation)
    return auth.sign(packet_for(command), key, vehicle.address, epoch=version)


def queue(s: Session, vehicle: Vehicle, body: CommandIn, pose: Pose | None = None) -> Command:
    check_limits(body, vehicle, pose)
    seq = s.exec(update(Vehicle).where(Vehicle.id == vehicle.id).values(next_seq=Vehicle.next_seq + 1)
                 .returning(Vehicle.next_seq)).one()[0] - 1  # fmt: skip
    command = Command(vehicle_id=vehicle.id, seq=seq, frame=b"", **body.model_dump())  # type: ignore[arg-type]
    try:
        command.frame = sign(command, vehicle)
    except FieldRangeError as exc:
        s.rollback()
        raise CommandRefused(exc.field, str(exc)) from None
    s.add(command)
    s.flush()
    s.add(CommandEvent(command_id=command.id, status="queued", detail=""))  # type: ignore[arg-type]
    s.commit()
    s.refresh(command)
    return command


def history(s: Session, command_id: int) -> list[CommandEvent]:
    return list(
        s.exec(select(CommandEvent).where(CommandEvent.command_id == command_id).order_by(CommandEvent.id))
    )
