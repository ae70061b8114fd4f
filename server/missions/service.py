"""Missions: recorded on the shore (the vehicle holds the plan), started and aborted by a control packet
naming their number, queued through the one command desk with the mission's new status."""

from __future__ import annotations

from sqlalchemy import Engine

from server.commands.models import CommandRecord
from server.commands.schemas import CommandIn
from server.commands.service import CommandDesk
from server.core.db import Tx, reading, saved_id, writing
from server.core.errors import NotFound
from server.missions import repository as repo
from server.missions.models import MemberState, Mission, MissionStatus
from server.missions.schemas import MissionIn
from server.safety.geometry import Point
from server.vehicles import service as vehicles
from server.vehicles.models import Vehicle


class Missions:
    def __init__(self, db: Engine, desk: CommandDesk) -> None:
        self.db = db
        self.desk = desk

    def create(self, vehicle_id: int, body: MissionIn) -> Mission:
        """Record a mission (the same JSON as the agent's mission file)."""
        with writing(self.db) as s:
            vehicles.get(s, vehicle_id)
            mission = Mission(
                vehicle_id=vehicle_id,
                name=body.name,
                number=body.number,
                plan=body.model_dump(include={"waypoints", "duration_s"}),
            )
            return repo.add(s, mission)

    def of_vehicle(self, vehicle_id: int) -> list[Mission]:
        with reading(self.db) as s:
            vehicles.get(s, vehicle_id)
            return repo.of_vehicle(s, vehicle_id)

    def start(self, mission_id: int, issued_by: str) -> CommandRecord:
        return self._transition(mission_id, "start_mission", MissionStatus.STARTED, issued_by)

    def abort(self, mission_id: int, issued_by: str) -> CommandRecord:
        return self._transition(mission_id, "abort_mission", MissionStatus.ABORTED, issued_by)

    def _transition(
        self, mission_id: int, command: str, status: MissionStatus, issued_by: str
    ) -> CommandRecord:
        """The control packet that starts or aborts a mission, queued with the mission's new status."""
        with reading(self.db) as s:
            mission = repo.get(s, mission_id)
        if mission is None:
            raise NotFound(f"no mission {mission_id}", "mission_id")

        def new_status(tx: Tx) -> None:
            repo.set_status(tx, mission_id, status)

        return self.desk.submit(
            mission.vehicle_id, CommandIn(command=command, param_id=mission.number), issued_by, new_status
        )

    def routes(self, vehicle: Vehicle) -> dict[int, list[Point]]:
        """The waypoints of every mission the vehicle has on record, by number (the newest of each), in
        the fleet's frame (a plan's are relative to the vehicle's home)."""
        with reading(self.db) as s:
            recorded = repo.of_vehicle(s, saved_id(vehicle))
        north, east = vehicle.home
        return {
            m.number: [
                (north + w["north"], east + w["east"], w["depth"]) for w in m.plan.get("waypoints", [])
            ]
            for m in recorded  # oldest first: a newer one with the same number replaces it
        }

    def team_ahead(self, vehicle_id: int) -> list[Point]:
        """The waypoints a running member of a started team will still be sent to after its current leg
        (every one while the team first stops it), in the fleet's frame; none if it runs no team's lanes."""
        with reading(self.db) as s:
            started = repo.started_teams(s)
        for team in started:
            for m in team.members:
                if m["vehicle_id"] == vehicle_id and m["state"] == MemberState.RUNNING:
                    first = m["next"] + (0 if m.get("stopping") else 1)
                    return [(p[0], p[1], p[2]) for p in m["waypoints"][first:]]
        return []
