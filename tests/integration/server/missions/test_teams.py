"""Team missions and the center's safety functions through the API, with check-points and priority
packets arriving through the shore's ingest as the modem would deliver them: lanes split among vehicles
and run leg by leg, bad input refused with the reason, a path too close to another vehicle's refused,
separation warnings (a silent vehicle's uncertainty warns but does not block), lost-link actions checked
at start, and a time-sensitive anomaly restructuring the team (confirmed by an operator, or at once)."""

from __future__ import annotations

import itertools
import json
import math
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from launch.demo import SQUARE
from launch.stack import SPACING_M, wait_for
from server.app import create_app
from server.core.config import Settings
from server.core.events import Event, SeparationWarning
from server.link.state import IncomingFrame
from server.shore import Shore
from tacit import auth
from tacit.packets import CheckpointPacket, CommandStatus, MissionState, Priority, PriorityPacket, Stream
from tests.support.sqlite import migrated

OP = {"Authorization": "Bearer operator-token"}
KEYS = {"rov1": "a1" * 32, "rov2": "b2" * 32, "rov3": "c3" * 32}
ADDRESS = {"rov1": 2, "rov2": 3, "rov3": 4}
AREA = {"south": 0.0, "north": 20.0, "west": 0.0, "east": 20.0}
_stamps = itertools.count(int(time.time()) - 500)


def make_client(tmp_path: Path, **settings: Any) -> Iterator[TestClient]:
    config = Settings(
        database_url=migrated(tmp_path / "tacit.db"),
        modem_url="",
        map_enabled=False,
        write_tokens=["operator-token"],
        ping_interval=3600,
        separation_check_interval=0.2,
        **settings,
    )
    with TestClient(create_app(config)) as c:
        for name, key in KEYS.items():
            body = {"name": name, "address": ADDRESS[name], "key": key, "max_depth": 10.0}
            assert c.post("/api/v1/vehicles", json=body, headers=OP).status_code == 201
        yield c


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    yield from make_client(tmp_path)


def shore(client: TestClient) -> Shore:
    return client.app.state.shore  # type: ignore[attr-defined,no-any-return]


def report(
    client: TestClient,
    name: str,
    north: float,
    east: float,
    depth: float = 2.0,
    command: int = 0,
    status: CommandStatus = CommandStatus.NONE,
    age: float = 0.0,
    state: MissionState | None = None,
    mission: int = 0,
    waypoint: int = 0,
    key: str | None = None,
    address: int | None = None,
) -> None:
    """A check-point from the vehicle (holding, or reporting on its command ``command``; else ``state``,
    with its ``mission`` and the ``waypoint`` it goes to), heard ``age`` seconds ago; ``key`` and
    ``address``: a vehicle the test registered itself."""
    packet = CheckpointPacket(
        seq=next(_stamps) % 256,
        time=next(_stamps),
        state=state or (MissionState.COMMANDED if command else MissionState.HOLDING),
        mission_id=mission,
        waypoint=waypoint,
        last_command=command,
        command_status=status,
        north=north,
        east=east,
        depth=depth,
        heading=0.0,
    )
    src = address or ADDRESS[name]
    frame = auth.sign_checkpoint(packet, bytes.fromhex(key or KEYS[name]), 1, src, [])
    shore(client).ingest.handle(IncomingFrame(src, 1, frame, at=time.time() - age))


def plume(client: TestClient, name: str, stream: Stream = Stream.ENVIRONMENTAL) -> None:
    """A time-sensitive priority packet (the warm plume: its header names the environmental stream),
    tagged under the vehicle's key."""
    packet = PriorityPacket(next(_stamps) % 256, Priority.TIME_SENSITIVE, stream, bytes(29))
    frame = auth.tag_priority(packet, bytes.fromhex(KEYS[name]), ADDRESS[name])
    shore(client).ingest.handle(IncomingFrame(ADDRESS[name], 1, frame))


def post(client: TestClient, path: str, body: dict | None = None) -> Any:
    return client.post(f"/api/v1{path}", json=body, headers=OP)


def team_body(*names: str, **extra: Any) -> dict:
    return {
        "name": "survey",
        "vehicles": [{"vehicle": n} for n in names],
        "area": AREA,
        "spacing": 5.0,
        "depth": 2.0,
        **extra,
    }


def command(client: TestClient, command_id: int) -> dict:
    return client.get(f"/api/v1/commands/{command_id}", headers=OP).json()


def member(client: TestClient, team_id: int, name: str) -> dict:
    team = client.get(f"/api/v1/teams/{team_id}", headers=OP).json()
    return next(m for m in team["members"] if m["name"] == name)


def test_bad_team_missions_are_refused_with_the_reason(client: TestClient) -> None:
    cases = [
        (team_body("rov1", "rov9"), "no vehicle named 'rov9'"),
        (team_body("rov1", "rov1"), "a vehicle is named twice"),
        (team_body("rov1", area={**AREA, "north": 0.0}), "the area is empty"),
        (team_body("rov1", area={"polygon": [[0, 0], [10, 10], [10, 0], [0, 10]]}), "edges cross"),
        (team_body("rov1", "rov2", "rov3", spacing=10.0), "holds 2 lanes, fewer than the 3 vehicles"),
        (team_body("rov1", "rov2", spacing=3.0), "lanes 3 m apart would bring neighbouring vehicles closer"),
        (team_body("rov1", depth=30.0), "the target depth 30.00 m is outside 0 .. 10.0 m"),
        (team_body("rov1", area={**AREA, "north": 600.0}), "leg 1 does not fit its limits: distance 600.0 m"),
    ]
    for body, says in cases:
        refused = post(client, "/teams", body)
        assert refused.status_code == 422, (body, refused.text)
        assert says in refused.json()["detail"], refused.json()
    both = post(client, "/teams", team_body("rov1", area={**AREA, "polygon": [[0, 0], [1, 1], [1, 0]]}))
    assert both.status_code == 422 and "not both" in both.json()["detail"]
    assert client.get("/api/v1/teams", headers=OP).json() == []
    assert post(client, "/vehicles/99/commands", {"command": "hold"}).status_code == 404
    assert post(client, "/teams/99/start").status_code == 404


def test_a_team_mission_runs_its_lanes_leg_by_leg(client: TestClient) -> None:
    report(client, "rov1", -5.0, 2.5, depth=0.0)
    report(client, "rov2", -5.0, 17.5, depth=0.0)
    refused = post(client, "/teams/1/start")
    assert refused.status_code == 404
    created = post(client, "/teams", team_body("rov1", "rov2")).json()
    assert [m["waypoints"] for m in created["members"]] == [
        [[0, 2.5, 2], [20, 2.5, 2], [20, 7.5, 2], [0, 7.5, 2]],
        [[0, 12.5, 2], [20, 12.5, 2], [20, 17.5, 2], [0, 17.5, 2]],
    ]
    assert created["link"]["legs"] == 8 and 17 < created["link"]["channel_s_per_leg"] < 18  # 1 km away
    started = post(client, f"/teams/{created['id']}/start")
    assert started.status_code == 202, started.text
    rov1, rov2 = started.json()["members"]
    assert rov1["state"] == rov2["state"] == "running" and rov1["stopping"] and rov2["stopping"]
    stop = command(client, rov1["command_id"])
    assert stop["command"] == "abort_mission"  # the team takes the vehicle over: it holds where it is
    report(client, "rov1", -5.0, 2.5, depth=0.0, command=stop["seq"], status=CommandStatus.EXECUTED)
    rov1 = wait_for(
        lambda: (m := member(client, created["id"], "rov1"))["stopping"] is False and m,
        timeout=10,
        what="leg 1",
    )
    first = command(client, rov1["command_id"])
    assert (first["command"], first["distance"], first["angle"], first["depth"], first["absolute_angle"]) == (
        "move",
        5.0,
        0.0,
        2.0,
        True,
    )
    assert post(client, f"/teams/{created['id']}/start").status_code == 409

    report(client, "rov1", 0.3, 2.4, command=first["seq"], status=CommandStatus.EXECUTED)
    wait_for(lambda: member(client, created["id"], "rov1")["next"] == 1, timeout=10, what="rov1's second leg")
    second = command(client, member(client, created["id"], "rov1")["command_id"])
    assert second["distance"] == pytest.approx(19.7, abs=0.05) and second["angle"] == pytest.approx(
        0.29, abs=0.01
    )
    assert second["issued_by"] == "team"
    report(client, "rov1", 16.0, 2.5, command=second["seq"], status=CommandStatus.EXECUTED)  # 4 m short
    wait_for(
        lambda: member(client, created["id"], "rov1")["command_id"] != second["id"],
        timeout=10,
        what="a correction",
    )
    correction = command(client, member(client, created["id"], "rov1")["command_id"])
    assert member(client, created["id"], "rov1")["next"] == 1 and correction["distance"] == 4.0
    report(client, "rov1", 19.0, 2.5, command=correction["seq"], status=CommandStatus.EXECUTED)  # once only
    wait_for(lambda: member(client, created["id"], "rov1")["next"] == 2, timeout=10, what="rov1's third leg")

    report(
        client,
        "rov2",
        -5.0,
        17.5,
        0.0,
        command=command(client, rov2["command_id"])["seq"],
        status=CommandStatus.REFUSED,
    )
    wait_for(
        lambda: member(client, created["id"], "rov2")["state"] == "stopped", timeout=10, what="rov2 stopped"
    )
    assert member(client, created["id"], "rov2")["reason"].startswith("its takeover refused")
    aborted = post(client, f"/teams/{created['id']}/abort").json()
    assert (
        aborted["status"] == "aborted"
        and aborted["members"][0]["reason"] == "team aborted by config-operator-1"
    )


def test_a_path_too_close_to_another_vehicles_is_refused_and_closeness_warns(client: TestClient) -> None:
    seen: list[Event] = []
    shore(client).bus.on_event(seen.append)
    report(client, "rov1", 0.0, 0.0)
    report(client, "rov2", 0.0, 30.0)
    west = {"command": "move", "distance": 28.0, "angle": 270.0, "absolute_angle": True}
    refused = post(client, "/vehicles/2/commands", west)
    assert refused.status_code == 422
    assert refused.json()["detail"] == (
        "rov2's path from (0.0 N, 30.0 E, 2.0 m deep) to (0.0 N, 2.0 E, 2.0 m deep) passes 2.0 m from rov1, "
        "which holds at (0.0 N, 0.0 E, 2.0 m deep): closer than the 5 m separation"
    )
    home = post(client, "/vehicles/2/commands", {"command": "return_home"})  # its home is the origin
    assert (
        home.status_code == 422
        and "to (0.0 N, 0.0 E, 0.0 m deep) passes 2.0 m from rov1" in home.json()["detail"]
    )
    assert post(client, "/vehicles/2/commands", {**west, "distance": 20.0}).status_code == 202
    towards = {"command": "move", "distance": 15.0, "angle": 90.0, "absolute_angle": True}
    crossing = post(client, "/vehicles/1/commands", towards)  # into rov2's queued path (30 -> 10 E)
    assert crossing.status_code == 422 and "from rov2, which goes from" in crossing.json()["detail"]
    assert client.get("/api/v1/safety", headers=OP).json()["warnings"] == []

    report(client, "rov2", 0.0, 4.0)  # the report moves rov2 close to rov1: a warning
    warned = wait_for(
        lambda: [e for e in seen if isinstance(e, SeparationWarning) and e.active],
        timeout=10,
        what="a warning",
    )
    assert warned[0].vehicles == ["rov1", "rov2"] and warned[0].distance_m == 4.0
    safety = client.get("/api/v1/safety", headers=OP).json()
    assert [w["vehicles"] for w in safety["warnings"]] == [["rov1", "rov2"]]
    away = {"command": "move", "distance": 10.0, "angle": 90.0, "absolute_angle": True}
    assert post(client, "/vehicles/2/commands", away).status_code == 202  # too close already: away is fine

    report(client, "rov2", 0.0, 30.0)
    wait_for(
        lambda: [e for e in seen if isinstance(e, SeparationWarning) and not e.active],
        timeout=10,
        what="the end",
    )
    report(client, "rov3", 0.0, 21.0, age=80.0)  # silent for 80 s: 5 m of uncertainty
    wait_for(
        lambda: client.get("/api/v1/safety", headers=OP).json()["warnings"], timeout=10, what="doubt warns"
    )
    still = post(
        client,
        "/vehicles/3/commands",
        {"command": "move", "distance": 3.0, "angle": 180.0, "absolute_angle": True},
    )
    assert still.status_code == 202, still.text  # 9 m apart centre to centre: doubt warns, never blocks


def test_lost_link_actions_are_checked_when_a_team_starts(client: TestClient) -> None:
    report(client, "rov1", -5.0, 2.5, depth=0.0)
    report(client, "rov2", -5.0, 17.5, depth=0.0)
    moved = client.put("/api/v1/vehicles/1/home", json={"home": [10.0, 40.0]}, headers=OP)
    assert moved.status_code == 200, moved.text  # rov1's home is east of rov2's lanes
    across = [{"vehicle": "rov1", "lost_action": "return"}, {"vehicle": "rov2", "lost_action": "surface"}]
    team = post(client, "/teams", team_body("rov1", "rov2") | {"vehicles": across}).json()
    assert team["members"][0]["home"] == [10.0, 40.0]
    refused = post(client, f"/teams/{team['id']}/start")
    assert refused.status_code == 422
    reason = (
        "if the link is lost, rov1 (hold or return) and rov2 (hold or surface) may come 0.0 m apart, closer "
        "than the 5 m separation"  # each holds until it has the team's action, then does that
    )
    assert refused.json()["detail"] == reason
    shown = client.get(f"/api/v1/teams/{team['id']}", headers=OP).json()
    assert (shown["status"], shown["detail"]) == ("refused", reason)
    assert client.get("/api/v1/vehicles/1/commands", headers=OP).json() == []  # nothing was queued
    holding = post(client, "/teams", team_body("rov1", "rov2")).json()  # both hold: their lanes stay apart
    assert post(client, f"/teams/{holding['id']}/start").status_code == 202
    again = post(client, "/teams", team_body("rov1", "rov2")).json()
    busy = post(client, f"/teams/{again['id']}/start")
    assert busy.status_code == 409 and busy.json()["detail"] == (
        f"rov1, rov2 run team mission {holding['id']} (survey): abort it first"
    )
    assert client.get(f"/api/v1/teams/{again['id']}", headers=OP).json()["status"] == "refused"
    running = client.delete(f"/api/v1/teams/{holding['id']}", headers=OP)
    assert running.status_code == 409 and "abort it first" in running.json()["detail"]
    for refused_team in (team, again):  # a refused team is deleted, not left for ever
        assert client.delete(f"/api/v1/teams/{refused_team['id']}", headers=OP).status_code == 204
        assert client.get(f"/api/v1/teams/{refused_team['id']}", headers=OP).status_code == 404


def started_team(client: TestClient) -> int:
    for name, east in (("rov1", 2.5), ("rov2", 17.5), ("rov3", 32.5)):
        report(client, name, -5.0, east, depth=0.0)
    body = team_body("rov1", "rov2", "rov3", area={**AREA, "east": 45.0})
    team = post(client, "/teams", body).json()
    assert post(client, f"/teams/{team['id']}/start").status_code == 202
    return int(team["id"])


def test_a_plume_found_by_one_vehicle_proposes_work_near_it_for_the_others(client: TestClient) -> None:
    team = started_team(client)
    report(client, "rov3", 10.0, 40.0)  # far east, on its lanes
    report(client, "rov2", 10.0, 20.0)
    report(client, "rov1", 10.0, 2.5)
    plume(client, "rov1", Stream.KINEMATIC)  # time-sensitive for a manoeuvre: no anomaly of the water
    plume(client, "rov2")
    proposals = wait_for(
        lambda: client.get("/api/v1/proposals", headers=OP).json(), timeout=10, what="a proposal"
    )
    proposal = proposals[0]
    assert len(proposals) == 1
    assert (proposal["team_id"], proposal["finder"], proposal["status"]) == (team, "rov2", "proposed")
    assert proposal["anomaly"][:2] == pytest.approx([10.0, 20.0], abs=0.5)
    assert {w["name"] for w in proposal["work"]} == {"rov1", "rov3"}
    plume(client, "rov2")  # once per vehicle and team
    assert len(client.get(f"/api/v1/teams/{team}/proposals", headers=OP).json()) == 1

    confirmed = post(client, f"/proposals/{proposal['id']}/confirm")
    assert confirmed.status_code == 202 and confirmed.json()["status"] == "applied", confirmed.text
    assert post(client, f"/proposals/{proposal['id']}/confirm").status_code == 409
    for work in proposal["work"]:
        helper = member(client, team, work["name"])
        assert helper["waypoints"][-1] == work["target"] and helper["state"] == "running", helper
        sent = command(client, helper["command_id"])
        assert sent["issued_by"] == "config-operator-1" and sent["command"] == "move"
        assert math.dist(work["target"][:2], proposal["anomaly"][:2]) == pytest.approx(15.0)


def test_with_restructure_auto_the_proposal_is_applied_at_once(tmp_path: Path) -> None:
    client = next(clients := make_client(tmp_path, restructure_auto=True, restructure_vehicles=1))
    try:
        team = started_team(client)
        report(client, "rov2", 10.0, 20.0)
        report(client, "rov1", 10.0, 2.5)
        plume(client, "rov2")

        def applied() -> list[dict]:
            return [p for p in client.get("/api/v1/proposals", headers=OP).json() if p["status"] == "applied"]

        done = wait_for(applied, timeout=10, what="the proposal applied")
        assert done[0]["decided_by"] == "auto (restructure_auto)"
        assert [w["name"] for w in done[0]["work"]] == ["rov1"]
        assert member(client, team, "rov1")["waypoints"][-1] == done[0]["work"][0]["target"]
    finally:
        clients.close()


def manual_example() -> dict:
    """The team mission docs/missions.md gives for the demo fleet, as written there."""
    text = (Path(__file__).parents[4] / "docs" / "missions.md").read_text()
    found = re.search(r"POST /api/v1/teams\n((?:    .*\n)+)", text)
    assert found is not None, "docs/missions.md shows no POST /api/v1/teams"
    return dict(json.loads(found.group(1)))


@pytest.mark.parametrize("corner", [(0.0, 0.0), (20.0, 20.0)], ids=["home", "north-east"])
def test_the_manuals_example_starts_on_the_demo_fleet(
    client: TestClient, corner: tuple[float, float]
) -> None:
    """The demo's vehicles fly their squares (``launch.demo.SQUARE``) around homes ``SPACING_M`` apart:
    wherever they are on them (each at the same corner of its own square; their plans hold the whole
    square ahead), the manual's example is created and started."""
    for k, name in enumerate(KEYS):
        home = [0.0, SPACING_M * k]
        vehicle_id = k + 1
        assert (
            client.put(f"/api/v1/vehicles/{vehicle_id}/home", json={"home": home}, headers=OP).status_code
            == 200
        )
        assert post(client, f"/vehicles/{vehicle_id}/missions", SQUARE).status_code == 201
        north, east = home[0] + corner[0], home[1] + corner[1]
        report(client, name, north, east, state=MissionState.PREPROGRAMMED, mission=1, waypoint=2)
    team = post(client, "/teams", manual_example())
    assert team.status_code == 201, team.text
    started = post(client, f"/teams/{team.json()['id']}/start")
    assert started.status_code == 202, started.text
    assert [m["state"] for m in started.json()["members"]] == ["running"] * 3
