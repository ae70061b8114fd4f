"""The separation check at every door that may move a vehicle, through the API, with check-points
arriving through the shore's ingest as the modem would deliver them: a route in two queued moves, a
mission's start and a resume (its whole route), the fleet's "return all home" to one shared home, the
lost-link action as the vehicle's configuration has it and as a ``set_param`` changes it, and a new home.
Team missions' starts and legs: ``missions/test_teams.py``."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from tacit.packets import CommandStatus, MissionState
from tacit.params import LostAction, Param
from tests.integration.server.missions.test_teams import OP, make_client, post, report

EAST = {"command": "move", "distance": 20.0, "angle": 90.0, "absolute_angle": True}
NORTH = {"command": "move", "distance": 20.0, "angle": 0.0, "absolute_angle": True}


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    yield from make_client(tmp_path)


def refused(answer: Any, says: str) -> None:
    assert answer.status_code == 422, answer.text
    assert says in answer.json()["detail"], answer.json()["detail"]


def queued(client: TestClient, vehicle_id: int) -> list[str]:
    return [c["command"] for c in client.get(f"/api/v1/vehicles/{vehicle_id}/commands", headers=OP).json()]


def test_a_second_queued_move_is_checked_from_anywhere_along_the_first(client: TestClient) -> None:
    report(client, "rov1", 0.0, 0.0)
    report(client, "rov3", 10.0, 10.0)  # inside the parallelogram of east-then-north, 10 m off its corners
    assert post(client, "/vehicles/1/commands", EAST).status_code == 202  # 10 m from rov3 at its closest
    refused(
        post(client, "/vehicles/1/commands", NORTH),
        "rov1's path from (0.0 N, 20.0 E, 2.0 m deep) to (20.0 N, 20.0 E, 2.0 m deep) passes 0.0 m from rov3",
    )
    assert queued(client, 1) == ["move"]
    report(client, "rov3", 10.0, 40.0)
    assert post(client, "/vehicles/1/commands", NORTH).status_code == 202


def test_a_mission_start_and_a_resume_are_checked_along_the_whole_route(client: TestClient) -> None:
    report(client, "rov1", 0.0, 0.0)
    assert client.put("/api/v1/vehicles/2/home", json={"home": [0.0, 30.0]}, headers=OP).status_code == 200
    report(client, "rov2", 0.0, 30.0)
    across = [{"north": 0.0, "east": 0.0, "depth": 2.0}, {"north": 0.0, "east": -28.0, "depth": 2.0}]
    mission = post(
        client, "/vehicles/2/missions", {"name": "across", "number": 5, "waypoints": across}
    ).json()
    refused(post(client, f"/missions/{mission['id']}/start"), "passes 2.0 m from rov1")
    refused(post(client, "/vehicles/2/commands", {"command": "start_mission", "param_id": 5}), "passes 2.0 m")
    refused(
        post(client, "/vehicles/2/commands", {"command": "start_mission", "param_id": 9}),
        "rov2's mission 9 is not recorded on this shore, so its route cannot be checked",
    )
    report(client, "rov2", 0.0, 30.0, state=MissionState.HOLDING, mission=5, waypoint=1)  # held on its way
    refused(post(client, "/vehicles/2/commands", {"command": "resume"}), "passes 2.0 m from rov1")
    away = [{"north": 0.0, "east": 0.0, "depth": 2.0}, {"north": 10.0, "east": 0.0, "depth": 2.0}]
    clear = post(client, "/vehicles/2/missions", {"name": "clear", "number": 6, "waypoints": away}).json()
    assert post(client, f"/missions/{clear['id']}/start").status_code == 202
    assert queued(client, 2) == ["start_mission"]


def test_return_all_home_to_one_shared_home_is_refused_saying_so(client: TestClient) -> None:
    report(client, "rov1", 10.0, 0.0)
    report(client, "rov2", 10.0, 30.0)
    shared = post(client, "/fleet/commands", {"command": "return_home"})
    refused(
        shared,
        "rov1's path from (10.0 N, 0.0 E, 2.0 m deep) to (0.0 N, 0.0 E, 0.0 m deep) passes 0.0 m from rov2",
    )
    refused(
        shared, "(both end at (0.0 N, 0.0 E, 0.0 m deep): send them one at a time, or give each its own home)"
    )
    assert queued(client, 1) == queued(client, 2) == []  # all or none
    assert client.put("/api/v1/vehicles/2/home", json={"home": [0.0, 30.0]}, headers=OP).status_code == 200
    assert post(client, "/fleet/commands", {"command": "return_home"}).status_code == 202
    assert queued(client, 1) == queued(client, 2) == ["return_home"]
    report(client, "rov3", 10.0, 2.0)  # too close to rov1 already: stopping never makes it worse
    assert post(client, "/fleet/commands", {"command": "abort_mission"}).status_code == 202


def lost_action(client: TestClient, vehicle_id: int) -> str:
    return client.get(f"/api/v1/vehicles/{vehicle_id}", headers=OP).json()["lost_action"]


def test_the_lost_link_action_counts_as_configured_and_as_set_param_changes_it(client: TestClient) -> None:
    body = {"name": "rov4", "address": 5, "key": "d4" * 32, "lost_action": "return"}
    assert post(client, "/vehicles", body).status_code == 201  # its agent returns home (the origin)
    report(client, "rov4", 0.0, 30.0, key="d4" * 32, address=5)
    report(client, "rov1", 20.0, 15.0)
    south = {"command": "move", "distance": 20.0, "angle": 180.0, "absolute_angle": True}
    refused(
        post(client, "/vehicles/1/commands", south),
        "if the link is lost, rov1 (hold) and rov4 (return) may come 1.0 m apart",
    )
    hold = {"command": "set_param", "param_id": int(Param.LOST_ACTION), "param_value": 0.0}
    change = post(client, "/vehicles/4/commands", hold).json()
    refused(post(client, "/vehicles/1/commands", south), "rov4 (hold or return)")  # until rov4 has it
    report(
        client,
        "rov4",
        0.0,
        30.0,
        key="d4" * 32,
        address=5,
        command=change["seq"],
        status=CommandStatus.EXECUTED,
    )
    assert lost_action(client, 4) == "hold"
    assert post(client, "/vehicles/1/commands", south).status_code == 202
    back = {**hold, "param_value": float(LostAction.RETURN.code)}
    refused(post(client, "/vehicles/4/commands", back), "if the link is lost, rov4 (hold or return) and rov1")
    refused(post(client, "/vehicles/4/commands", {**hold, "param_value": 7.0}), "takes 0, 1, 2")
    assert post(client, "/vehicles/4/commands", {**hold, "param_value": 1.0}).status_code == 202  # surface


def test_a_new_home_is_checked_where_a_return_would_go(client: TestClient) -> None:
    body = {"name": "rov4", "address": 5, "key": "d4" * 32, "lost_action": "return", "home": [0.0, 40.0]}
    assert post(client, "/vehicles", body).status_code == 201
    report(client, "rov4", 0.0, 30.0, key="d4" * 32, address=5)
    report(client, "rov1", 0.0, 15.0)
    moved = client.put("/api/v1/vehicles/4/home", json={"home": [0.0, 0.0]}, headers=OP)
    refused(moved, "if the link is lost, rov4 (return) and rov1 (hold) may come 1.0 m apart")
    assert client.get("/api/v1/vehicles/4", headers=OP).json()["home"] == [0.0, 40.0]
    assert client.put("/api/v1/vehicles/4/home", json={"home": [0.0, 50.0]}, headers=OP).status_code == 200
