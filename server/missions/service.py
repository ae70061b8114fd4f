"""Missions: recorded on the shore (the vehicle holds the plan), started and aborted by a control packet
naming their number, queued through the one command desk with the mission's new status."""

from __future__ import annotations

from sqlalchemy import Engine

from server.commands.models import CommandRecord
from server.commands.schemas import CommandIn
from server.commands.service import CommandDesk
from server.core.db import Tx, reading, writing
from server.core.errors import NotFound
from server.missions import repository as repo
from server.missions.models import Mission, MissionStatus
from server.missions.schemas import MissionIn
from server.vehicles import service as vehicles


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

    def route(self, vehicle_id: int) -> list[tuple[float, float, float]]:
        """The waypoints (north, east, depth) of the vehicle's started mission: its planned trajectory."""
        with reading(self.db) as s:
            mission = repo.started(s, vehicle_id)
        waypoints = mission.plan.get("waypoints", []) if mission else []
        return [(w["north"], w["east"], w["depth"]) for w in waypoints]
