"""The command lifecycle: its states, the transitions allowed between them, and the one writer of
command rows.

A command is checked against the packet's ranges and the vehicle's limits (``tacit.limits``) and refused,
with the field at fault, before it can reach the modem. ``submit`` is the one way in (REST, the map and
missions call it); ``advance`` is the one way a command's state changes (the link engine for what the
modem says, the ingest for what check-points say). Each change is a row in ``command_event``, so every
command's history (times, attempts, the vehicle's reason) can be shown.

    queued -> sent (each attempt) -> acknowledged (the vehicle's modem ACKed in hardware)
           -> executing -> executed | refused   (from the vehicle's check-points)
    queued / sent -> failed (no ACK after the configured attempts); superseded (a newer command
    replaced it before it ran)

The states from the vehicle win over the modem's: a check-point that says "executed" is final even if
a late ACK arrives afterwards. A failed command that a check-point shows ran after all becomes what
the vehicle says. Sequence numbers are persisted, so a restart never reuses one; the frame is signed
once per transmission, at send time, with the vehicle's key of that moment.
"""

from __future__ import annotations

import enum
import logging
import math
import time
from collections.abc import Callable, Mapping

from sqlalchemy import Engine, insert, update
from sqlmodel import Session, col, select

from server.db import writing
from server.errors import NotFound, Refused
from server.events import EventBus
from server.link import keys
from server.models import Command, CommandEvent, Mission, Vehicle, now, saved_id
from server.schemas import CommandIn
from tacit import auth
from tacit.limits import Limits
from tacit.navigation import Pose
from tacit.packets import Command as Kind
from tacit.packets import CommandStatus, ControlFlag, ControlPacket, FieldRangeError

log = logging.getLogger("tacit.server.commands")


class Status(enum.StrEnum):
    QUEUED = "queued"
    SENT = "sent"
    ACKNOWLEDGED = "acknowledged"
    EXECUTING = "executing"
    EXECUTED = "executed"
    REFUSED = "refused"
    SUPERSEDED = "superseded"
    FAILED = "failed"


class MissionStatus(enum.StrEnum):
    """A recorded mission, as the shore last asked the vehicle (the vehicle's own state is its check-point's)."""

    CREATED = "created"
    STARTED = "started"
    ABORTED = "aborted"


PENDING = (Status.QUEUED, Status.SENT)  # waiting for the link
FINAL = frozenset({Status.EXECUTED, Status.REFUSED, Status.SUPERSEDED})
_FROM_VEHICLE = frozenset({Status.EXECUTING, *FINAL})
NEXT: Mapping[Status, frozenset[Status]] = {
    Status.QUEUED: frozenset({Status.SENT, Status.FAILED, *_FROM_VEHICLE}),
    Status.SENT: frozenset({Status.SENT, Status.ACKNOWLEDGED, Status.FAILED, *_FROM_VEHICLE}),
    # sent again when no check-point confirmed it (the modem ACKs even when the vehicle's host is down)
    Status.ACKNOWLEDGED: frozenset({Status.SENT, *_FROM_VEHICLE}),
    Status.EXECUTING: FINAL,
    Status.FAILED: _FROM_VEHICLE,  # the vehicle got it after all: its check-point says so
    **{final: frozenset() for final in FINAL},
}
FROM_CHECKPOINT = {CommandStatus.EXECUTING: Status.EXECUTING, CommandStatus.EXECUTED: Status.EXECUTED,
                   CommandStatus.REFUSED: Status.REFUSED, CommandStatus.SUPERSEDED: Status.SUPERSEDED}  # fmt: skip


def allowed(current: str, new: Status) -> bool:
    """Whether a command in state ``current`` may move to ``new``."""
    return new in NEXT[Status(current)]


class CommandRefused(Refused):
    """A command outside the packet's ranges or the vehicle's limits (HTTP 422 naming the field)."""


def limits_of(vehicle: Vehicle) -> Limits:
    """The vehicle's limits as the shore holds them (set through the API)."""
    return Limits(vehicle.max_depth, vehicle.max_distance, vehicle.geofence_radius, vehicle.max_speed)


def check_limits(body: CommandIn, vehicle: Vehicle, pose: Pose | None = None) -> None:
    """Raise ``CommandRefused`` if the command breaks one of the vehicle's limits (``tacit.limits``)."""
    if not math.isfinite(body.param_value):
        raise CommandRefused("param_value must be a finite number", "param_value")
    refused = limits_of(vehicle).check(Kind[body.command.upper()], body.distance, body.angle, body.depth,
                                       body.speed, body.absolute_angle, pose)  # fmt: skip
    if refused is not None:
        raise CommandRefused(refused.message, refused.field)


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


def submit(s: Session, vehicle: Vehicle, body: CommandIn, pose: Pose | None = None,
           mission_id: int | None = None, mission_status: str = "") -> Command:  # fmt: skip
    """Check and queue a command in one transaction (with the mission's new status, if it starts or
    aborts one); raises ``CommandRefused``. ``s`` must be a writing session (``server.db.writing``)."""
    check_limits(body, vehicle, pose)
    seq = s.exec(update(Vehicle).where(col(Vehicle.id) == vehicle.id).values(next_seq=col(Vehicle.next_seq) + 1)
                 .returning(col(Vehicle.next_seq))).one()[0] - 1  # fmt: skip
    command = Command(vehicle_id=saved_id(vehicle), seq=seq, frame=b"", **body.model_dump())
    try:
        packet_for(command).signed_part()  # every field within its range on the wire
    except FieldRangeError as exc:
        s.rollback()
        raise CommandRefused(str(exc), exc.field) from None
    s.add(command)
    s.flush()
    s.add(CommandEvent(command_id=saved_id(command), status=Status.QUEUED, detail=""))
    if mission_id is not None:
        s.execute(update(Mission).where(col(Mission.id) == mission_id).values(status=mission_status))
    s.commit()
    return command


def advance(s: Session, command: Command, status: Status, detail: str = "", reason: str | None = None,
            report: dict | None = None, **extra: object) -> bool:  # fmt: skip
    """Move ``command`` to ``status`` if the lifecycle allows it, with a history row; False if not.
    ``reason`` replaces the stored reason (the vehicle's, or why it failed); ``report`` is what the
    vehicle's check-point said with it (``report_of``). The caller commits."""
    if not allowed(command.status, status):
        return False
    values = {"status": status.value, "updated_at": now(), **extra}
    if reason is not None:
        values["reason"] = reason
    s.execute(update(Command).where(col(Command.id) == command.id).values(**values))
    s.execute(insert(CommandEvent).values(command_id=command.id, status=status.value, detail=detail, at=now(),
                                          report=report))  # fmt: skip
    return True


REPORT_FIELDS = ("time", "state", "north", "east", "depth", "heading")
# commands that set the vehicle's course: once the vehicle takes one on, an older one still executing never ends
NEW_COURSE = frozenset(
    {"move", "goto_depth", "return_home", "hold", "resume", "start_mission", "abort_mission"}
)


def supersede_older(s: Session, command: Command) -> list[Command]:
    """The vehicle reported ``command`` executing or executed: if it set a new course, the vehicle's older
    commands still executing were abandoned on board; mark them superseded (it reports only its latest)."""
    if command.command not in NEW_COURSE:
        return []
    query = select(Command).where(Command.vehicle_id == command.vehicle_id, col(Command.id) < saved_id(command),
                                  Command.status == Status.EXECUTING.value)  # fmt: skip
    older = list(s.exec(query))
    return [
        c for c in older if advance(s, c, Status.SUPERSEDED, f"by command {command.seq} ({command.command})")
    ]


def report_of(checkpoint: Mapping[str, object]) -> dict:
    """What a command's history keeps of the check-point that reported its status: the vehicle's time
    (UNIX s, when the status changed on board) and its mission state and pose at that moment."""
    return {key: checkpoint[key] for key in REPORT_FIELDS if key in checkpoint}


def history(s: Session, command_id: int) -> list[CommandEvent]:
    return histories(s, [command_id]).get(command_id, [])


def histories(s: Session, command_ids: list[int]) -> dict[int, list[CommandEvent]]:
    """The history of each command, oldest step first (one query for a whole page of commands)."""
    out: dict[int, list[CommandEvent]] = {}
    if not command_ids:
        return out
    query = (
        select(CommandEvent)
        .where(col(CommandEvent.command_id).in_(command_ids))
        .order_by(col(CommandEvent.id))
    )
    for event in s.exec(query):
        out.setdefault(event.command_id, []).append(event)
    return out


class CommandDesk:
    """Where commands come in, from the REST API, the operator's map and missions alike: checked against
    the vehicle's limits and its last reported pose, queued in one transaction, announced, and the link
    woken to send it."""

    def __init__(self, db: Engine, bus: EventBus, pose: Callable[[int], Pose | None],
                 wake: Callable[[], None]) -> None:  # fmt: skip
        self.db = db
        self.bus = bus
        self.pose = pose  # by modem address: the last check-point's pose, if any
        self.wake = wake

    def submit(self, vehicle_id: int, body: CommandIn, mission_id: int | None = None,
               mission_status: str = "") -> Command:  # fmt: skip
        with writing(self.db) as s:
            vehicle = s.get(Vehicle, vehicle_id)
            if vehicle is None:
                raise NotFound(f"no vehicle {vehicle_id}", "vehicle_id")
            command = submit(s, vehicle, body, self.pose(vehicle.address), mission_id, mission_status)
        log.info("vehicle %s: command %s seq %d queued", vehicle.name, command.command, command.seq)
        self.bus.publish("command", id=command.id, seq=command.seq, status=Status.QUEUED.value,
                         vehicle=vehicle.name, command=command.command)  # fmt: skip
        self.wake()
        return command
