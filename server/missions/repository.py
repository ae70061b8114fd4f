"""The mission tables' SQL: missions, team missions and their proposals."""

from __future__ import annotations

from sqlalchemy import delete, update
from sqlmodel import Session, col, select

from server.missions.models import (
    Mission,
    MissionStatus,
    ProposalStatus,
    TeamMission,
    TeamProposal,
    TeamStatus,
)


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


def add_team(s: Session, team: TeamMission) -> TeamMission:
    s.add(team)
    s.commit()
    s.refresh(team)
    return team


def team(s: Session, team_id: int) -> TeamMission | None:
    return s.get(TeamMission, team_id)


def teams(s: Session) -> list[TeamMission]:
    return list(s.exec(select(TeamMission).order_by(col(TeamMission.id).desc())))


def started_teams(s: Session) -> list[TeamMission]:
    return list(s.exec(select(TeamMission).where(TeamMission.status == TeamStatus.STARTED)))


def save_team(s: Session, team_id: int, members: list, status: TeamStatus) -> None:
    """A team's members (a new list: the JSON column is replaced whole) and status."""
    s.execute(
        update(TeamMission).where(col(TeamMission.id) == team_id).values(members=members, status=status.value)
    )


def refuse_team(s: Session, team_id: int, detail: str) -> None:
    """The team's start was refused: why."""
    s.execute(
        update(TeamMission)
        .where(col(TeamMission.id) == team_id)
        .values(status=TeamStatus.REFUSED.value, detail=detail[:1024])
    )


def delete_team(s: Session, team_id: int) -> None:
    """The team mission and its proposals."""
    s.execute(delete(TeamProposal).where(col(TeamProposal.team_id) == team_id))
    s.execute(delete(TeamMission).where(col(TeamMission.id) == team_id))


def add_proposal(s: Session, proposal: TeamProposal) -> TeamProposal:
    s.add(proposal)
    s.commit()
    s.refresh(proposal)
    return proposal


def proposal(s: Session, proposal_id: int) -> TeamProposal | None:
    return s.get(TeamProposal, proposal_id)


def proposals(s: Session, team_id: int | None, status: ProposalStatus | None) -> list[TeamProposal]:
    query = select(TeamProposal)
    if team_id is not None:
        query = query.where(TeamProposal.team_id == team_id)
    if status is not None:
        query = query.where(TeamProposal.status == status)
    return list(s.exec(query.order_by(col(TeamProposal.id).desc())))


def proposal_by(s: Session, team_id: int, finder: str) -> TeamProposal | None:
    """The team's proposal prompted by ``finder`` that is still open or was applied."""
    query = select(TeamProposal).where(
        TeamProposal.team_id == team_id,
        TeamProposal.finder == finder,
        col(TeamProposal.status) != ProposalStatus.DISMISSED,
    )
    return s.exec(query).first()


def decide(s: Session, proposal_id: int, status: ProposalStatus, by: str, detail: str) -> None:
    s.execute(
        update(TeamProposal)
        .where(col(TeamProposal.id) == proposal_id)
        .values(status=status.value, decided_by=by, detail=detail)
    )
