"""The mission state machine of the paper's Algorithm 2, as explicit states and transitions.

    WAITING --control--> (check-point) --START_MISSION--> PREPROGRAMMED
    PREPROGRAMMED --data predictable--> PREPROGRAMMED (check-points at an interval)
    PREPROGRAMMED --unpredictable, time-sensitive--> SELF_DETERMINED (decide locally, priority packet)
    PREPROGRAMMED --unpredictable, not time-sensitive--> AWAITING_COMMAND (keep the trajectory)
    AWAITING_COMMAND --unpredictable, time-sensitive--> SELF_DETERMINED (a plume will not wait)
    SELF_DETERMINED / AWAITING_COMMAND / any --control packet--> COMMANDED (follow the command)
    COMMANDED --done, mission time left--> PREPROGRAMMED (back to the trajectory: "go to line 3")
    COMMANDED --done, no mission--> HOLDING
    any active --t > T_mission, or waypoints done--> RETURNING --home--> FINISHED
    any active --shore silent > link_lost_timeout--> LINK_LOST (hold, surface or return)
    HOLD -> HOLDING; ABORT_MISSION -> ABORTED (holds where it is); RETURN_HOME -> RETURNING

No I/O here: the agent feeds it events and the pose, and gets back the target to steer to and
whether a check-point is due. Its state is plain data, persisted by the agent after every change.

Arrival is always arrival *at a target*: the navigator reports which target it has reached, and a state
counts it only when that is the target the state steers to. A command that arrives while the vehicle
sits on the previous command's target is therefore executing until the vehicle reaches the new one
(a bare "arrived" flag belongs to whatever the navigator was steering to, which may be the old target).
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

from tacit import navigation
from tacit.limits import Limits
from tacit.navigation import Pose, Target
from tacit.packets import Command, CommandStatus, ControlFlag, ControlPacket, MissionState, Reason
from tacit.params import CHECKPOINT_INTERVAL, LostAction, Param

log = logging.getLogger("tacit.agent.mission")

ACTIVE = {
    MissionState.PREPROGRAMMED,
    MissionState.SELF_DETERMINED,
    MissionState.AWAITING_COMMAND,
    MissionState.COMMANDED,
    MissionState.HOLDING,
    MissionState.RETURNING,
}
HOME = Target(0.0, 0.0, 0.0)  # compared with, never handed out (a Target is mutable)
FOLLOWING = (MissionState.PREPROGRAMMED, MissionState.AWAITING_COMMAND)  # on the pre-programmed trajectory


@dataclass
class MissionPlan:
    number: int
    name: str
    waypoints: list[tuple[float, float, float]]  # north, east, depth
    duration_s: float = 1800.0

    @classmethod
    def square(
        cls, number: int = 1, side: float = 20.0, depth: float = 2.0, duration_s: float = 1800.0
    ) -> MissionPlan:
        """The paper's square trajectory (Fig. 5b), starting and ending at home."""
        corners = [(0, 0), (side, 0), (side, side), (0, side), (0, 0)]
        return cls(number, "square", [(n, e, depth) for n, e in corners], duration_s)

    @classmethod
    def lawnmower(
        cls,
        number: int = 2,
        width: float = 40.0,
        length: float = 40.0,
        spacing: float = 10.0,
        depth: float = 2.0,
        duration_s: float = 3600.0,
    ) -> MissionPlan:
        points, east, forward = [], 0.0, True
        while east <= width + 1e-9:
            ends = (0.0, length) if forward else (length, 0.0)
            points += [(ends[0], east, depth), (ends[1], east, depth)]
            east += spacing
            forward = not forward
        return cls(number, "lawnmower", points, duration_s)

    @classmethod
    def load(cls, path: str | Path) -> MissionPlan:
        """A mission file: the JSON the server's missions API takes
        (``{"name", "number", "waypoints": [{"north", "east", "depth"}], "duration_s"}``)."""
        data = json.loads(Path(path).read_text())
        try:
            waypoints = [(float(w["north"]), float(w["east"]), float(w["depth"])) for w in data["waypoints"]]
            return cls(int(data["number"]), str(data["name"]), waypoints, float(data.get("duration_s", 1800)))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: not a mission file ({exc})") from None


@dataclass
class MissionProgress:
    """Everything that must survive a restart (persisted as JSON by the agent)."""

    state: MissionState = MissionState.WAITING
    mission: int | None = None
    waypoint: int = 0
    started_at: float | None = None  # vehicle time the mission started
    target: tuple[float, float, float] | None = None  # the command's, self-determined, or hold point
    resume_state: MissionState | None = None
    last_command: int = 0
    command_status: CommandStatus = CommandStatus.NONE
    commanded: int = 0  # the command whose target is being steered to (reported executed on arrival)
    reason: Reason = Reason.OK
    params: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        data = asdict(self)
        data["state"] = self.state.name
        data["resume_state"] = self.resume_state.name if self.resume_state else None
        data["command_status"] = self.command_status.name
        data["reason"] = self.reason.name
        return data

    @classmethod
    def from_dict(cls, data: dict) -> MissionProgress:
        data = dict(data)
        data["state"] = MissionState[data["state"]]
        data["resume_state"] = MissionState[data["resume_state"]] if data.get("resume_state") else None
        data["command_status"] = CommandStatus[data["command_status"]]
        data["reason"] = Reason[data["reason"]]
        data["target"] = tuple(data["target"]) if data.get("target") else None
        return cls(**data)


class MissionFSM:
    def __init__(
        self,
        plans: dict[int, MissionPlan],
        limits: Limits,
        status: MissionProgress | None = None,
        link_lost_timeout: float = 300.0,
        lost_action: str = "hold",
        checkpoint_interval: float = CHECKPOINT_INTERVAL,
    ) -> None:
        self.configured_lost_action = LostAction.named(lost_action)  # until a SET_PARAM changes it
        self.plans = plans
        self.limits = limits
        self.status = status or MissionProgress()
        self.status.params.setdefault("link_lost_timeout", link_lost_timeout)
        self.status.params.setdefault("checkpoint_interval", checkpoint_interval)
        self.checkpoint_due = True
        self._last_checkpoint = -math.inf

    @property
    def state(self) -> MissionState:
        return self.status.state

    @property
    def lost_action(self) -> LostAction:
        """What it does when the link is lost: its configuration's, or the last SET_PARAM's."""
        code = self.status.params.get(Param.LOST_ACTION.setting)
        return (None if code is None else LostAction.of_code(code)) or self.configured_lost_action

    def _go(self, state: MissionState) -> None:
        if state is not self.status.state:
            self.status.state = state
            self.checkpoint_due = True

    def _report(self, seq: int, status: CommandStatus, reason: Reason = Reason.OK) -> None:
        self.status.last_command, self.status.command_status, self.status.reason = seq, status, reason
        self.checkpoint_due = True

    # --- control packets ------------------------------------------------------------------------

    def on_control(self, packet: ControlPacket, pose: Pose, now: float) -> tuple[CommandStatus, Reason]:
        """Apply a control packet (already authenticated); returns what the check-point will say."""
        handler = {
            Command.MOVE: self._move,
            Command.GOTO_DEPTH: self._goto_depth,
            Command.HOLD: self._hold,
            Command.RESUME: self._resume,
            Command.START_MISSION: self._start,
            Command.ABORT_MISSION: self._abort,
            Command.RETURN_HOME: self._return,
            Command.SET_PARAM: self._set_param,
            Command.REQUEST_CHECKPOINT: lambda p, _pose, _now: (CommandStatus.EXECUTED, Reason.OK),
        }[packet.command]
        status, reason = handler(packet, pose, now)
        self._started(packet.command, status, packet.seq)
        self._report(packet.seq, status, reason)
        return status, reason

    def _commanded(self, target: tuple[float, float, float]) -> tuple[CommandStatus, Reason]:
        refused = self.limits.check_target(*target)
        if refused is not None:
            return CommandStatus.REFUSED, refused.reason
        if self.status.state in (
            MissionState.PREPROGRAMMED,
            MissionState.SELF_DETERMINED,
            MissionState.AWAITING_COMMAND,
        ):
            self.status.resume_state = MissionState.PREPROGRAMMED
        self.status.target = target
        self._go(MissionState.COMMANDED)
        return CommandStatus.EXECUTING, Reason.OK

    def _started(self, command: Command, status: CommandStatus, seq: int) -> None:
        """Which command the vehicle now works on: a later set_param, request_checkpoint or refused command
        is reported meanwhile, but arrival is reported for this one."""
        if status is CommandStatus.EXECUTING:
            self.status.commanded = seq
        elif status is CommandStatus.EXECUTED and command.ends_run:
            self.status.commanded = 0  # whatever was under way is over

    def _move(self, p: ControlPacket, pose: Pose, _now: float) -> tuple[CommandStatus, Reason]:
        refused = self.limits.check(Command.MOVE, p.distance, speed=p.speed)
        if refused is not None:
            return CommandStatus.REFUSED, refused.reason
        absolute = bool(p.flags & ControlFlag.ABSOLUTE_ANGLE)
        north, east = navigation.move_target(
            pose.north, pose.east, pose.heading, p.distance, p.angle, absolute
        )
        return self._commanded((north, east, pose.depth + p.depth))

    def _goto_depth(self, p: ControlPacket, pose: Pose, _now: float) -> tuple[CommandStatus, Reason]:
        return self._commanded((pose.north, pose.east, p.depth))

    def _hold(self, _p: ControlPacket, pose: Pose, _now: float) -> tuple[CommandStatus, Reason]:
        self.status.target = (pose.north, pose.east, pose.depth)
        self._go(MissionState.HOLDING)
        return CommandStatus.EXECUTED, Reason.OK

    def _resume(self, _p: ControlPacket, _pose: Pose, _now: float) -> tuple[CommandStatus, Reason]:
        if self.status.mission is None:
            return CommandStatus.REFUSED, Reason.UNKNOWN_MISSION
        self._go(MissionState.PREPROGRAMMED)
        return CommandStatus.EXECUTED, Reason.OK

    def _start(self, p: ControlPacket, _pose: Pose, now: float) -> tuple[CommandStatus, Reason]:
        if p.param_id not in self.plans:
            return CommandStatus.REFUSED, Reason.UNKNOWN_MISSION
        self.status.mission, self.status.waypoint, self.status.started_at = p.param_id, 0, now
        self.status.resume_state = None
        self._go(MissionState.PREPROGRAMMED)
        return CommandStatus.EXECUTED, Reason.OK

    def _abort(self, _p: ControlPacket, pose: Pose, _now: float) -> tuple[CommandStatus, Reason]:
        self.status.mission, self.status.resume_state = None, None
        self.status.target = (pose.north, pose.east, pose.depth)
        self._go(MissionState.ABORTED)
        return CommandStatus.EXECUTED, Reason.OK

    def _return(self, _p: ControlPacket, _pose: Pose, _now: float) -> tuple[CommandStatus, Reason]:
        self._go(MissionState.RETURNING)
        return CommandStatus.EXECUTING, Reason.OK

    def _set_param(self, p: ControlPacket, _pose: Pose, _now: float) -> tuple[CommandStatus, Reason]:
        known = p.param_id in Param.__members__.values()
        if not known or not math.isfinite(p.param_value) or p.param_value < 0:
            return CommandStatus.REFUSED, Reason.UNKNOWN_PARAM
        param = Param(p.param_id)
        if param is Param.LOST_ACTION and LostAction.of_code(p.param_value) is None:
            return CommandStatus.REFUSED, Reason.UNKNOWN_PARAM
        self.status.params[param.setting] = p.param_value
        return CommandStatus.EXECUTED, Reason.OK

    # --- data events ----------------------------------------------------------------------------

    def on_unpredictable(self, time_sensitive: bool, local_target: tuple[float, float, float] | None) -> None:
        """Unpredictable data was found (and a priority packet queued by the compressor). A time-sensitive
        event turns the vehicle towards it also while it awaits a command on its trajectory: waiting for
        the shore must not make it miss a plume that will not wait."""
        state = self.status.state
        if time_sensitive and local_target is not None and state in FOLLOWING:
            self.status.target = local_target
            self._go(MissionState.SELF_DETERMINED)
        elif state is MissionState.PREPROGRAMMED:
            self._go(MissionState.AWAITING_COMMAND)

    # --- time -----------------------------------------------------------------------------------

    def step(
        self, now: float, pose: Pose, reached: Target | None, shore_heard_at: float | None
    ) -> Target | None:
        """Advance on time and arrival; the target to steer to (None: stay idle). ``reached`` is the
        target the navigator has arrived at (None while under way): it counts only for the same target."""
        s = self.status
        if (
            now - self._last_checkpoint >= s.params["checkpoint_interval"]
            and s.state is not MissionState.WAITING
        ):
            self.checkpoint_due = True
        if (
            s.state in ACTIVE
            and shore_heard_at is not None
            and now - shore_heard_at > s.params["link_lost_timeout"]
        ):
            self._lost(pose)
        if s.mission is not None and s.mission not in self.plans:
            self._unknown_mission(pose)
        if (
            s.started_at is not None
            and s.mission is not None
            and now - s.started_at > self.plans[s.mission].duration_s
            and s.state in ACTIVE
            and s.state is not MissionState.RETURNING
        ):
            self._go(MissionState.RETURNING)
        return self._target(pose, reached)

    def _unknown_mission(self, pose: Pose) -> None:
        """The saved status names a mission this configuration no longer has (the plans changed while it
        ran): hold where the vehicle is, as a hold command would, and say so, instead of failing every tick."""
        s = self.status
        log.error("mission %d is not in this configuration's plans any more: holding position", s.mission)
        s.mission, s.started_at, s.waypoint = None, None, 0
        s.target = (pose.north, pose.east, pose.depth)
        self._go(MissionState.HOLDING)

    def _lost(self, pose: Pose) -> None:
        targets = {
            LostAction.HOLD: (pose.north, pose.east, pose.depth),
            LostAction.SURFACE: (pose.north, pose.east, 0.0),
            LostAction.RETURN: (0.0, 0.0, 0.0),
        }
        self.status.target = targets[self.lost_action]
        self._go(MissionState.LINK_LOST)

    def _target(self, pose: Pose, reached: Target | None) -> Target | None:
        s = self.status
        if s.state is MissionState.WAITING or s.state is MissionState.FINISHED:
            return None
        if s.state in (MissionState.PREPROGRAMMED, MissionState.AWAITING_COMMAND):
            return self._waypoint(reached)
        if s.state is MissionState.RETURNING:
            if reached == HOME and math.hypot(pose.north, pose.east) < 1.0:
                s.mission = None
                self._go(MissionState.FINISHED)
                if s.commanded:  # a commanded return home
                    self._report(s.commanded, CommandStatus.EXECUTED)
                    s.commanded = 0
                return None
            return Target(0.0, 0.0, 0.0)
        target = Target(*s.target) if s.target else None
        if s.state is MissionState.COMMANDED and target is not None and reached == target:
            self._report(s.commanded or s.last_command, CommandStatus.EXECUTED)
            s.commanded = 0
            if s.resume_state is MissionState.PREPROGRAMMED and s.mission is not None:
                s.resume_state = None
                self._go(MissionState.PREPROGRAMMED)
                return self._waypoint(None)
            self._go(MissionState.HOLDING)
        return target

    def _waypoint(self, reached: Target | None) -> Target | None:
        s = self.status
        plan = self.plans.get(s.mission) if s.mission is not None else None
        if plan is None:
            self._go(MissionState.HOLDING)
            return None
        if s.waypoint < len(plan.waypoints) and reached == Target(*plan.waypoints[s.waypoint]):
            s.waypoint += 1
            self.checkpoint_due = True
        if s.waypoint >= len(plan.waypoints):
            self._go(MissionState.RETURNING)
            return Target(0.0, 0.0, 0.0)
        return Target(*plan.waypoints[s.waypoint])

    def checkpoint_sent(self, now: float) -> None:
        self.checkpoint_due = False
        self._last_checkpoint = now
