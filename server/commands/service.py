"""Commands: the one way in (``CommandDesk.submit``: REST, the map and missions call it), the one way a
command's state changes (``advance``: the link for what the modem says, ingest for what check-points
say), signing at send time, and reading a command with its history.

A command is checked against the packet's ranges and the vehicle's limits (``tacit.limits``) and refused,
with the field at fault, before it can reach the modem. Each change is a row in ``commandevent``, so
every command's history (times, attempts, the vehicle's reason) can be shown. Sequence numbers are
persisted, so a restart never reuses one; the frame is signed once per transmission, at send time, with
the vehicle's key of that moment.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import replace

from sqlalchemy import Engine

from server.commands import repository as repo
from server.commands.lifecycle import FROM_CHECKPOINT, allowed, report_of
from server.commands.models import CommandRecord, CommandState, CommandStep, Origin, StepSource
from server.commands.schemas import CommandIn
from server.core.db import Tx, reading, saved_id, writing
from server.core.errors import Conflict, NotFound, Refused, TooMany
from server.core.events import Bus, CommandChanged
from server.telemetry import clock
from server.telemetry import service as telemetry
from server.vehicles import keys
from server.vehicles import repository as vehicle_repo
from server.vehicles import service as vehicles
from server.vehicles.models import Vehicle
from tacit import auth
from tacit.navigation import Pose
from tacit.packets import (
    CheckpointPacket,
    Command,
    CommandStatus,
    ControlFlag,
    ControlPacket,
    FieldRangeError,
    unpack_settled,
)
from tacit.params import LostAction, Param

log = logging.getLogger("tacit.server.commands")

IN_FLIGHT = (
    CommandState.SENT,
    CommandState.ACKNOWLEDGED,
    CommandState.EXECUTING,
)  # a check-point will end it
RETRY_AFTER_S = 10  # a full queue's answer: about two command attempts at the default range
ABORTED = "by an abort before it was sent"  # what happens to the commands an abort overtakes
MODEM = Origin(StepSource.MODEM)  # the single shore's link records what its own modem said


class CommandRefused(Refused):
    """A command outside the packet's ranges or the vehicle's limits (HTTP 422 naming the field)."""


def check_limits(body: CommandIn, vehicle: Vehicle, pose: Pose | None = None) -> None:
    """Raise ``CommandRefused`` if the command breaks one of the vehicle's limits (``tacit.limits``); ``pose``
    is in the fleet's frame (a check-point's), the geofence around the vehicle's home."""
    if not math.isfinite(body.param_value):
        raise CommandRefused("param_value must be a finite number", "param_value")
    lost = body.kind() is Command.SET_PARAM and body.param_id == Param.LOST_ACTION
    if lost and LostAction.of_code(body.param_value) is None:
        raise CommandRefused(
            f"parameter {int(Param.LOST_ACTION)} ({Param.LOST_ACTION.hint}) takes "
            + ", ".join(str(a.code) for a in LostAction),
            "param_value",
        )
    from_home = (
        None
        if pose is None
        else replace(pose, north=pose.north - vehicle.home_north, east=pose.east - vehicle.home_east)
    )
    refused = vehicle.limits().check(
        body.kind(), body.distance, body.angle, body.depth, body.speed, body.absolute_angle, from_home
    )
    if refused is not None:
        raise CommandRefused(refused.message, refused.field)


def packet_for(command: CommandRecord, stamp: int | None = None) -> ControlPacket:
    flags = ControlFlag(0)
    if command.absolute_angle:
        flags |= ControlFlag.ABSOLUTE_ANGLE
    if command.delay_sensitive:
        flags |= ControlFlag.DELAY_SENSITIVE
    return ControlPacket(
        Command[command.command.upper()],
        command.seq,
        int(time.time()) if stamp is None else stamp,
        command.distance,
        command.angle,
        command.depth,
        command.speed,
        command.param_id,
        command.param_value,
        flags,
    )


def sign(command: CommandRecord, vehicle: Vehicle) -> bytes:
    """The frame to transmit now: the command signed with the vehicle's current key and a fresh stamp."""
    version, key = keys.for_commands(vehicle)  # the last key the vehicle confirmed (staged rotation)
    return auth.sign(packet_for(command), key, vehicle.address, epoch=version)


def queue(
    s: Tx, vehicle: Vehicle, body: CommandIn, issued_by: str, pose: Pose | None = None
) -> CommandRecord:
    """Check and queue a command (``s`` a writing session; the caller commits); raises ``CommandRefused``."""
    check_limits(body, vehicle, pose)
    seq = vehicle_repo.take_seq(s, saved_id(vehicle))
    command = CommandRecord(
        vehicle_id=saved_id(vehicle), seq=seq, frame=b"", issued_by=issued_by, **body.model_dump()
    )
    try:
        packet_for(command).signed_part()  # every field within its range on the wire
    except FieldRangeError as exc:
        s.rollback()
        raise CommandRefused(str(exc), exc.field) from None
    return repo.add(s, command)


def advance(
    s: Tx,
    command: CommandRecord,
    status: CommandState,
    detail: str = "",
    reason: str | None = None,
    report: dict | None = None,
    at: float | None = None,
    *,
    origin: Origin,
    **extra: object,
) -> bool:
    """Move ``command`` to ``status`` if the lifecycle allows it, with a history row dated ``at`` (default
    now) saying who said it (``origin``); False if not. ``reason`` replaces the stored reason (the vehicle's, or why it failed); ``report``
    is what the vehicle's check-point said with it (``lifecycle.report_of``). The caller commits."""
    if not allowed(command.status, status):
        return False
    values = dict(extra)
    if reason is not None:
        values["reason"] = reason
    repo.move(s, command.id, status, detail, report, values, origin, at)
    return True


def supersede_older(s: Tx, command: CommandRecord) -> list[CommandRecord]:
    """The vehicle reported ``command`` executing or executed: if it set a new course, the vehicle's older
    commands still executing were abandoned on board; mark them superseded (it reports only its latest)."""
    if not Command[command.command.upper()].sets_course:
        return []
    detail = f"by command {command.seq} ({command.command})"
    said = Origin(StepSource.VEHICLE)
    return [
        c
        for c in repo.executing_before(s, command)
        if advance(s, c, CommandState.SUPERSEDED, detail, origin=said)
    ]


def _uncancellable(command: CommandRecord) -> str:
    """Why ``command`` can no longer be cancelled, in one sentence."""
    if command.status == CommandState.QUEUED:
        return (
            f"command {command.id} (seq {command.seq}) was already signed for transmission (on the air, or "
            "handed to a gateway): too late to cancel, it goes on as sent"
        )
    if command.status in (CommandState.SENT, CommandState.ACKNOWLEDGED, CommandState.EXECUTING):
        return f"command {command.id} (seq {command.seq}) is {command.status} already: it goes on as sent"
    if command.status == CommandState.CANCELLING:
        return f"command {command.id} (seq {command.seq}) is being withdrawn from its gateway already"
    return f"command {command.id} (seq {command.seq}) is {command.status}: nothing left to cancel"


def _caught_up(s: Tx, vehicle: Vehicle, reported: int) -> int:
    """The latest sequence number issued to the vehicle, raised to the one its verified check-point
    reports when that is ahead (by less than half the 16-bit circle): the shore's database is older than
    the vehicle's memory (restored from a backup, or lost). Numbers it would issue again from there are
    ones the vehicle already accepted, and it would refuse every command as a replay."""
    latest = vehicle.next_seq - 1
    ahead = (reported - latest) % 65536
    if 0 < ahead < 32768:
        log.warning(
            "vehicle %s: its check-point reports command seq %d, which this shore has not issued (a database "
            "older than the vehicle's memory): issuing from seq %d",
            vehicle.name,
            latest + ahead,
            latest + ahead + 1,
        )
        latest += ahead
        vehicle_repo.raise_next_seq(s, saved_id(vehicle), latest + 1)
        vehicle.next_seq = latest + 1
    return latest


def _took_effect(s: Tx, vehicle: Vehicle, command: CommandRecord) -> None:
    """What the shore keeps of a command the vehicle executed: a new lost-link action."""
    if command.command == Command.SET_PARAM.name.lower() and command.param_id == Param.LOST_ACTION:
        action = LostAction.of_code(command.param_value)
        if action is not None:
            vehicle_repo.set_lost_action(s, saved_id(vehicle), action)
            log.info(
                "vehicle %s: lost-link action now %s (command seq %d)", vehicle.name, action, command.seq
            )


def apply_checkpoint(s: Tx, vehicle: Vehicle, cp: CheckpointPacket, body: dict) -> list[CommandChanged]:
    """What a verified check-point says of the vehicle's commands, through the one lifecycle:
    last_command's status, with where and when (``body``, the check-point), and the final statuses of the
    four commands before it, oldest first, each in its turn; then older commands a new course left
    executing are superseded."""
    if not cp.last_command:
        return []
    latest = _caught_up(s, vehicle, cp.last_command)  # the check-point names it with these low 16 bits
    last = latest - ((latest - cp.last_command) % 65536)
    heard_at = time.time()
    vehicle_offset = telemetry.clock_offset(s, saved_id(vehicle), (cp.time, heard_at))
    report = {**report_of(body), "shore_time": clock.on_shore_clock(cp.time, heard_at, vehicle_offset)}
    settled: list[tuple[int, CommandStatus | None, dict | None]] = [
        (last - k, status, None) for k, status in enumerate(unpack_settled(cp.settled), start=1)
    ]
    events: list[CommandChanged] = []
    newest: CommandRecord | None = None
    said = Origin(StepSource.VEHICLE)  # the check-point's MAC verified (``server.link.verify``)
    for seq, reported, where in [*reversed(settled), (last, cp.command_status, report)]:
        status = FROM_CHECKPOINT.get(reported) if reported else None
        command = repo.by_seq(s, saved_id(vehicle), seq) if status is not None and seq > 0 else None
        reason = cp.reason.name.lower() if where is not None and reported is CommandStatus.REFUSED else ""
        if (
            command is None
            or status is None
            or not advance(s, command, status, reason, reason=reason, report=where, origin=said)
        ):
            continue
        events.append(
            CommandChanged(
                saved_id(command), command.seq, status, vehicle=vehicle.name, reason=reason, report=where
            )
        )
        if status is CommandState.EXECUTED:
            _took_effect(s, vehicle, command)
        if where is not None and status in (CommandState.EXECUTING, CommandState.EXECUTED):
            newest = command
    if newest is not None:  # after the settled finals: only what the vehicle left unsettled is superseded
        events += [
            CommandChanged(saved_id(old), old.seq, CommandState.SUPERSEDED, vehicle=vehicle.name)
            for old in supersede_older(s, newest)
        ]
    return events


class CommandDesk:
    """Where commands come in, from the REST API, the operator's map and missions alike: checked against
    the vehicle's limits and its last reported pose, queued in one transaction, announced, and the link
    woken to send it. Also the commands' reads."""

    def __init__(
        self,
        db: Engine,
        bus: Bus,
        pose: Callable[[int], Pose | None],
        max_queued: int,
        withdrawable: bool = False,
    ) -> None:
        """``withdrawable``: a signed command may still be taken back (a center: its gateways hold the
        frames it hands them until they send them, and take a withdrawal); on a single shore a signed
        command is on the air."""
        self.db = db
        self.withdrawable = withdrawable
        self._claims = threading.Lock()  # a single shore's: a cancel and a signing, one at a time
        self._signed: set[int] = set()  # a single shore's commands signed for an attempt, not yet recorded
        self.bus = bus
        self.pose = pose  # by modem address: the last check-point's pose, if any
        self.max_queued = max_queued  # Settings.max_queued_commands
        self.wake: Callable[[], None] = lambda: None  # the link's: send what was queued now
        # the safety functions' check of the command's path for each of the vehicles against the other
        # vehicles' (``server.safety``; raises Refused)
        self.guard: Callable[[list[int], CommandIn], None] = lambda _vehicle_ids, _body: None

    def submit(
        self, vehicle_id: int, body: CommandIn, issued_by: str, then: Callable[[Tx], None] | None = None
    ) -> CommandRecord:
        """Queue a command sent by the operator named ``issued_by``; ``then(s)`` runs in the same transaction (a mission's new status).
        First the guard: a command whose path passes too close to another vehicle's is refused
        (``server.safety``)."""
        self.guard([vehicle_id], body)
        events: list[CommandChanged] = []
        with writing(self.db) as s:
            command = self._queue(s, vehicles.get(s, vehicle_id), body, issued_by, events)
            if then is not None:
                then(s)
            s.commit()
        self._announce(events)
        return command

    def submit_fleet(
        self, vehicle_ids: list[int] | None, body: CommandIn, issued_by: str
    ) -> list[CommandRecord]:
        """One operator action for several vehicles (every registered one if ``vehicle_ids`` is None): the
        command queued once per vehicle, each with its own seq and status, all or none (one transaction:
        an unknown vehicle, or one whose queue is full, refuses the action before anything is queued).
        The guard checks every vehicle's new path against the others' new and planned ones: a return of
        all home to one shared home is refused saying so."""
        with reading(self.db) as s:
            fleet = [vehicles.get(s, i) for i in vehicle_ids] if vehicle_ids else vehicle_repo.every(s)
        if not fleet:
            raise Refused("no vehicle is registered", "vehicle_ids")
        if len({v.id for v in fleet}) < len(fleet):
            raise Refused("a vehicle is named twice", "vehicle_ids")
        self.guard([saved_id(v) for v in fleet], body)
        events: list[CommandChanged] = []
        with writing(self.db) as s:
            queued = [self._queue(s, vehicles.get(s, saved_id(v)), body, issued_by, events) for v in fleet]
            s.commit()
        self._announce(events)
        return queued

    def _queue(
        self, s: Tx, vehicle: Vehicle, body: CommandIn, issued_by: str, events: list[CommandChanged]
    ) -> CommandRecord:
        """Check and queue one command for ``vehicle``, its events added to ``events``. An abort (the fleet's
        stop) first supersedes the vehicle's commands not yet sent: they would only run after it, and they
        never hold it back. Otherwise refused with ``TooMany`` while the vehicle already has ``max_queued``
        commands waiting for the link: at a few seconds per attempt, a longer queue would only hold the
        link for minutes (and each command would run long after the operator asked for it)."""
        if body.kind() is Command.ABORT_MISSION:
            events += [
                CommandChanged(
                    saved_id(c), c.seq, CommandState.SUPERSEDED, vehicle=vehicle.name, detail=ABORTED
                )
                for c in repo.queued(s, saved_id(vehicle))
                if advance(
                    s, c, CommandState.SUPERSEDED, ABORTED, origin=Origin(StepSource.OPERATOR, issued_by)
                )
            ]
        waiting = repo.pending_count(s, saved_id(vehicle))
        if waiting >= self.max_queued:
            raise TooMany(
                f"vehicle {vehicle.name} has {waiting} commands waiting for the link, its queue's cap "
                f"({self.max_queued}, max_queued_commands: a longer queue would hold the link for minutes and "
                "each command would run long after it was asked for); wait for them to be sent, cancel "
                "queued ones (POST /api/v1/commands/{id}/cancel), or let them fail if it cannot be "
                "reached, then send again",
                RETRY_AFTER_S,
                "vehicle_id",
            )
        command = queue(s, vehicle, body, issued_by, self.pose(vehicle.address))
        log.info("vehicle %s: command %s seq %d queued", vehicle.name, command.command, command.seq)
        events.append(
            CommandChanged(
                saved_id(command),
                command.seq,
                CommandState.QUEUED,
                vehicle=vehicle.name,
                command=command.command,
            )
        )
        return command

    def _announce(self, events: list[CommandChanged]) -> None:
        """What was queued (and superseded) on the bus once committed, then the link woken to send it."""
        for event in events:
            self.bus.publish(event)
        self.wake()

    # --- what the link asks ---------------------------------------------------------------------

    def next_to_send(self, vehicle_id: int, confirm_deadline: float) -> CommandRecord | None:
        """The oldest queued or sent command; else the vehicle's latest if it was acknowledged but not
        confirmed by a check-point since before ``confirm_deadline``. Only the latest: re-sending an older
        one could run it after a newer one."""
        with reading(self.db) as s:
            pending = repo.oldest_pending(s, vehicle_id)
            if pending is not None:
                return pending
            latest = repo.latest(s, vehicle_id)
        if (
            latest is not None
            and latest.status == CommandState.ACKNOWLEDGED
            and latest.updated_at < confirm_deadline
        ):
            log.debug(  # asked again every tick until it is sent: the sender logs the attempt
                "vehicle %d: command seq %d acknowledged but never confirmed: sending again",
                vehicle_id,
                latest.seq,
            )
            return latest
        return None

    def demand(self, vehicle_id: int) -> tuple[bool, bool]:
        """What the MAC's schedule weighs: whether a command waits for the link, and whether the vehicle's
        latest is in flight (sent, acknowledged or executing: the operator waits for its check-point)."""
        with reading(self.db) as s:
            latest = repo.latest(s, vehicle_id)
            return repo.oldest_pending(
                s, vehicle_id
            ) is not None, latest is not None and latest.status in IN_FLIGHT

    def frame(self, command: CommandRecord) -> bytes | None:
        """The command signed now for its vehicle (``sign``), for a transmission; None if an operator
        cancelled it meanwhile (it must not go). From here a cancel is refused. A center's processes share
        the store, which decides (the frame kept with the command, ``repo.claim``); a single shore's one
        process decides under its own lock, so that a transmission never waits for the store's writer."""
        with reading(self.db) as s:
            frame = sign(command, vehicles.get(s, command.vehicle_id))
        if self.withdrawable:
            with writing(self.db) as s:
                if not repo.claim(s, command.id, frame):
                    return None
                s.commit()
            return frame
        with self._claims:
            with reading(self.db) as s:
                current = repo.get(s, command.id)
            if current is None or current.status == CommandState.CANCELLED:
                return None
            self._signed.add(saved_id(command))
        return frame

    def cancel(self, command_id: int, by: str) -> CommandRecord:
        """An operator (``by``) takes back a queued command: never signed, it ends ``cancelled`` and is
        never sent; at a center, one a gateway holds (signed, no attempt reported) is ``cancelling``: the
        dispatcher withdraws it, and the gateway's word ends it (``cancelled`` if it had not sent it, else
        it goes on as sent). ``Conflict`` (409) when it lost the race with a transmission: on the air, or
        past queued; it goes on as sent."""
        with self._claims, writing(self.db) as s:
            command = repo.get(s, command_id)
            if command is None:
                raise NotFound(f"no command {command_id}", "command_id")
            if command_id not in self._signed and repo.cancel(s, command_id, by):
                status, detail = CommandState.CANCELLED, f"by {by}"
            elif self.withdrawable and command.status == CommandState.QUEUED:
                status, detail = CommandState.CANCELLING, f"by {by}: withdrawn from the gateway that holds it"
                advance(s, command, status, detail, origin=Origin(StepSource.OPERATOR, by))
            else:
                raise Conflict(_uncancellable(command), "command_id")
            s.commit()
            command = repo.get(s, command_id)
        assert command is not None
        log.info("command %d (seq %d) %s by %s", command_id, command.seq, status, by)
        self.bus.publish(CommandChanged(command_id, command.seq, status, detail=detail))
        return command

    def cancelling(self) -> list[CommandRecord]:
        """The commands whose cancel waits for a gateway's word."""
        with reading(self.db) as s:
            return repo.with_status(s, CommandState.CANCELLING)

    def unanswered(self, command_id: int | None) -> int:
        """Attempts since the command was last acknowledged: a command sent again because no check-point
        confirmed it gets its own round of attempts, not what is left of the first round's."""
        with reading(self.db) as s:
            steps = repo.statuses(s, command_id)
        if CommandState.ACKNOWLEDGED in steps:
            steps = steps[len(steps) - steps[::-1].index(CommandState.ACKNOWLEDGED) :]
        return sum(step == CommandState.SENT for step in steps)

    def record(
        self,
        command: CommandRecord,
        status: CommandState,
        detail: str = "",
        reason: str | None = None,
        at: float | None = None,
        **extra: int | bytes,
    ) -> bool:
        """What the single shore's own modem said of a command (``said``)."""
        return self.said(MODEM, command, status, detail, reason, at, **extra)

    def said(
        self,
        origin: Origin,
        command: CommandRecord,
        status: CommandState,
        detail: str = "",
        reason: str | None = None,
        at: float | None = None,
        **extra: int | bytes,
    ) -> bool:
        """What the link said of a command (``origin``: the shore's modem, a gateway, the shore itself),
        if the lifecycle allows it (a check-point may already have said executing / executed / refused,
        which a late ACK must not undo); published if it moved. ``at``: when it happened (default now);
        ``extra``: column values (attempts, frame)."""
        with writing(self.db) as s:
            current = repo.get(s, command.id)
            if current is None or not advance(
                s, current, status, detail, reason, None, at, origin=origin, **extra
            ):
                return False
            s.commit()
        self._signed.discard(saved_id(command))  # its attempt recorded: its status says the rest
        self.bus.publish(CommandChanged(saved_id(command), command.seq, status, detail=detail))
        return True

    def not_started(self, vehicle_id: int) -> list[CommandRecord]:
        """The vehicle's commands it has not said it runs, oldest first: where it will go next."""
        with reading(self.db) as s:
            return repo.not_started(s, vehicle_id)

    def pending(self, vehicle_id: int) -> int:
        """How many of the vehicle's commands wait for the link."""
        with reading(self.db) as s:
            return repo.pending_count(s, vehicle_id)

    # --- reads ------------------------------------------------------------------------------------

    def get(self, command_id: int) -> tuple[CommandRecord, list[CommandStep]]:
        with reading(self.db) as s:
            command = repo.get(s, command_id)
            if command is None:
                raise NotFound(f"no command {command_id}", "command_id")
            return command, repo.steps(s, [command_id]).get(command_id, [])

    def page(
        self, vehicle_id: int | None, limit: int, offset: int = 0, history: bool = False
    ) -> list[tuple[CommandRecord, list[CommandStep] | None]]:
        """A vehicle's commands (every vehicle's if None), newest first, with their histories if asked."""
        with reading(self.db) as s:
            if vehicle_id is not None:
                vehicles.get(s, vehicle_id)
            rows = repo.page(s, vehicle_id, limit, offset)
            steps = repo.steps(s, [saved_id(c) for c in rows]) if history else {}
        return [(c, steps.get(saved_id(c), []) if history else None) for c in rows]
