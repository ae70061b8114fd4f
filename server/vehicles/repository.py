"""The vehicle table's SQL."""

from __future__ import annotations

from collections.abc import Sequence

from sqlalchemy import update
from sqlmodel import Session, col, select

from server.vehicles.models import Vehicle
from tacit.params import LostAction


def get(s: Session, vehicle_id: int) -> Vehicle | None:
    return s.get(Vehicle, vehicle_id)


def by_name(s: Session, name: str) -> Vehicle | None:
    return s.exec(select(Vehicle).where(Vehicle.name == name)).first()


def by_address(s: Session, address: int) -> Vehicle | None:
    return s.exec(select(Vehicle).where(Vehicle.address == address)).first()


def using_key(s: Session, key_hex: str, other_than: int | None = None) -> Vehicle | None:
    """A vehicle (other than ``other_than``) whose current or previous key is ``key_hex``."""
    query = select(Vehicle).where(
        (col(Vehicle.key_hex) == key_hex) | (col(Vehicle.previous_key_hex) == key_hex)
    )
    if other_than is not None:
        query = query.where(col(Vehicle.id) != other_than)
    return s.exec(query).first()


def every(s: Session) -> list[Vehicle]:
    return list(s.exec(select(Vehicle).order_by(col(Vehicle.id))))


def many(s: Session, vehicle_ids: Sequence[int]) -> dict[int, Vehicle]:
    """The vehicles, by id, in one query."""
    if not vehicle_ids:
        return {}
    rows = s.exec(select(Vehicle).where(col(Vehicle.id).in_(vehicle_ids))).all()
    return {v.id: v for v in rows if v.id is not None}


def save(s: Session, vehicle: Vehicle) -> Vehicle:
    s.add(vehicle)
    s.commit()
    s.refresh(vehicle)
    return vehicle


def take_seq(s: Session, vehicle_id: int) -> int:
    """The vehicle's next command sequence number, taken (persisted: a restart never reuses one)."""
    statement = (
        update(Vehicle)
        .where(col(Vehicle.id) == vehicle_id)
        .values(next_seq=col(Vehicle.next_seq) + 1)
        .returning(col(Vehicle.next_seq))
    )
    return int(s.exec(statement).one()[0]) - 1


def raise_next_seq(s: Session, vehicle_id: int, next_seq: int) -> None:
    """Never issue a sequence number below ``next_seq`` (a number the vehicle has already accepted)."""
    s.execute(
        update(Vehicle)
        .where(col(Vehicle.id) == vehicle_id, col(Vehicle.next_seq) < next_seq)
        .values(next_seq=next_seq)
    )


def confirm_key(s: Session, vehicle_id: int) -> None:
    """The staged rotation is over: the vehicle proved it holds the new key."""
    s.execute(
        update(Vehicle)
        .where(col(Vehicle.id) == vehicle_id)
        .values(previous_key_hex=None, rotation_since=None, next_key_held=False)
    )


def hold_next_key(s: Session, vehicle_id: int, held: bool) -> None:
    """What the vehicle's last check-point signed with its confirmed key said of the staged one."""
    s.execute(update(Vehicle).where(col(Vehicle.id) == vehicle_id).values(next_key_held=held))


def set_lost_action(s: Session, vehicle_id: int, action: LostAction) -> None:
    """The vehicle executed a SET_PARAM of its lost-link action."""
    s.execute(update(Vehicle).where(col(Vehicle.id) == vehicle_id).values(lost_action=action))
