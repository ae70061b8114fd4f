"""Team missions: a survey area split among vehicles as lanes (``server.missions.plans``), run by the
shore one leg at a time, and restructured when a team vehicle reports a time-sensitive anomaly.

Work reaches a submerged vehicle only as control packets (docs/missions.md): each leg is one MOVE on an
absolute bearing from where the vehicle reported finishing the last leg to the next waypoint, queued
through the command desk (limits and separation checked like any command) when the check-point saying
"executed" arrives. A vehicle holds at the end of each leg (Algorithm 2: commanded, no mission, then
holding) until its next leg comes. A leg refused, failed or replaced by another command stops that
vehicle's part, with the reason; the others go on.
"""

from __future__ import annotations

import copy
import itertools
import logging
import math
import threading
from typing import Any, TypeGuard

from sqlalchemy import Engine

from server.commands.models import CommandState
from server.commands.schemas import CommandIn
from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.db import reading, saved_id, writing
from server.core.errors import ApiError, Conflict, NotFound, Refused
from server.core.events import Bus, CommandChanged, Event, PacketHeard, TeamChanged
from server.missions import plans
from server.missions import repository as repo
from server.missions.models import (
    MemberState,
    ProposalStatus,
    TeamMission,
    TeamProposal,
    TeamStatus,
)
from server.missions.schemas import TeamIn
from server.safety.geometry import Point
from server.safety.paths import Planned, Unplaced
from server.safety.service import Separation
from server.telemetry.models import PacketTrust
from server.vehicles.models import Vehicle
from server.vehicles.service import Vehicles
from tacit.navigation import Pose, distance_and_angle
from tacit.packets import Command, ControlPacket, Priority, Stream
from tacit.params import LostAction, Param

log = logging.getLogger("tacit.server.teams")
ARRIVE_M = 2.0  # m: a leg that ends farther from its waypoint is run once more (``off_target``)
ENDS = {CommandState.REFUSED, CommandState.FAILED, CommandState.SUPERSEDED}  # a leg that will not run


def leg(start: Point, end: Point) -> CommandIn:
    """The control packet of one leg: a MOVE on a true bearing, with the depth change; refused (422)
    if the leg does not fit the packet's fields (``ControlPacket.FIELDS``)."""
    distance, bearing = distance_and_angle(start[0], start[1], 0.0, end[0], end[1], absolute=True)
    change = end[2] - start[2]
    for name, value in (("distance", distance), ("depth", change)):
        f = ControlPacket.field(name)
        if not f.lo <= value <= f.hi:
            raise Refused(
                f"a leg's {name} of {value:.1f} {f.unit} is outside a control packet's {f.lo} .. {f.hi}",
                "area",
            )
    return CommandIn(
        command="move",
        distance=round(distance, 1),
        angle=round(bearing, 2),
        depth=round(change, 2),
        absolute_angle=True,
    )


def takeover(member: dict[str, Any], vehicle: Vehicle) -> list[CommandIn]:
    """What the team sends a vehicle first: ``abort_mission`` (it holds where it is and drops a mission of
    its own, which it would otherwise go back to between legs, and whose time could run out mid-survey);
    then its lost-link action if the team names another than the vehicle's (``set_param``; after the
    abort, which would supersede it)."""
    bodies = [CommandIn(command="abort_mission")]
    action = LostAction(member["lost_action"])
    if action != vehicle.lost_action:
        bodies.append(
            CommandIn(command="set_param", param_id=int(Param.LOST_ACTION), param_value=float(action.code))
        )
    return bodies


def check_fit(vehicle: Vehicle, waypoints: list[Point]) -> None:
    """Refuse (422) lanes the vehicle cannot run: a waypoint or a leg outside its limits (the geofence is
    around its home: the limits see the waypoints relative to it)."""
    limits = vehicle.limits()
    waypoints = [(n - vehicle.home_north, e - vehicle.home_east, d) for n, e, d in waypoints]
    refused = limits.check_target(*waypoints[0])
    if refused is not None:
        raise Refused(f"{vehicle.name}'s first lane starts where it may not go: {refused.message}", "area")
    for k, (a, b) in enumerate(itertools.pairwise(waypoints), start=1):
        body = leg(a, b)
        pose = Pose(a[0], a[1], a[2], 0.0)
        refused = limits.check(Command.MOVE, body.distance, body.angle, body.depth, 0.0, True, pose)
        if refused is not None:
            raise Refused(f"{vehicle.name}'s leg {k} does not fit its limits: {refused.message}", "area")


def link_cost(team: TeamMission, settings: Settings) -> dict[str, Any]:
    """The team mission's legs (the first one to each vehicle's lanes included) and their channel time."""
    per = plans.LegCost.at(settings.default_range, settings.sound_speed)
    legs = sum(len(m["waypoints"]) for m in team.members)
    return {
        "legs": legs,
        "bits_per_leg_down": per.bits_down,
        "bits_per_leg_up": per.bits_up,
        "channel_s_per_leg": round(per.channel_s, 2),
        "channel_s": round(legs * per.channel_s, 1),
    }


def off_target(member: dict[str, Any], report: dict[str, Any] | None) -> bool:
    """Whether the vehicle reported ending its leg more than ``ARRIVE_M`` from the waypoint it was sent
    to, for the first time at that waypoint. A leg is a relative move computed from where the shore
    thought the vehicle was (its prediction, when a proposal redirects it mid-leg): the error shows at
    the end, and one more leg from the reported position corrects it."""
    if not report or member.get("corrected") == member["next"] or "north" not in report:
        return False
    aim = member["waypoints"][member["next"]]
    return math.dist((report["north"], report["east"]), aim[:2]) > ARRIVE_M


def is_water_anomaly(event: Event) -> TypeGuard[PacketHeard]:
    """A priority packet the vehicle marked time-sensitive for its water samples (the warm plume: the
    agent flags the sample, and the packet's header names the environmental stream), whose tag passed.
    A packet time-sensitive for a large kinematic surprise (a manoeuvre) is no anomaly of the water."""
    return (
        isinstance(event, PacketHeard)
        and event.type == "priority"
        and event.priority == Priority.TIME_SENSITIVE
        and event.body.get("stream") == Stream.ENVIRONMENTAL.name.lower()
        and event.auth != PacketTrust.FORGED.value
    )


class Teams:
    def __init__(
        self,
        settings: Settings,
        db: Engine,
        desk: CommandDesk,
        vehicles: Vehicles,
        separation: Separation,
        bus: Bus,
    ) -> None:
        self.settings = settings
        self.db = db
        self.desk = desk
        self.vehicles = vehicles
        self.separation = separation
        self.bus = bus
        self._lock = threading.Lock()  # a team's members are read, changed and written under it

    # --- the operator's actions --------------------------------------------------------------------

    def create(self, body: TeamIn) -> TeamMission:
        """Split the area into lanes, one contiguous set per vehicle (west to east, in the order given),
        and check each vehicle can run its lanes; 422 with the reason otherwise."""
        chosen = [self._named(v.vehicle) for v in body.vehicles]
        if len({saved_id(v) for v in chosen}) < len(chosen):
            raise Refused("a vehicle is named twice", "vehicles")
        if len(chosen) > 1 and body.spacing < self.settings.separation:
            raise Refused(
                f"lanes {body.spacing:g} m apart would bring neighbouring vehicles closer than the "
                f"{self.settings.separation:g} m separation: space them at least that far",
                "spacing",
            )
        try:
            groups = plans.split(plans.lanes(body.area.corners(), body.spacing), len(chosen))
        except plans.PlanError as exc:
            raise Refused(str(exc), "area") from None
        members = []
        for vehicle, spec, group in zip(chosen, body.vehicles, groups, strict=True):
            waypoints = plans.sweep(group, body.depth)
            check_fit(vehicle, waypoints)
            members.append(
                {
                    "vehicle_id": saved_id(vehicle),
                    "name": vehicle.name,
                    "lost_action": spec.lost_action or vehicle.lost_action,
                    "home": list(vehicle.home),
                    "waypoints": [list(p) for p in waypoints],
                    "next": 0,
                    "command_id": None,
                    "state": MemberState.WAITING.value,
                    "reason": "",
                }
            )
        team = TeamMission(
            name=body.name,
            area=[list(p) for p in body.area.corners()],
            spacing=body.spacing,
            depth=body.depth,
            members=members,
        )
        with writing(self.db) as s:
            return repo.add_team(s, team)

    def start(self, team_id: int, issued_by: str) -> TeamMission:
        """Take each vehicle over (``takeover``) and check every vehicle's whole plan (where it may be when
        it stops, its lanes, its lost-link action) against the others'; then queue the takeovers: each
        vehicle's first leg follows when it reports it stopped. A refused start leaves the team
        ``refused`` with the reason (it may be started again, or deleted)."""
        with self._lock:
            team = self.get(team_id)
            if team.status not in (TeamStatus.CREATED, TeamStatus.REFUSED):
                raise Conflict(f"team mission {team_id} is {team.status}", "team_id")
            members = copy.deepcopy(team.members)
            try:
                self._check_free(members)
                self._check_start(members)
                for member in members:
                    vehicle = self.vehicles.get(member["vehicle_id"])
                    queued = [
                        self.desk.submit(saved_id(vehicle), b, issued_by) for b in takeover(member, vehicle)
                    ]
                    member.update(
                        command_id=saved_id(queued[0]), state=MemberState.RUNNING.value, stopping=True
                    )
            except ApiError as exc:  # refused, or a vehicle's queue is full (those before it hold)
                with writing(self.db) as s:
                    repo.refuse_team(s, team_id, exc.detail)
                    s.commit()
                self.bus.publish(TeamChanged(team_id=team_id, what="refused", detail={"reason": exc.detail}))
                raise
            self._save(team_id, members, TeamStatus.STARTED)
        self.bus.publish(TeamChanged(team_id=team_id, what="started"))
        return self.get(team_id)

    def delete(self, team_id: int) -> None:
        """Delete a team mission that is not running (created, refused, aborted or finished)."""
        with self._lock:
            team = self.get(team_id)
            if team.status == TeamStatus.STARTED:
                raise Conflict(f"team mission {team_id} is running: abort it first", "team_id")
            with writing(self.db) as s:
                repo.delete_team(s, team_id)
                s.commit()
        self.bus.publish(TeamChanged(team_id=team_id, what="deleted"))

    def abort(self, team_id: int, issued_by: str) -> TeamMission:
        """No more legs are queued; each vehicle finishes the leg it has and holds there."""
        with self._lock:
            team = self.get(team_id)
            if team.status != TeamStatus.STARTED:
                raise Conflict(f"team mission {team_id} is {team.status}", "team_id")
            members = copy.deepcopy(team.members)
            for m in members:
                if m["state"] == MemberState.RUNNING.value:
                    m.update(state=MemberState.STOPPED.value, reason=f"team aborted by {issued_by}")
            self._save(team_id, members, TeamStatus.ABORTED)
        self.bus.publish(TeamChanged(team_id=team_id, what="aborted"))
        return self.get(team_id)

    def confirm(self, proposal_id: int, issued_by: str) -> TeamProposal:
        """Apply a proposal: each helper's current leg is replaced by one to its new waypoint."""
        with self._lock:
            proposal = self._open(proposal_id)
            team = self.get(proposal.team_id)
            if team.status != TeamStatus.STARTED:
                raise Conflict(f"team mission {team.id} is {team.status}", "proposal_id")
            members = copy.deepcopy(team.members)
            outcome = [self._redirect(members, w, issued_by) for w in proposal.work]
            self._save(saved_id(team), members, TeamStatus(team.status))
            with writing(self.db) as s:
                repo.decide(s, proposal_id, ProposalStatus.APPLIED, issued_by, "; ".join(outcome))
                s.commit()
        self.bus.publish(
            TeamChanged(team_id=proposal.team_id, what="applied", detail={"proposal": proposal_id})
        )
        return self.proposal(proposal_id)

    def dismiss(self, proposal_id: int, issued_by: str) -> TeamProposal:
        with self._lock:
            proposal = self._open(proposal_id)
            with writing(self.db) as s:
                repo.decide(s, proposal_id, ProposalStatus.DISMISSED, issued_by, "")
                s.commit()
        self.bus.publish(
            TeamChanged(team_id=proposal.team_id, what="dismissed", detail={"proposal": proposal_id})
        )
        return self.proposal(proposal_id)

    # --- reads ---------------------------------------------------------------------------------------

    def cost(self, team: TeamMission) -> dict[str, Any]:
        return link_cost(team, self.settings)

    def get(self, team_id: int) -> TeamMission:
        with reading(self.db) as s:
            team = repo.team(s, team_id)
        if team is None:
            raise NotFound(f"no team mission {team_id}", "team_id")
        return team

    def every(self) -> list[TeamMission]:
        with reading(self.db) as s:
            return repo.teams(s)

    def proposal(self, proposal_id: int) -> TeamProposal:
        with reading(self.db) as s:
            found = repo.proposal(s, proposal_id)
        if found is None:
            raise NotFound(f"no proposal {proposal_id}", "proposal_id")
        return found

    def proposals(
        self, team_id: int | None = None, status: ProposalStatus | None = None
    ) -> list[TeamProposal]:
        with reading(self.db) as s:
            if team_id is not None and repo.team(s, team_id) is None:
                raise NotFound(f"no team mission {team_id}", "team_id")
            return repo.proposals(s, team_id, status)

    # --- what the link reports (the watcher's thread) -----------------------------------------------

    def on_event(self, event: Event) -> None:
        """A leg's command ended (next leg, or the vehicle's part stops); a time-sensitive anomaly in
        the water from a team vehicle (a proposal)."""
        if isinstance(event, CommandChanged) and event.status in (CommandState.EXECUTED, *ENDS):
            self._leg_ended(event)
        elif is_water_anomaly(event):
            self._anomaly(event.vehicle)

    def _leg_ended(self, event: CommandChanged) -> None:
        with self._lock:
            found = self._member_of(event.id)
            if found is None:
                return
            team, members, member = found
            if event.status == CommandState.EXECUTED:
                if member.pop("stopping", False):
                    pass  # it stopped where it reported: its first leg starts there
                elif off_target(member, event.report):
                    member["corrected"] = member["next"]  # the same waypoint once more, from there
                else:
                    member["next"] += 1
                self._next_leg(member, event.report, "team")
            else:
                why = event.reason or event.detail
                ended = "its takeover" if member.pop("stopping", False) else f"leg {member['next'] + 1}"
                ended = f"{ended} {event.status}"
                member.update(state=MemberState.STOPPED.value, reason=f"{ended}: {why}" if why else ended)
            done = all(m["state"] != MemberState.RUNNING.value for m in members)
            self._save(saved_id(team), members, TeamStatus.FINISHED if done else TeamStatus(team.status))
        self.bus.publish(
            TeamChanged(team_id=saved_id(team), what=member["state"], detail={"vehicle": member["name"]})
        )

    def _next_leg(self, member: dict[str, Any], report: dict[str, Any] | None, issued_by: str) -> None:
        """Queue the member's leg to its ``next`` waypoint from where it reported it was (done if none)."""
        if member["next"] >= len(member["waypoints"]):
            member.update(state=MemberState.DONE.value, command_id=None)
            return
        try:
            start = self._start_of(member["vehicle_id"], report)
            body = leg(start, tuple(member["waypoints"][member["next"]]))
            command = self.desk.submit(member["vehicle_id"], body, issued_by)
        except ApiError as exc:
            member.update(
                state=MemberState.STOPPED.value,
                reason=f"leg {member['next'] + 1}: {exc.detail}",
                command_id=None,
            )
            return
        member.update(command_id=saved_id(command), state=MemberState.RUNNING.value)

    def _anomaly(self, finder: str) -> None:
        """A team vehicle reported a time-sensitive anomaly: propose new work for the others near it (the
        rule: ``plans.restructure``), once per vehicle and team; applied at once if the setting says so."""
        with self._lock:
            found = self._team_of(finder)
            if found is None:
                return
            team, others = found
            where = self._planned(finder)
            helpers = {m["name"]: p.start for m in others if (p := self._planned(m["name"])) is not None}
            if where is None or not helpers:
                return
            targets = plans.restructure(
                where.start,
                helpers,
                self.settings.restructure_radius,
                self.settings.restructure_vehicles,
                self.settings.separation,
            )
            ids = {m["name"]: m["vehicle_id"] for m in others}
            work = [
                {"vehicle_id": ids[name], "name": name, "target": [round(x, 2) for x in t]}
                for name, t in targets.items()
            ]
            with writing(self.db) as s:
                proposal = repo.add_proposal(
                    s,
                    TeamProposal(
                        team_id=saved_id(team),
                        finder=finder,
                        anomaly=[round(x, 2) for x in where.start],
                        work=work,
                    ),
                )
        log.warning(
            "team %s: %s reported a time-sensitive anomaly; proposal %d", team.name, finder, proposal.id
        )
        self.bus.publish(
            TeamChanged(team_id=saved_id(team), what="proposal", detail={"proposal": proposal.id})
        )
        if self.settings.restructure_auto:
            self.confirm(saved_id(proposal), "auto (restructure_auto)")

    # --- helpers -------------------------------------------------------------------------------------

    def _named(self, name: str) -> Vehicle:
        vehicle = self.vehicles.named(name)
        if vehicle is None:
            raise Refused(f"no vehicle named {name!r}", "vehicles")
        return vehicle

    def _planned(self, name: str) -> Planned | None:
        vehicle = self.vehicles.named(name)
        return self.separation.planned(vehicle) if vehicle is not None else None

    def _start_of(self, vehicle_id: int, report: dict[str, Any] | None) -> Point:
        """Where the next leg starts: where the vehicle reported ending the last, else its prediction."""
        if report and all(k in report for k in ("north", "east", "depth")):
            return (report["north"], report["east"], report["depth"])
        planned = self.separation.planned(self.vehicles.get(vehicle_id))
        if planned is None:
            raise Refused("the vehicle has not reported its position yet", "vehicles")
        return planned.start

    def _check_free(self, members: list[dict[str, Any]]) -> None:
        """Refuse (``Conflict``) a start while one of its vehicles runs another team's lanes."""
        ids = {m["vehicle_id"] for m in members}
        for other in self._running():
            busy = [
                m["name"]
                for m in other.members
                if m["vehicle_id"] in ids and m["state"] == MemberState.RUNNING
            ]
            if busy:
                raise Conflict(
                    f"{', '.join(busy)} {'runs' if len(busy) == 1 else 'run'} team mission {other.id} "
                    f"({other.name}): abort it first",
                    "team_id",
                )

    def _running(self) -> list[TeamMission]:
        with reading(self.db) as s:
            return repo.started_teams(s)

    def _check_start(self, members: list[dict[str, Any]]) -> None:
        """Refuse (``Refused``) a start whose plans would bring two vehicles closer than the separation:
        each member's plan is its takeover and then all its lanes, with its lost-link action."""
        candidates = {}
        for m in members:
            vehicle = self.vehicles.get(m["vehicle_id"])
            try:
                found = self.separation.candidate(
                    vehicle, takeover(m, vehicle), [tuple(p) for p in m["waypoints"]]
                )
            except Unplaced as exc:
                raise Refused(str(exc), "vehicles") from None
            if found is None:
                raise Refused(
                    f"{m['name']} has not reported its position yet: its first leg starts there", "vehicles"
                )
            candidates[m["vehicle_id"]] = found
        self.separation.refuse_closer(candidates, "the team's start")

    def _redirect(self, members: list[dict[str, Any]], work: dict[str, Any], issued_by: str) -> str:
        """One helper's new waypoint replaces the rest of its lanes; its leg there is queued now."""
        member = next((m for m in members if m["vehicle_id"] == work["vehicle_id"]), None)
        if member is None or member["state"] == MemberState.STOPPED.value:
            return f"{work['name']}: not running, nothing sent"
        member["waypoints"] = [*member["waypoints"][: member["next"]], work["target"]]
        self._next_leg(member, None, issued_by)
        return f"{work['name']}: {member['state']} {member['reason']}".rstrip()

    def _member_of(self, command_id: int) -> tuple[TeamMission, list[dict[str, Any]], dict[str, Any]] | None:
        with reading(self.db) as s:
            started = repo.started_teams(s)
        for team in started:
            members = copy.deepcopy(team.members)
            for m in members:
                if m["command_id"] == command_id and m["state"] == MemberState.RUNNING.value:
                    return team, members, m
        return None

    def _team_of(self, name: str) -> tuple[TeamMission, list[dict[str, Any]]] | None:
        """The started team ``name`` is in, with its other members still running or done, unless that
        vehicle already prompted one of the team's proposals."""
        with reading(self.db) as s:
            for team in repo.started_teams(s):
                names = [m["name"] for m in team.members]
                if name in names and repo.proposal_by(s, saved_id(team), name) is None:
                    others = [
                        m
                        for m in team.members
                        if m["name"] != name and m["state"] != MemberState.STOPPED.value
                    ]
                    return team, others
        return None

    def _open(self, proposal_id: int) -> TeamProposal:
        proposal = self.proposal(proposal_id)
        if proposal.status != ProposalStatus.PROPOSED:
            raise Conflict(f"proposal {proposal_id} is {proposal.status}", "proposal_id")
        return proposal

    def _save(self, team_id: int, members: list[dict[str, Any]], status: TeamStatus) -> None:
        with writing(self.db) as s:
            repo.save_team(s, team_id, members, status)
            s.commit()
