"""Missions: recorded on the shore, started and aborted by a control packet naming their number; team
missions split among vehicles and run leg by leg, and the shore's proposals to restructure them."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from server.api.deps import Id, MissionsDep, TeamsDep, Writer, require_read, require_write
from server.commands.schemas import CommandOut
from server.core import errors
from server.core.errors import Conflict
from server.missions.models import Mission, ProposalStatus, TeamMission, TeamProposal
from server.missions.schemas import MissionIn, MissionOut, ProposalOut, TeamIn, TeamOut

router = APIRouter(prefix="/api/v1", tags=["missions"])


def _out(mission: Mission) -> MissionOut:
    return MissionOut.model_validate(mission, from_attributes=True)


@router.post(
    "/vehicles/{vehicle_id}/missions",
    status_code=201,
    response_model=MissionOut,
    dependencies=[Depends(require_write)],
)
def create_mission(vehicle_id: Id, body: MissionIn, missions: MissionsDep) -> MissionOut:
    """Record a mission (the same JSON as the agent's mission file: the vehicle holds the plan; the
    link only says which mission number to start)."""
    return _out(missions.create(vehicle_id, body))


@router.get(
    "/vehicles/{vehicle_id}/missions", response_model=list[MissionOut], dependencies=[Depends(require_read)]
)
def list_missions(vehicle_id: Id, missions: MissionsDep) -> list[MissionOut]:
    return [_out(m) for m in missions.of_vehicle(vehicle_id)]


@router.post("/missions/{mission_id}/start", status_code=202, response_model=CommandOut)
def start_mission(mission_id: Id, missions: MissionsDep, actor: Writer) -> CommandOut:
    return CommandOut.model_validate(missions.start(mission_id, actor.name), from_attributes=True)


@router.post("/missions/{mission_id}/abort", status_code=202, response_model=CommandOut)
def abort_mission(mission_id: Id, missions: MissionsDep, actor: Writer) -> CommandOut:
    return CommandOut.model_validate(missions.abort(mission_id, actor.name), from_attributes=True)


# --- team missions (server.missions.teams; docs/missions.md) ------------------------------------------


def _team(team: TeamMission, teams: TeamsDep) -> TeamOut:
    fields = {name: getattr(team, name) for name in TeamOut.model_fields if name != "link"}
    return TeamOut.model_validate({**fields, "link": teams.cost(team)})


def _proposal(proposal: TeamProposal) -> ProposalOut:
    return ProposalOut.model_validate(proposal, from_attributes=True)


@router.post("/teams", status_code=201, response_model=TeamOut, dependencies=[Depends(require_write)])
def create_team(body: TeamIn, teams: TeamsDep) -> TeamOut:
    """Split a survey area among named vehicles, as lanes of a lawnmower (one contiguous set each, west
    to east in the order given). 422 with the reason for an unknown vehicle, an empty or crossed area,
    fewer lanes than vehicles, or lanes outside a vehicle's limits or a control packet's fields."""
    return _team(teams.create(body), teams)


@router.get("/teams", response_model=list[TeamOut], dependencies=[Depends(require_read)])
def list_teams(teams: TeamsDep) -> list[TeamOut]:
    return [_team(t, teams) for t in teams.every()]


@router.get("/teams/{team_id}", response_model=TeamOut, dependencies=[Depends(require_read)])
def get_team(team_id: Id, teams: TeamsDep) -> TeamOut:
    """The team mission with each vehicle's waypoints, current leg (its command) and state."""
    return _team(teams.get(team_id), teams)


@router.post(
    "/teams/{team_id}/start", status_code=202, response_model=TeamOut, responses=errors.responses(Conflict)
)
def start_team(team_id: Id, teams: TeamsDep, actor: Writer) -> TeamOut:
    """Take each vehicle over (``abort_mission``, and ``set_param`` of its lost-link action if the team
    names another); its first leg follows when it reports it stopped. Refused (422, the team then
    ``refused`` with the reason in ``detail``) if any vehicle's plan (where it may stop, its lanes, its
    lost-link action) would come closer than the separation to another's."""
    return _team(teams.start(team_id, actor.name), teams)


@router.delete(
    "/teams/{team_id}",
    status_code=204,
    dependencies=[Depends(require_write)],
    responses=errors.responses(Conflict),
)
def delete_team(team_id: Id, teams: TeamsDep) -> None:
    """Delete a team mission that is not running (created, refused, aborted or finished) with its
    proposals; 409 while it runs (abort it first)."""
    teams.delete(team_id)


@router.post(
    "/teams/{team_id}/abort", status_code=202, response_model=TeamOut, responses=errors.responses(Conflict)
)
def abort_team(team_id: Id, teams: TeamsDep, actor: Writer) -> TeamOut:
    """Queue no more legs: each vehicle finishes the leg it has and holds."""
    return _team(teams.abort(team_id, actor.name), teams)


@router.get(
    "/teams/{team_id}/proposals", response_model=list[ProposalOut], dependencies=[Depends(require_read)]
)
def team_proposals(team_id: Id, teams: TeamsDep) -> list[ProposalOut]:
    return [_proposal(p) for p in teams.proposals(team_id)]


@router.get("/proposals", response_model=list[ProposalOut], dependencies=[Depends(require_read)])
def proposals(teams: TeamsDep, status: ProposalStatus | None = None) -> list[ProposalOut]:
    """The shore's proposals of new work (newest first): when a team vehicle reports a time-sensitive
    anomaly, the restructuring rule sends others near it (settings ``restructure_*``)."""
    return [_proposal(p) for p in teams.proposals(None, status)]


@router.post(
    "/proposals/{proposal_id}/confirm",
    status_code=202,
    response_model=ProposalOut,
    responses=errors.responses(Conflict),
)
def confirm_proposal(proposal_id: Id, teams: TeamsDep, actor: Writer) -> ProposalOut:
    """Apply the proposal: each helper's leg to its new waypoint is queued (checked like any command)."""
    return _proposal(teams.confirm(proposal_id, actor.name))


@router.post(
    "/proposals/{proposal_id}/dismiss", response_model=ProposalOut, responses=errors.responses(Conflict)
)
def dismiss_proposal(proposal_id: Id, teams: TeamsDep, actor: Writer) -> ProposalOut:
    return _proposal(teams.dismiss(proposal_id, actor.name))
