"""Vehicles on one simulated channel under the center's safety functions and a team mission.

Two vehicles driven toward one point: the center refuses the command whose path would bring the second
into the first (naming it and how close), accepts one that stops a safe distance short, and warns once
the two vehicles' predicted positions, with their uncertainty, come within the separation. Three vehicles
on a team survey, each on its own lanes (its reported track within their band): one finds the warm plume,
and the shore sends the nearest other vehicle to it."""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient

from launch.stack import Stack, StackConfig, wait_for
from server.app import create_app
from server.core.config import Settings
from server.core.events import Event, SeparationWarning

OP = {"Authorization": "Bearer operator"}
KEYS = ["d4" * 32, "e5" * 32, "f6" * 32]
POINT = (15.0, 15.0)  # both vehicles are sent here: rov1 from (0, 0), rov2 from (0, 30)
SPACING = 10.0  # m between the team survey's lanes
TRACK_SLACK = 1.5  # m: a reported position's error beyond its lanes' band (homes are on the bands' edges)
# warm water at 2 m between rov1's first two lanes, 25 m or more from the others' lanes
PLUME = {"front_step": 0.0, "patches": [], "plume_north": 18.0, "plume_east": 10.0, "plume_sigma": 6.0}


@dataclass
class Fleet:
    stack: Stack
    client: TestClient
    ids: list[int]
    seen: list[Event]

    def get(self, path: str) -> Any:
        return self.client.get(f"/api/v1{path}", headers=OP).json()

    def post(self, path: str, body: dict | None = None) -> Any:
        return self.client.post(f"/api/v1{path}", json=body, headers=OP)


@contextmanager
def fleet(tmp: Path, vehicles: int, environment: dict | None = None, **settings: Any) -> Iterator[Fleet]:
    """The simulated vehicles with their agents, each heard once, and the server in this process."""
    config = StackConfig(
        tmp,
        range_m=150.0,
        time_scale=8.0,
        noise_db=95.0,
        seed=5,
        vehicles=vehicles,
        keys=KEYS[:vehicles],
        write_tokens=["operator"],
        environment=environment,
    )
    stack = Stack(config)
    stack.start_sim()
    values = stack.server_settings(map_enabled=False, poll_interval=2.0, ping_interval=3600)
    client = TestClient(create_app(Settings(**values, separation_check_interval=2.0, **settings)))
    client.__enter__()
    seen: list[Event] = []
    client.app.state.shore.bus.on_event(seen.append)  # type: ignore[attr-defined]
    try:
        ids = [
            client.post("/api/v1/vehicles", json=m.registration(), headers=OP).json()["id"]
            for m in stack.members
        ]
        for member in stack.members:
            stack.write_agent_config(member.index, checkpoint_interval=10)
            stack.start_agent(member.index)
        out = Fleet(stack, client, ids, seen)
        wait_for(
            lambda: all(v["checkpoint"] for v in out.get("/link")["vehicles"].values()),
            timeout=60,
            what="all heard",
        )
        yield out
    finally:
        client.__exit__(None, None, None)
        stack.close()


def move_to(start: tuple[float, float], end: tuple[float, float], depth: float = 1.0) -> dict:
    """A move on a true bearing from ``start`` to ``end`` (the fleet's frame), going ``depth`` m down."""
    bearing = math.degrees(math.atan2(end[1] - start[1], end[0] - start[0])) % 360
    distance = round(math.dist(start, end), 1)
    return {
        "command": "move",
        "distance": distance,
        "angle": round(bearing, 2),
        "absolute_angle": True,
        "depth": depth,
    }


def band(waypoints: list[list[float]], spacing: float) -> tuple[float, float]:
    """The east-west band of a vehicle's lanes (``waypoints``: north, east, depth): half a lane spacing
    either side of its outer lanes, and ``TRACK_SLACK`` more for the reported positions' noise."""
    easts = [w[1] for w in waypoints]
    return min(easts) - spacing / 2 - TRACK_SLACK, max(easts) + spacing / 2 + TRACK_SLACK


def test_two_vehicles_toward_one_point_refused_then_warned(tmp_path: Path) -> None:
    with fleet(tmp_path, 2, separation=5.0) as f:
        first = f.post(f"/vehicles/{f.ids[0]}/commands", move_to((0.0, 0.0), POINT))
        assert first.status_code == 202, first.text
        wait_for(
            lambda: f.get(f"/commands/{first.json()['id']}")["status"] == "executed",
            timeout=90,
            what="rov1 there",
        )

        same = f.post(f"/vehicles/{f.ids[1]}/commands", move_to((0.0, 30.0), POINT))
        assert same.status_code == 422, same.text
        detail = same.json()["detail"]
        assert detail.startswith("rov2's path from") and " m from rov1, which " in detail, detail
        assert detail.endswith("closer than the 5 m separation")
        assert f.get("/safety")["warnings"] == []

        short = (POINT[0], POINT[1] + 6.0)  # stops 6 m east of rov1: clear of it, within 5 m + both doubts
        second = f.post(f"/vehicles/{f.ids[1]}/commands", move_to((0.0, 30.0), short))
        assert second.status_code == 202, second.text
        warned = wait_for(
            lambda: [e for e in f.seen if isinstance(e, SeparationWarning) and e.active],
            timeout=90,
            what="a warning",
        )
        assert warned[0].vehicles == ["rov1", "rov2"] and warned[0].distance_m < warned[0].limit_m
        assert [w["vehicles"] for w in f.get("/safety")["warnings"]] == [["rov1", "rov2"]]


def test_a_team_survey_restructured_by_the_plume_one_vehicle_finds(tmp_path: Path) -> None:
    # separation 4 m: each home sits 5 m from the neighbour's nearest lane, and a vehicle reported a
    # decimetre toward it would make the lost-link check at start refuse the team (it includes positions)
    with fleet(
        tmp_path,
        3,
        PLUME,
        restructure_auto=True,
        restructure_vehicles=1,
        restructure_radius=30.0,
        separation=4.0,
    ) as f:
        area = {"south": 0.0, "north": 60.0, "west": 0.0, "east": 90.0}  # three 60 m lanes each
        body = {
            "name": "plume hunt",
            "vehicles": [{"vehicle": f"rov{k}"} for k in (1, 2, 3)],
            "area": area,
            "spacing": SPACING,
            "depth": 2.0,
        }
        team = f.post("/teams", body).json()
        assert [m["waypoints"][0][1] for m in team["members"]] == [5.0, 35.0, 65.0]  # one lane set each
        started = f.post(f"/teams/{team['id']}/start")
        assert started.status_code == 202, started.text

        def applied() -> list[dict]:
            return [p for p in f.get("/proposals") if p["status"] == "applied"]

        proposal = wait_for(applied, timeout=180, what="the plume found and the team restructured")[0]
        assert proposal["finder"] == "rov1" and [w["name"] for w in proposal["work"]] == ["rov2"]
        target = proposal["work"][0]["target"]
        # on rov2's side of the anomaly, 10 m clear of rov1's lanes
        assert abs(math.dist(target[:2], proposal["anomaly"][:2]) - 30.0) < 0.1

        def rov2() -> dict:
            return next(m for m in f.get(f"/teams/{team['id']}")["members"] if m["name"] == "rov2")

        wait_for(lambda: rov2()["state"] == "done", timeout=180, what="rov2 at its new waypoint")
        assert rov2()["waypoints"][-1] == target
        there = f.get("/link")["vehicles"]["rov2"]["checkpoint"]
        assert math.dist((there["north"], there["east"]), target[:2]) < 3.0, (there, target)
        rov1 = next(m for m in f.get(f"/teams/{team['id']}")["members"] if m["name"] == "rov1")
        assert (
            rov1["state"] in ("running", "done") and len(rov1["waypoints"]) == 6
        )  # the finder keeps its lanes

        # each vehicle ran its own lanes: its reported track (every check-point) stays in its lanes' band,
        # rov2's until the shore sent it to the plume; the others went up their first lane
        for member in team["members"]:  # as planned, before the restructuring
            west, east = band(member["waypoints"], SPACING)
            points = f.get(f"/packets?type=checkpoint&vehicle_id={member['vehicle_id']}&limit=1000")["items"]
            track = [
                (p["body"]["north"], p["body"]["east"])
                for p in points
                if member["name"] != "rov2" or p["at"] < proposal["created_at"]
            ]
            assert all(west <= e <= east for _, e in track), (member["name"], west, east, track)
            if member["name"] != "rov2":
                assert max(n for n, _ in track) > area["north"] / 2, (member["name"], track)
