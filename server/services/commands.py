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

from server.models import Command, CommandEvent, Vehicle
from server.schemas import CommandIn
from tacit import auth, navigation
from tacit.packets import Command as Kind
from tacit.packets import ControlFlag, ControlPacket, FieldRangeError


class CommandRefused(ValueError):
    def __init__(self, field: str, message: str) -> None:
        super().__init__(message)
        self.field = field


def check_limits(body: CommandIn, vehicle: Vehicle, position: dict | None = None) -> None:
    """Raise ``CommandRefused`` if the command breaks one of the vehicle's limits."""
    if not math.isfinite(body.param_value):
        raise CommandRefused("param_value", "param_value must be a finite number")
    if body.speed > vehicle.max_speed:
        raise CommandRefused("speed", f"speed {body.speed} m/s exceeds the vehicle's {vehicle.max_speed} m/s")
    if body.command == "move":
        if body.distance > vehicle.max_distance:
            raise CommandRefused("distance", f"distance {body.distance} m exceeds the vehicle's "
                                 f"{vehicle.max_distance} m per move")  # fmt: skip
        if abs(body.depth) > vehicle.max_depth:
            raise CommandRefused(
                "depth", f"depth change {body.depth} m exceeds the vehicle's {vehicle.max_depth} m"
            )
        if position is not None:
            _check_move_target(body, vehicle, position)
    if body.command == "goto_depth" and not 0 <= body.depth <= vehicle.max_depth:
        raise CommandRefused("depth", f"target depth {body.depth} m is outside 0 .. {vehicle.max_depth} m")


def _check_move_target(body: CommandIn, vehicle: Vehicle, position: dict) -> None:
    north, east = navigation.move_target(position["north"], position["east"], position["heading"],
                                         body.distance, body.angle, body.absolute_angle)  # fmt: skip
    if math.hypot(north, east) > vehicle.geofence_radius:
        raise CommandRefused("distance", f"the move ends {math.hypot(north, east):.0f} m from home, outside "
                             f"the {vehicle.geofence_radius:.0f} m geofence")  # fmt: skip
    depth = position.get("depth", 0.0) + body.depth
    if not 0 <= depth <= vehicle.max_depth:
        raise CommandRefused(
            "depth", f"the move ends at {depth:.1f} m depth, outside 0 .. {vehicle.max_depth} m"
        )


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
    return auth.sign(packet_for(command), bytes.fromhex(vehicle.key_hex), vehicle.address)


def queue(s: Session, vehicle: Vehicle, body: CommandIn, position: dict | None = None) -> Command:
    check_limits(body, vehicle, position)
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
