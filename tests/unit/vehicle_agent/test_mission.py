"""The mission state machine (Algorithm 2) and dead reckoning, without I/O."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tacit.limits import Limits
from tacit.navigation import Pose, Target
from tacit.packets import Command, CommandStatus, ControlFlag, ControlPacket, MissionState, Reason
from tacit.params import LostAction, Param
from vehicle_agent.compressor import PlumeDetector
from vehicle_agent.mavlink_io import VehicleTelemetry
from vehicle_agent.mission import MissionFSM, MissionPlan, MissionProgress
from vehicle_agent.navigator import NavConfig, PositionEstimate

HOME = Pose(0.0, 0.0, 0.0, 0.0)


def fsm(**kw: object) -> MissionFSM:
    return MissionFSM(
        {1: MissionPlan.square(1, side=10.0, depth=2.0, duration_s=600)}, Limits(max_depth=20), **kw
    )  # type: ignore[arg-type]


def control(command: Command, seq: int, **kw: object) -> ControlPacket:
    return ControlPacket(command, seq, 0, **kw)  # type: ignore[arg-type]


def test_waits_then_follows_the_mission_and_resumes_after_a_command() -> None:
    m = fsm()
    assert m.step(0, HOME, None, 0) is None and m.state is MissionState.WAITING
    assert m.on_control(control(Command.START_MISSION, 1, param_id=1), HOME, 0) == (
        CommandStatus.EXECUTED,
        Reason.OK,
    )
    target = m.step(1, HOME, None, 1)
    assert m.state is MissionState.PREPROGRAMMED and (target.north, target.depth) == (0.0, 2.0)
    m.step(2, HOME, Target(0.0, 0.0, 2.0), 2)  # reached waypoint 0
    assert m.status.waypoint == 1
    status, _ = m.on_control(control(Command.MOVE, 2, distance=5, angle=90), Pose(3, 0, 2, 0), 3)
    assert status is CommandStatus.EXECUTING and m.state is MissionState.COMMANDED
    assert m.status.target == pytest.approx((3.0, 5.0, 2.0))
    m.step(
        4, Pose(3, 5, 2, 90), Target(*m.status.target), 4
    )  # the command done: back to the trajectory ("go to line 3")
    assert m.state is MissionState.PREPROGRAMMED and m.status.command_status is CommandStatus.EXECUTED


def test_consecutive_commands_are_executed_only_at_their_own_target() -> None:
    """The vehicle sits on the first command's target (the navigator's arrival flag still up) when the
    second command comes: the second is executing until the vehicle reaches the second target."""
    m = fsm()
    m.on_control(control(Command.MOVE, 1, distance=10, angle=0), HOME, 0)
    first = Target(*m.status.target)
    assert m.step(1, HOME, None, 1) == first and m.status.command_status is CommandStatus.EXECUTING
    m.step(20, Pose(10, 0, 0, 0), first, 20)
    assert m.status.command_status is CommandStatus.EXECUTED and m.state is MissionState.HOLDING
    assert m.step(21, Pose(10, 0, 0, 0), first, 21) == first  # holding there

    m.on_control(control(Command.MOVE, 2, distance=10, angle=90), Pose(10, 0, 0, 0), 22)
    second = Target(*m.status.target)
    assert second != first and m.status.command_status is CommandStatus.EXECUTING
    for now in (22.04, 23, 30):  # the navigator still reports the old target reached: not this one
        assert m.step(now, Pose(10, 0, 0, 0), first, now) == second
        assert (m.status.last_command, m.status.command_status) == (2, CommandStatus.EXECUTING)
        assert m.state is MissionState.COMMANDED
    m.step(31, Pose(10, 5, 0, 90), None, 31)  # under way
    assert m.status.command_status is CommandStatus.EXECUTING
    m.step(40, Pose(10, 10, 0, 90), second, 40)
    assert (m.status.last_command, m.status.command_status) == (2, CommandStatus.EXECUTED)

    m.on_control(control(Command.GOTO_DEPTH, 3, depth=3), Pose(10, 10, 0, 90), 41)  # same spot, deeper
    m.step(41.04, Pose(10, 10, 0, 90), second, 41.04)
    assert m.status.command_status is CommandStatus.EXECUTING
    m.step(50, Pose(10, 10, 3, 90), Target(*m.status.target), 50)
    assert (m.status.last_command, m.status.command_status) == (3, CommandStatus.EXECUTED)


def test_arrival_is_reported_for_the_move_even_after_other_commands_meanwhile() -> None:
    """A request for a check-point, a parameter and a refused command come while a move is under way:
    each is reported, and on arrival the check-point names the move as executed (not the latest seq)."""
    m = fsm()
    m.on_control(control(Command.MOVE, 1, distance=10, angle=0), HOME, 0)
    target = Target(*m.status.target)
    m.on_control(control(Command.REQUEST_CHECKPOINT, 2), Pose(3, 0, 0, 0), 1)
    assert (m.status.last_command, m.status.command_status) == (2, CommandStatus.EXECUTED)
    m.on_control(control(Command.SET_PARAM, 3, param_id=1, param_value=0.7), Pose(4, 0, 0, 0), 2)
    assert (
        m.on_control(control(Command.GOTO_DEPTH, 4, depth=50), Pose(5, 0, 0, 0), 3)[0]
        is CommandStatus.REFUSED
    )
    assert m.step(4, Pose(6, 0, 0, 0), None, 4) == target  # still steering to the move's target
    m.step(10, Pose(10, 0, 0, 0), target, 10)
    assert (m.status.last_command, m.status.command_status) == (1, CommandStatus.EXECUTED)
    assert m.state is MissionState.HOLDING

    m.on_control(control(Command.RETURN_HOME, 5), Pose(10, 0, 0, 0), 11)
    m.on_control(control(Command.REQUEST_CHECKPOINT, 6), Pose(5, 0, 0, 0), 12)
    m.step(20, Pose(0.1, 0, 0, 0), Target(0.0, 0.0, 0.0), 20)
    assert m.state is MissionState.FINISHED
    assert (m.status.last_command, m.status.command_status) == (5, CommandStatus.EXECUTED)

    m.on_control(control(Command.MOVE, 7, distance=5, angle=0), HOME, 21)
    m.on_control(control(Command.HOLD, 8), Pose(2, 0, 0, 0), 22)  # the move is abandoned: nothing to report
    m.step(23, Pose(2, 0, 0, 0), Target(*m.status.target), 23)
    assert (m.status.last_command, m.status.command_status, m.status.commanded) == (
        8,
        CommandStatus.EXECUTED,
        0,
    )


def test_a_waypoint_counts_only_when_it_is_the_one_reached() -> None:
    m = fsm()
    m.on_control(control(Command.START_MISSION, 1, param_id=1), HOME, 0)
    m.step(1, HOME, Target(5.0, 5.0, 2.0), 1)  # some other target (a command's, before the mission resumed)
    assert m.status.waypoint == 0
    m.step(2, HOME, Target(0.0, 0.0, 2.0), 2)
    assert m.status.waypoint == 1


def test_unpredictable_data_time_sensitive_or_not() -> None:
    m = fsm()
    m.on_control(control(Command.START_MISSION, 1, param_id=1), HOME, 0)
    m.on_unpredictable(False, None)
    assert m.state is MissionState.AWAITING_COMMAND  # keeps the trajectory meanwhile
    assert m.step(1, HOME, None, 1) is not None
    m.on_unpredictable(True, (4.0, 4.0, 2.0))  # a plume while awaiting a command: it will not wait
    assert m.state is MissionState.SELF_DETERMINED and m.step(2, HOME, None, 2).east == 4.0
    m.on_unpredictable(False, None)  # ordinary surprises do not pull it off its self-determined course
    assert m.state is MissionState.SELF_DETERMINED


def test_limits_unknown_missions_and_parameters_are_refused_with_a_reason() -> None:
    m = fsm()
    assert m.on_control(control(Command.GOTO_DEPTH, 1, depth=50), HOME, 0) == (
        CommandStatus.REFUSED,
        Reason.OUT_OF_LIMITS,
    )
    assert m.on_control(control(Command.MOVE, 2, distance=2000), HOME, 0)[1] is Reason.OUT_OF_LIMITS
    assert (
        m.on_control(
            control(Command.MOVE, 3, distance=500, angle=0, flags=ControlFlag.ABSOLUTE_ANGLE),
            Pose(600, 0, 1, 0),
            0,
        )[1]
        is Reason.GEOFENCE
    )
    assert m.on_control(control(Command.START_MISSION, 4, param_id=9), HOME, 0)[1] is Reason.UNKNOWN_MISSION
    assert m.on_control(control(Command.SET_PARAM, 5, param_id=200), HOME, 0)[1] is Reason.UNKNOWN_PARAM
    assert (
        m.on_control(control(Command.SET_PARAM, 6, param_id=1, param_value=0.8), HOME, 0)[0]
        is CommandStatus.EXECUTED
    )
    assert m.status.params["plume_threshold"] == 0.8 and m.state is MissionState.WAITING


def test_mission_time_link_loss_and_finish() -> None:
    m = fsm(link_lost_timeout=30.0, lost_action="surface")
    m.on_control(control(Command.START_MISSION, 1, param_id=1), HOME, 0)
    m.step(10, Pose(5, 0, 2, 0), None, 10)
    m.step(50, Pose(5, 0, 2, 0), None, 10)  # 40 s without hearing the shore
    assert m.state is MissionState.LINK_LOST and m.status.target == (5.0, 0.0, 0.0)
    m.on_control(control(Command.RESUME, 2), Pose(5, 0, 0, 0), 51)
    m.step(700, Pose(5, 0, 2, 0), None, 700)  # past T_mission
    assert m.state is MissionState.RETURNING
    m.step(710, Pose(0.2, 0.1, 0.0, 0), Target(0.0, 0.0, 0.0), 710)
    assert m.state is MissionState.FINISHED


def test_the_lost_link_action_is_its_configurations_until_a_set_param_changes_it() -> None:
    m = fsm(link_lost_timeout=30.0, lost_action="hold")
    action = int(Param.LOST_ACTION)
    for seq, value in enumerate((7.0, 1.5, -1.0), start=1):  # not an action: refused, nothing changes
        status, reason = m.on_control(
            control(Command.SET_PARAM, seq, param_id=action, param_value=value), HOME, 0
        )
        assert (status, reason) == (CommandStatus.REFUSED, Reason.UNKNOWN_PARAM)
    assert m.lost_action is LostAction.HOLD
    set_return = control(Command.SET_PARAM, 4, param_id=action, param_value=float(LostAction.RETURN.code))
    assert m.on_control(set_return, HOME, 0)[0] is CommandStatus.EXECUTED
    restored = fsm(status=MissionProgress.from_dict(json.loads(json.dumps(m.status.to_dict()))))
    assert restored.lost_action is LostAction.RETURN  # kept across a restart
    m.on_control(control(Command.START_MISSION, 5, param_id=1), HOME, 0)
    m.step(50, Pose(5, 3, 2, 0), None, 10)  # 40 s without hearing the shore
    assert m.state is MissionState.LINK_LOST and m.status.target == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="lost_action is hold, surface, return"):
        fsm(lost_action="drift")


def test_status_survives_a_round_trip_through_json() -> None:
    m = fsm()
    m.on_control(control(Command.START_MISSION, 7, param_id=1), HOME, 0)
    restored = MissionProgress.from_dict(m.status.to_dict())
    assert restored == m.status


def test_a_restored_mission_the_plans_no_longer_have_holds_where_the_vehicle_is() -> None:
    """A state file saved while mission 1 ran, restored with plans that lost it (the configuration
    changed): the vehicle holds, and says so in its next check-point, instead of failing every tick."""
    saved = fsm()
    saved.on_control(control(Command.START_MISSION, 1, param_id=1), HOME, 0)
    status = MissionProgress.from_dict(saved.status.to_dict())
    m = MissionFSM(
        {2: MissionPlan.square(2, side=5.0, depth=1.0, duration_s=60)}, Limits(max_depth=20), status
    )
    target = m.step(5, Pose(3, 4, 2, 0), None, 5)
    assert m.state is MissionState.HOLDING and target == Target(3, 4, 2)
    assert m.status.mission is None and m.checkpoint_due


def test_dead_reckoning_integrates_the_gap_of_a_restart() -> None:
    """Killed at 0.95 m/s under cruise thrust: ArduSub keeps that thrust 3 s, then the hull coasts."""
    config = NavConfig()
    estimate = PositionEstimate(config)
    estimate.resume(0.0, 0.0, 0.95, config.cruise_thrust, time=100.0, yaw=0.0)
    estimate.update(VehicleTelemetry(time=110.0, yaw=1.5), 0)  # the heading now is not the one it coasted on
    coast = config.drag_length * math.log(1 + 0.95 * 7.0 / config.drag_length)  # quadratic drag, 7 s
    assert estimate.north == pytest.approx(0.95 * 3.0 + coast, rel=0.05) and estimate.speed < 0.2
    assert abs(estimate.east) < 0.05


def test_plume_bearing_along_a_straight_leg_is_along_the_track() -> None:
    """On a straight leg the cross-track gradient cannot be known; the warmer way is ahead or behind."""
    detector = PlumeDetector(threshold=0.5)
    rng = np.random.default_rng(4)
    for i in range(30):  # heading north along east = 0 (+- 5 cm), water warming ahead
        detector.add(i, 0.5 * i, rng.normal(0, 0.05), 20.0 + 0.02 * i + rng.normal(0, 0.01))
    bearing = detector.warmer_bearing()
    assert bearing is not None and min(bearing, 360 - bearing) < 5
    detector = PlumeDetector(threshold=0.5)
    for n in range(-5, 6):
        for e in range(-5, 6):
            detector.samples.append((float(n), float(e), 20.0 + 0.1 * e))  # a survey grid: warmer to the east
    assert abs(detector.warmer_bearing() - 90.0) < 1
