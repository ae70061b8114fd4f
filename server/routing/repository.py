"""The routing's SQL: gateways seen, what each gateway heard of each vehicle, assignments, dispatches."""

from __future__ import annotations

from sqlalchemy import func
from sqlmodel import Session, col, select

from server.backhaul.models import RelayedFrame
from server.core.db import now
from server.routing.models import Assignment, Dispatch, DispatchState, GatewayRecord


def touch_gateway(s: Session, name: str, at: float) -> None:
    row = s.get(GatewayRecord, name)
    if row is None:
        s.add(GatewayRecord(name=name, first_seen=at, last_seen=at))
    elif at > row.last_seen:
        row.last_seen = at
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


def hearing(s: Session, since: float) -> list[tuple[int, str, int, float | None]]:
    """Per source address and gateway, the frames heard since ``since`` (their clocks) and their mean
    SNR: (src, gateway, frames, mean snr_in)."""
    query = (
        select(RelayedFrame.src, RelayedFrame.gateway, func.count(), func.avg(RelayedFrame.snr_in))
        .where(col(RelayedFrame.at) >= since, col(RelayedFrame.frame_id).is_not(None))
        .group_by(col(RelayedFrame.src), col(RelayedFrame.gateway))
    )
    return [
        (int(src), str(g), int(n), None if snr is None else float(snr)) for src, g, n, snr in s.exec(query)
    ]


def frames_sent(s: Session, since: float) -> dict[int, int]:
    """Per source address, its distinct frames any gateway heard since ``since``."""
    query = (
        select(RelayedFrame.src, func.count(func.distinct(RelayedFrame.frame_id)))
        .where(col(RelayedFrame.at) >= since, col(RelayedFrame.frame_id).is_not(None))
        .group_by(col(RelayedFrame.src))
    )
    return {int(src): int(n) for src, n in s.exec(query)}


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
