"""The command tables' SQL: the only place that reads or writes ``command`` and ``commandevent``."""

from __future__ import annotations

from sqlalchemy import func, insert, update
from sqlmodel import Session, col, select

from server.commands.lifecycle import NOT_STARTED, PENDING
from server.commands.models import CommandRecord, CommandState, CommandStep, Origin, StepSource
from server.core.db import now, saved_id


def add(s: Session, command: CommandRecord) -> CommandRecord:
    """Insert a queued command with its first history step."""
    s.add(command)
    s.flush()
    s.add(
        CommandStep(
            command_id=saved_id(command), status=CommandState.QUEUED, detail="",
            source=StepSource.OPERATOR, via=command.issued_by,
        )
    )  # fmt: skip
    return command


def get(s: Session, command_id: int | None) -> CommandRecord | None:
    return s.get(CommandRecord, command_id)


def by_seq(s: Session, vehicle_id: int, seq: int) -> CommandRecord | None:
    return s.exec(
        select(CommandRecord).where(CommandRecord.vehicle_id == vehicle_id, CommandRecord.seq == seq)
    ).first()


def move(
    s: Session,
    command_id: int | None,
    status: CommandState,
    detail: str,
    report: dict | None,
    values: dict[str, object],
    origin: Origin,
    at: float | None = None,
) -> None:
    """Set the command's status (and ``values``) and add the history step, dated ``at`` (default now),
    saying who said it (``origin``)."""
    at = now() if at is None else at
    s.execute(
        update(CommandRecord)
        .where(col(CommandRecord.id) == command_id)
        .values(status=status.value, updated_at=now(), **values)
    )
    s.execute(
        insert(CommandStep).values(
            command_id=command_id,
            status=status.value,
            detail=detail,
            at=at,
            report=report,
            source=origin.source.value,
            via=origin.via,
        )  # fmt: skip
    )


def claim(s: Session, command_id: int | None, frame: bytes) -> bool:
    """The command's frame, signed for a transmission, kept with it unless it was cancelled: whether it
    may go. One conditional statement, so a cancel and a transmission cannot both win."""
    query = (
        update(CommandRecord)
        .where(col(CommandRecord.id) == command_id, col(CommandRecord.status) != CommandState.CANCELLED.value)
        .values(frame=frame)
    )
    return bool(s.execute(query).rowcount)  # type: ignore[attr-defined]


def cancel(s: Session, command_id: int | None, by: str) -> bool:
    """Cancel the command if it is queued and was never signed for a transmission (no frame kept):
    whether it was. One conditional statement (see ``claim``); the caller commits."""
    query = (
        update(CommandRecord)
        .where(
            col(CommandRecord.id) == command_id,
            col(CommandRecord.status) == CommandState.QUEUED.value,
            func.length(col(CommandRecord.frame)) == 0,
        )
        .values(status=CommandState.CANCELLED.value, updated_at=now())
    )
    if not s.execute(query).rowcount:  # type: ignore[attr-defined]
        return False
    s.execute(
        insert(CommandStep).values(
            command_id=command_id, status=CommandState.CANCELLED.value, detail=f"by {by}", at=now(),
            source=StepSource.OPERATOR.value, via=by,
        )
    )  # fmt: skip
    return True


def with_status(s: Session, status: CommandState) -> list[CommandRecord]:
    return list(
        s.exec(
            select(CommandRecord).where(CommandRecord.status == status.value).order_by(col(CommandRecord.id))
        )
    )


def queued(s: Session, vehicle_id: int) -> list[CommandRecord]:
    """The vehicle's commands not yet sent once, oldest first."""
    query = select(CommandRecord).where(
        CommandRecord.vehicle_id == vehicle_id, CommandRecord.status == CommandState.QUEUED
    )
    return list(s.exec(query.order_by(col(CommandRecord.id))))


def oldest_pending(s: Session, vehicle_id: int) -> CommandRecord | None:
    query = select(CommandRecord).where(
        CommandRecord.vehicle_id == vehicle_id, col(CommandRecord.status).in_(PENDING)
    )
    return s.exec(query.order_by(col(CommandRecord.id))).first()


def latest(s: Session, vehicle_id: int) -> CommandRecord | None:
    query = select(CommandRecord).where(CommandRecord.vehicle_id == vehicle_id)
    return s.exec(query.order_by(col(CommandRecord.id).desc())).first()


def pending_count(s: Session, vehicle_id: int) -> int:
    query = select(CommandRecord.id).where(
        CommandRecord.vehicle_id == vehicle_id, col(CommandRecord.status).in_(PENDING)
    )
    return len(s.exec(query).all())


def executing_before(s: Session, command: CommandRecord) -> list[CommandRecord]:
    """The vehicle's older commands still executing."""
    query = select(CommandRecord).where(
        CommandRecord.vehicle_id == command.vehicle_id,
        col(CommandRecord.id) < saved_id(command),
        CommandRecord.status == CommandState.EXECUTING,
    )
    return list(s.exec(query))


def page(s: Session, vehicle_id: int | None, limit: int, offset: int = 0) -> list[CommandRecord]:
    """Newest first; every vehicle's when ``vehicle_id`` is None."""
    query = select(CommandRecord).order_by(col(CommandRecord.id).desc())
    if vehicle_id is not None:
        query = query.where(CommandRecord.vehicle_id == vehicle_id)
    return list(s.exec(query.offset(offset).limit(limit)))


def steps(s: Session, command_ids: list[int]) -> dict[int, list[CommandStep]]:
    """The history of each command, oldest step first (one query for a whole page of commands)."""
    out: dict[int, list[CommandStep]] = {}
    if not command_ids:
        return out
    query = (
        select(CommandStep).where(col(CommandStep.command_id).in_(command_ids)).order_by(col(CommandStep.id))
    )
    for step in s.exec(query):
        out.setdefault(step.command_id, []).append(step)
    return out


def first_sent_at(s: Session, command_id: int | None) -> float | None:
    query = select(CommandStep.at).where(
        CommandStep.command_id == command_id, CommandStep.status == CommandState.SENT
    )
    return s.exec(query.order_by(col(CommandStep.id))).first()


def statuses(s: Session, command_id: int | None) -> list[CommandState]:
    query = (
        select(CommandStep.status).where(CommandStep.command_id == command_id).order_by(col(CommandStep.id))
    )
    return [CommandState(x) for x in s.exec(query).all()]


def not_started(s: Session, vehicle_id: int) -> list[CommandRecord]:
    """The vehicle's commands it has not said it runs (queued, sent, acknowledged), oldest first."""
    query = select(CommandRecord).where(
        CommandRecord.vehicle_id == vehicle_id, col(CommandRecord.status).in_(NOT_STARTED)
    )
    return list(s.exec(query.order_by(col(CommandRecord.id))))
