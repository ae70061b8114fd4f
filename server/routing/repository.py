"""The routing's SQL: gateways seen, what each gateway heard of each vehicle, assignments, dispatches."""

from __future__ import annotations

from typing import Any

from sqlalchemy import ColumnElement, case, func
from sqlmodel import Session, col, select

from server.backhaul.models import RelayedFrame
from server.commands.models import CommandRecord, CommandState
from server.core.db import now
from server.routing.models import Assignment, Dispatch, DispatchState, GatewayRecord
from server.telemetry.models import Packet, PacketTrust


def touch_gateway(s: Session, name: str, at: float) -> None:
    row = s.get(GatewayRecord, name)
    if row is None:
        s.add(GatewayRecord(name=name, first_seen=at, last_seen=at))
    elif at > row.last_seen:
        row.last_seen = at
        s.add(row)
    s.flush()


def count_foreign_report(s: Session, name: str) -> None:
    """Gateway ``name`` reported a command that went through another: counted on its record."""
    row = s.get(GatewayRecord, name)
    if row is not None:
        row.foreign_reports += 1
        s.add(row)
        s.flush()


def set_faulty(s: Session, name: str, why: str, at: float) -> None:
    row = s.get(GatewayRecord, name)
    if row is not None:
        row.faulty, row.faulty_at = why[:256], at
        s.add(row)
        s.flush()


def save_gateway(s: Session, row: GatewayRecord) -> None:
    s.add(row)
    s.flush()


def frames_by_gateway(s: Session) -> dict[str, int]:
    """The relayed frames' records kept, by the gateway that heard them (each copy counts)."""
    query = select(RelayedFrame.gateway, func.count()).group_by(col(RelayedFrame.gateway))
    return {str(g): int(n) for g, n in s.exec(query)}


def gateways(s: Session) -> list[GatewayRecord]:
    return list(s.exec(select(GatewayRecord).order_by(col(GatewayRecord.name))).all())


def gateway(s: Session, name: str) -> GatewayRecord | None:
    return s.get(GatewayRecord, name)


def hearing(s: Session, since: float, cap: float) -> list[tuple[int, str, int, float | None]]:
    """Per source address and gateway, the verified frames heard since ``since`` (their clocks) and their
    mean SNR, each capped at ``cap`` dB: (src, gateway, frames, mean snr_in)."""
    snr = case((col(RelayedFrame.snr_in) > cap, cap), else_=col(RelayedFrame.snr_in))
    query = (
        select(RelayedFrame.src, RelayedFrame.gateway, func.count(), func.avg(snr))
        .where(col(RelayedFrame.at) >= since, col(RelayedFrame.frame_id).is_not(None), _verified())
        .group_by(col(RelayedFrame.src), col(RelayedFrame.gateway))
    )
    return [
        (int(src), str(g), int(n), None if snr is None else float(snr)) for src, g, n, snr in s.exec(query)
    ]


def frames_sent(s: Session, since: float) -> dict[int, int]:
    """Per source address, its distinct verified frames any gateway heard since ``since``."""
    query = (
        select(RelayedFrame.src, func.count(func.distinct(RelayedFrame.frame_id)))
        .where(col(RelayedFrame.at) >= since, col(RelayedFrame.frame_id).is_not(None), _verified())
        .group_by(col(RelayedFrame.src))
    )
    return {int(src): int(n) for src, n in s.exec(query)}


def _verified() -> ColumnElement[bool]:
    return col(RelayedFrame.verified).is_(True)


def heard_through(s: Session, src: int, gateway: str, since: float) -> bool:
    """A verified frame of ``src`` came through ``gateway`` since ``since`` (the center's clock)."""
    query = select(RelayedFrame.id).where(
        RelayedFrame.src == src, RelayedFrame.gateway == gateway, col(RelayedFrame.received_at) >= since,
        _verified(),
    )  # fmt: skip
    return s.exec(query.limit(1)).first() is not None


def acked_since(s: Session, since: float) -> list[tuple[Dispatch, CommandRecord]]:
    """The dispatches acked since ``since`` (the center's clock) whose commands no check-point has
    moved on from acknowledged, with their commands."""
    query = select(Dispatch, CommandRecord).where(
        Dispatch.command_id == CommandRecord.id, Dispatch.state == DispatchState.ACKED,
        col(Dispatch.updated_at) >= since, CommandRecord.status == CommandState.ACKNOWLEDGED,
    )  # fmt: skip
    return [(d, c) for d, c in s.exec(query.order_by(col(Dispatch.updated_at))).all()]


def held_since(s: Session, before: float) -> list[tuple[Dispatch, CommandRecord]]:
    """The dispatches a gateway reported stored or sent, not final, made before ``before``."""
    query = select(Dispatch, CommandRecord).where(
        Dispatch.command_id == CommandRecord.id,
        col(Dispatch.state).in_([DispatchState.STORED, DispatchState.SENT]),
        col(Dispatch.created_at) < before,
    )  # fmt: skip
    return [(d, c) for d, c in s.exec(query).all()]


def reported_since(s: Session, gateway: str, since: float) -> bool:
    """A dispatch through ``gateway`` moved since ``since`` (its report, or the center's verdict)."""
    query = select(Dispatch.id).where(Dispatch.gateway == gateway, col(Dispatch.updated_at) >= since)
    return s.exec(query.limit(1)).first() is not None


def checkpoints(s: Session, vehicle_id: int, since: float) -> list[dict[str, Any]]:
    """The bodies of the vehicle's verified check-points heard since ``since`` (their frames' clocks)."""
    query = select(Packet.body).where(
        Packet.vehicle_id == vehicle_id, Packet.type == "checkpoint", Packet.auth == PacketTrust.VERIFIED,
        col(Packet.at) >= since,
    )  # fmt: skip
    return [dict(body) for body in s.exec(query).all()]


def assignments(s: Session) -> dict[int, Assignment]:
    return {a.vehicle_id: a for a in s.exec(select(Assignment)).all()}


def save_assignment(s: Session, row: Assignment) -> None:
    s.merge(row)
    s.flush()


def dispatches(s: Session, command_id: int) -> list[Dispatch]:
    query = select(Dispatch).where(Dispatch.command_id == command_id).order_by(col(Dispatch.created_at))
    return list(s.exec(query).all())


def dispatch(s: Session, dispatch_id: str) -> Dispatch | None:
    return s.get(Dispatch, dispatch_id)


def add_dispatch(s: Session, row: Dispatch) -> None:
    s.add(row)
    s.flush()


def set_dispatch(s: Session, row: Dispatch, state: DispatchState) -> None:
    row.state, row.updated_at = state, now()
    s.add(row)
    s.flush()
