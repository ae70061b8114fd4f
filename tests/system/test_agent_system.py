"""The vehicle agent end to end on the simulators: commands move the vehicle as asked, a warm plume
turns it, the paper's square completes, forged and replayed commands are ignored, a restart resumes."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import pytest

from launch.stack import wait_for
from tests.support.system import OP, SCALE, System, angle_between, distance

TOLERANCE_DR = 1.5  # m: dead reckoning over a ~10 m move (calibrated cruise speed, no fix)
TOLERANCE_FIX = 0.6  # m: with a position source
DEPTH_TOLERANCE = 0.3  # m
HEADING_TOLERANCE = 8.0  # deg


@pytest.fixture
def system_factory(tmp_path: Path):
    made: list[System] = []

    def make(**kw: object) -> System:
        made.append(System(tmp_path, **kw))  # type: ignore[arg-type]
        return made[-1]

    yield make
    for system in made:
        system.close()


@pytest.mark.parametrize("fix", [False, True], ids=["dead-reckoning", "position-source"])
def test_move_command_is_executed_within_tolerance(system_factory, fix: bool) -> None:
    system = system_factory(position_source=fix)
    wait_for(lambda: system.checkpoint(), what="first check-point")
    start = system.truth.latest
    command = system.command(command="move", distance=8.0, angle=45.0, depth=2.0)
    wait_for(lambda: system.status(command) == "executed", timeout=90, what="command executed")
    time.sleep(5.0 / SCALE)  # let it settle (5 s of vehicle time)
    end = system.truth.latest
    course = math.radians(start.heading + 45.0)
    expected = (start.north + 8 * math.cos(course), start.east + 8 * math.sin(course))
    error = distance(end, *expected)
    assert error <= (TOLERANCE_FIX if fix else TOLERANCE_DR), (
        f"ended {error:.2f} m from the commanded point: start {start}, end {end}, expected {expected}"
    )
    assert abs(end.depth - (start.depth + 2.0)) <= DEPTH_TOLERANCE
    assert angle_between(end.heading, start.heading + 45.0) <= HEADING_TOLERANCE
    history = [
        e["status"] for e in system.client.get(f"/api/v1/commands/{command}", headers=OP).json()["history"]
    ]
    assert history.count("acknowledged") == 1 and history[-1] == "executed"


def test_a_new_vehicles_first_command_executes_on_its_first_round(system_factory) -> None:
    """Queued before the shore heard the new (unsynced) vehicle: it waits for the vehicle's first
    check-point and the SYNC answering it, then goes once; the vehicle refuses nothing as unsynced."""
    system = system_factory()
    command = system.command(command="move", distance=4.0, angle=0.0, depth=1.0)
    wait_for(lambda: system.status(command) == "executed", timeout=90, what="command executed")
    history = [
        e["status"] for e in system.client.get(f"/api/v1/commands/{command}", headers=OP).json()["history"]
    ]
    assert history.count("sent") == 1 and history.count("acknowledged") == 1, history
    log = system.agent_log()
    assert "SYNC" in log and "Unsynced" not in log


def test_out_of_limits_command_is_refused_by_the_vehicle(system_factory) -> None:
    system = system_factory(agent={"limits": {"max_depth": 5.0}})
    wait_for(lambda: system.checkpoint(), what="first check-point")
    command = system.command(command="goto_depth", depth=8.0)  # the server allows 100 m; the vehicle 5 m
    wait_for(lambda: system.status(command) == "refused", timeout=60, what="refusal")
    detail = system.client.get(f"/api/v1/commands/{command}", headers=OP).json()
    assert detail["reason"] == "out_of_limits"
    assert system.truth.latest.depth < 1.0


PLUME = {
    "surface_temp": 20.0,
    "thermocline_depth": 40.0,
    "front_step": 0.0,
    "plume_north": 22.0,
    "plume_east": 6.0,
    "plume_depth": 2.0,
    "plume_sigma": 6.0,
    "plume_sigma_z": 4.0,
    "plume_excess": 3.0,
    "patches": [],
}


def test_warm_plume_sends_a_time_sensitive_packet_and_turns_towards_it(system_factory) -> None:
    system = system_factory(
        environment=PLUME,
        agent={"missions": [{"builtin": "square", "number": 1, "side": 14.0, "depth": 2.0}]},
    )
    wait_for(lambda: system.checkpoint(), what="first check-point")
    system.command(command="start_mission", param_id=1)
    wait_for(
        lambda: (system.checkpoint() or {}).get("state") == "self_determined",
        timeout=120,
        what="self-determined trajectory",
    )
    wait_for(
        lambda: any(
            p["priority"] == 3 and p["body"]["stream"] == "environmental"
            for p in system.packets(type="priority")
        ),
        timeout=60,
        what="time-sensitive packet stored",
    )
    # the square's second leg runs along north = 14; warmer water lies north-east: the vehicle turns there
    wait_for(lambda: system.truth.latest.north > 15.5, timeout=60, what="a turn towards the plume")
    assert "warm water" in system.agent_log()


def test_square_mission_completes_and_survives_an_agent_restart(system_factory) -> None:
    system = system_factory(
        agent={"missions": [{"builtin": "square", "number": 1, "side": 8.0, "depth": 1.5}]}
    )
    wait_for(lambda: system.checkpoint(), what="first check-point")
    system.command(command="start_mission", param_id=1)
    wait_for(lambda: (system.checkpoint() or {}).get("waypoint", 0) >= 2, timeout=120, what="waypoint 2")
    system.kill_agent()  # SIGKILL, mid-mission
    saved = json.loads((system.tmp / "agent-state.json").read_text())
    assert (
        saved["mission"]["state"] in ("PREPROGRAMMED", "AWAITING_COMMAND")
        and saved["mission"]["waypoint"] >= 2
    )
    system.agent = system.start_agent()
    wait_for(
        lambda: (system.checkpoint() or {}).get("state") == "finished", timeout=180, what="mission finished"
    )
    corners = [(8, 0), (8, 8), (0, 8)]
    for north, east in corners:  # the true track passed near every corner of the square
        assert min(distance(t, north, east) for t in system.truth.track) < 2.0, (north, east)
    assert distance(system.truth.latest, 0, 0) < 2.0


def test_forged_and_replayed_commands_are_ignored(system_factory, tmp_path: Path) -> None:
    import asyncio

    from sqlmodel import Session, select

    from server.telemetry.models import Frame
    from tacit import auth, modem
    from tacit.packets import Command, ControlPacket

    system = system_factory(attacker=True)
    wait_for(lambda: system.checkpoint(), what="first check-point")
    genuine = system.command(command="goto_depth", depth=1.0)
    wait_for(lambda: system.status(genuine) == "executed", timeout=90, what="genuine command executed")
    with Session(system.client.app.state.shore.db) as s:
        captured = s.exec(select(Frame).where(Frame.direction == "out")).first().data
    forged = auth.sign(
        ControlPacket(Command.GOTO_DEPTH, seq=99, time=int(time.time()), depth=4.0), bytes(32), 2
    )

    async def attack() -> None:
        driver = modem.ModemDriver(
            modem.DriverSettings(
                url=str(system.stack.pty("attacker")), address=1, keepalive=60, config={"CST": "1"}
            )
        )
        await driver.start()  # the attacker's modem claims the shore's address
        for frame in (forged, captured):
            for _ in range(4):
                await driver.send(2, [frame], rate=0, ack=False)
                await asyncio.sleep(2.0 / SCALE)
        await driver.stop()

    asyncio.run(attack())
    wait_for(
        lambda: "BadMac" in system.agent_log() and "Replayed" in system.agent_log(),
        timeout=60,
        what="both rejections logged",
    )
    time.sleep(10.0 / SCALE)  # 10 s of vehicle time for a forged command to show
    assert system.truth.latest.depth < 1.5  # never went to the forged 4 m
    assert system.checkpoint()["last_command"] == 1  # only the genuine command was executed


def test_agent_on_a_replayed_real_dive_sends_priority_and_checkpoint_packets(
    system_factory, real_data
) -> None:
    system = system_factory(replay=str(real_data / "ardusub" / "small.tlog"))
    wait_for(
        lambda: system.packets(type="checkpoint"), timeout=60, what="a check-point from the replayed dive"
    )
    wait_for(
        lambda: any(p["body"]["stream"] == "kinematic" for p in system.packets(type="priority")),
        timeout=90,
        what="a priority packet of real IMU data",
    )
    telemetry = system.client.get(
        "/api/v1/telemetry", params={"stream": "imu", "limit": 50}, headers=OP
    ).json()
    certain = [row for row in telemetry["items"] if row["certain"]]
    assert certain and all(len(row["values"]) == 9 for row in certain)
    zacc = [row["values"][2] for row in certain]
    assert all(-1100 < z < -900 for z in zacc)  # the real accelerometer's gravity, reconstructed within eps
    assert list((system.tmp / "tlogs").glob("*.tlog"))  # the agent recorded the session


def test_consecutive_moves_are_executed_only_when_the_vehicle_got_there(system_factory) -> None:
    """The second move starts while the vehicle sits on the first one's target: "executed" must wait
    until the vehicle (the simulator's truth) reached the second target, and say where and when."""
    system = system_factory()
    wait_for(lambda: system.checkpoint(), what="first check-point")
    for distance_m, angle, depth in ((6.0, 0.0, 1.0), (6.0, 90.0, 0.0)):
        start = system.truth.latest
        course = math.radians(start.heading + angle)
        expected = (start.north + distance_m * math.cos(course), start.east + distance_m * math.sin(course))
        command = system.command(command="move", distance=distance_m, angle=angle, depth=depth)
        seen: list[tuple[str, float]] = []  # (status, how far the true vehicle was from the target then)

        def executed() -> bool:
            status = system.status(command)  # noqa: B023
            seen.append((status, distance(system.truth.latest, *expected)))  # noqa: B023
            return status == "executed"

        wait_for(executed, timeout=120, every=0.1, what="command executed")
        assert seen[-1][1] <= TOLERANCE_DR, f"executed {seen[-1][1]:.2f} m from the target: {seen}"
        assert max(far for status, far in seen if status != "executed") > 3.0  # it was seen under way
        detail = system.client.get(f"/api/v1/commands/{command}", headers=OP).json()
        steps = {e["status"]: e for e in detail["history"]}
        assert list(steps)[-2:] == ["executing", "executed"]
        report = steps["executed"]["report"]  # where and when, from the vehicle's check-point
        assert (
            math.hypot(report["north"] - system.truth.latest.north, report["east"] - system.truth.latest.east)
            <= 2.0
        )
        # whole seconds of the agent's clock (the simulation runs SCALE times faster): the move took some
        assert steps["executing"]["report"]["time"] < report["time"] <= steps["executed"]["at"] + 1
