"""The mission table's SQL."""

from __future__ import annotations

from sqlalchemy import update
from sqlmodel import Session, col, select

from server.missions.models import Mission, MissionStatus


def add(s: Session, mission: Mission) -> Mission:
    s.add(mission)
    s.commit()
    return mission


def get(s: Session, mission_id: int) -> Mission | None:
    return s.get(Mission, mission_id)


def of_vehicle(s: Session, vehicle_id: int) -> list[Mission]:
    return list(s.exec(select(Mission).where(Mission.vehicle_id == vehicle_id).order_by(col(Mission.id))))


def numbered(s: Session, vehicle_id: int, number: int) -> Mission | None:
    """The newest mission the vehicle knows by ``number``."""
    query = select(Mission).where(Mission.vehicle_id == vehicle_id, Mission.number == number)
    return s.exec(query.order_by(col(Mission.id).desc())).first()


def started(s: Session, vehicle_id: int) -> Mission | None:
    """The vehicle's newest started mission."""
    query = select(Mission).where(Mission.vehicle_id == vehicle_id, Mission.status == MissionStatus.STARTED)
    return s.exec(query.order_by(col(Mission.id).desc())).first()


def set_status(s: Session, mission_id: int, status: MissionStatus) -> None:
    s.execute(update(Mission).where(col(Mission.id) == mission_id).values(status=status.value))
