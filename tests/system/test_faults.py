"""Fault injection on the running system: the server killed with SIGKILL mid-mission and restarted."""

from __future__ import annotations

from launch.rig import Rig
from launch.stack import wait_for


def test_server_killed_mid_mission_loses_nothing_and_executes_once() -> None:
    rig = Rig(200.0, scale=8.0, settle=0, mission=True)
    try:
        api = rig.http
        api.post("/vehicles/1/missions", json={"name": "square", "number": 1, "waypoints": []})
        start = api.post("/missions/1/start").json()
        wait_for(
            lambda: api.get(f"/commands/{start['id']}").json()["status"] == "executed",
            60,
            what="mission start",
        )
        wait_for(
            lambda: api.get("/packets", params={"limit": 1}).json()["total"] >= 5, 60, what="packets stored"
        )
        pending = api.post("/vehicles/1/commands", json={"command": "goto_depth", "depth": 3.0}).json()
        before = api.get("/packets", params={"limit": 1000}).json()["items"]
        rig.kill_server()  # mid-mission, a command queued or in flight
        rig.start_server()
        after = {p["id"] for p in api.get("/packets", params={"limit": 1000}).json()["items"]}
        assert {p["id"] for p in before} <= after  # everything stored before the kill is still there
        wait_for(
            lambda: api.get(f"/commands/{pending['id']}").json()["status"] in ("executing", "executed"),
            90,
            what="the command queued before the kill delivered",
        )
        wait_for(
            lambda: api.get("/packets", params={"limit": 1}).json()["total"] > len(after),
            60,
            what="packets flowing again",
        )
        assert set(rig.executed_per_seq().values()) == {1}  # no command executed twice
    finally:
        rig.close()


def test_command_acknowledged_while_the_agent_was_down_is_delivered_later() -> None:
    """The vehicle's modem acknowledges in hardware even when the agent is dead: the shore must not take
    that ACK as delivery. The command goes again until a check-point confirms it, and runs once."""
    rig = Rig(200.0, scale=8.0, settle=0, mission=True)
    try:
        api = rig.http
        wait_for(
            lambda: api.get("/link").json()["vehicles"]["rov1"]["checkpoint"], 60, what="first check-point"
        )
        rig.kill_agent()
        command = api.post("/vehicles/1/commands", json={"command": "goto_depth", "depth": 2.0}).json()
        wait_for(
            lambda: api.get(f"/commands/{command['id']}").json()["status"] == "acknowledged",
            60,
            what="the modem's ACK with nobody listening",
        )
        rig.start_agent()
        wait_for(
            lambda: api.get(f"/commands/{command['id']}").json()["status"] in ("executing", "executed"),
            120,
            what="the command executed after the agent came back",
        )
        assert set(rig.executed_per_seq().values()) == {1}
    finally:
        rig.close()
