"""Fault injection on the running system: the server killed with SIGKILL mid-mission and restarted."""

from __future__ import annotations

from launch.rig import Rig
from launch.stack import wait_for


def test_server_killed_mid_mission_loses_nothing_and_executes_once() -> None:
    rig = Rig(200.0, scale=5.0, mission=True)
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
        wait_for(lambda: api.get(f"/commands/{pending['id']}").json()["status"] in ("executing", "executed"), 90,
                 what="the command queued before the kill delivered")  # fmt: skip
        wait_for(lambda: api.get("/packets", params={"limit": 1}).json()["total"] > len(after), 60,
                 what="packets flowing again")  # fmt: skip
        assert set(rig.executed_per_seq().values()) == {1}  # no command executed twice
    finally:
        rig.close()


def test_mavlink_link_drops_and_the_agent_reconnects(tmp_path) -> None:
    import socket

    from tests.conftest import tacit_process
    from vehicle_agent.mavlink_io import MavlinkLink

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    link = MavlinkLink(f"tcp:127.0.0.1:{port}", tlog=tmp_path / "agent.tlog", reconnect_max=1.0)
    link.start()
    try:
        with tacit_process("sim", "--mavlink-port", str(port)):
            assert link.wait_connected(20)
            wait_for(lambda: link.telemetry.heartbeats >= 1, 10, what="heartbeats")
        wait_for(lambda: not link.connected, 20, what="the drop noticed")  # the vehicle went away
        with tacit_process("sim", "--mavlink-port", str(port)):  # and came back on the same endpoint
            assert link.wait_connected(30)
            before = link.telemetry.heartbeats
            wait_for(lambda: link.telemetry.heartbeats > before, 10, what="telemetry again")
    finally:
        link.stop()
    assert (tmp_path / "agent.tlog").stat().st_size > 0


def test_command_acknowledged_while_the_agent_was_down_is_delivered_later() -> None:
    """The vehicle's modem acknowledges in hardware even when the agent is dead: the shore must not take
    that ACK as delivery. The command goes again until a check-point confirms it, and runs once."""
    rig = Rig(200.0, scale=5.0, mission=True)
    try:
        api = rig.http
        wait_for(
            lambda: api.get("/link").json()["vehicles"]["rov1"]["checkpoint"], 60, what="first check-point"
        )
        rig.kill_agent()
        command = api.post("/vehicles/1/commands", json={"command": "goto_depth", "depth": 2.0}).json()
        wait_for(lambda: api.get(f"/commands/{command['id']}").json()["status"] == "acknowledged", 60,
                 what="the modem's ACK with nobody listening")  # fmt: skip
        rig.start_agent()
        wait_for(lambda: api.get(f"/commands/{command['id']}").json()["status"] in ("executing", "executed"), 120,
                 what="the command executed after the agent came back")  # fmt: skip
        assert set(rig.executed_per_seq().values()) == {1}
    finally:
        rig.close()
