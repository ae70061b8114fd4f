"""``tacit agent``: the vehicle's service between ArduSub (MAVLink) and its Micro-Modem.

Every tick (10 Hz of vehicle time) it steers towards the mission state machine's target, feeds what
the vehicle measured to the compressor, answers the shore's polls with what is queued, applies the
shore's authenticated control packets, and persists its state. It never stops on a bad packet, a lost
link or a restart: the MAVLink and modem links reconnect with backoff while the vehicle holds.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import math
import signal
import sys
import time
import tomllib
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

from tacit import auth, modem
from tacit.config import check_keys
from tacit.limits import Limits
from tacit.navigation import Pose, Target
from tacit.packets import (
    OXYGEN_NONE,
    CheckpointPacket,
    ControlPacket,
    MissionState,
    Priority,
    Stream,
    with_seq,
)
from tacit.streams import default_streams
from vehicle_agent.compressor import Compressor, PlumeDetector
from vehicle_agent.link import VehicleLink
from vehicle_agent.mavlink_io import MavlinkLink
from vehicle_agent.mission import MissionFSM, MissionPlan, MissionStatus
from vehicle_agent.navigator import NavConfig, Navigator, PositionEstimate
from vehicle_agent.state import AgentState

log = logging.getLogger("tacit.agent")


@dataclass
class AgentConfig:
    address: int = 2
    shore_address: int = 1
    key: str = ""
    modem_url: str = "/dev/ttyUSB0"
    mavlink_url: str = "tcp:127.0.0.1:5777"
    state_file: str = "/var/lib/tacit/agent-state.json"
    tlog_dir: str = ""
    modem_log: str = ""
    time_scale: float = 1.0  # only for simulations that run faster than real time
    link_lost_timeout: float = 300.0
    lost_action: str = "hold"
    checkpoint_interval: float = 60.0
    plume_threshold: float = 0.5
    explore_distance: float = 10.0
    max_latency: float = 10.0
    max_silence: float = 60.0
    limits: Limits = field(default_factory=Limits)
    nav: NavConfig = field(default_factory=NavConfig)
    missions: list[dict] = field(default_factory=lambda: [{"builtin": "square", "number": 1}])

    @classmethod
    def load(cls, path: str | Path) -> AgentConfig:
        data = tomllib.loads(Path(path).read_text())
        check_keys(str(path), data, cls)
        limits = Limits(**data.pop("limits", {}))
        nav = NavConfig(**data.pop("nav", {}))
        config = cls(**data, limits=limits, nav=nav)
        auth.parse_key(config.key)  # a clear error now rather than at the first control packet
        return config

    def plans(self, base: Path) -> dict[int, MissionPlan]:
        plans = {}
        for entry in self.missions:
            entry = dict(entry)
            if "file" in entry:
                plan = MissionPlan.load(base / entry["file"])
            else:
                builtin = entry.pop("builtin")
                plan = {"square": MissionPlan.square, "lawnmower": MissionPlan.lawnmower}[builtin](**entry)
            plans[plan.number] = plan
        return plans


class Agent:
    def __init__(self, config: AgentConfig, plans: dict[int, MissionPlan]) -> None:
        self.config = config
        self.state_path = Path(config.state_file)
        self.state = AgentState.load(self.state_path)
        tlog = Path(config.tlog_dir) / time.strftime("agent-%Y%m%d-%H%M%S.tlog") if config.tlog_dir else None
        if tlog:
            tlog.parent.mkdir(parents=True, exist_ok=True)
        self.mav = MavlinkLink(config.mavlink_url, tlog)
        self.position = PositionEstimate(config.nav)
        if self.state.time is not None:
            self.position.resume(self.state.north, self.state.east, self.state.speed, self.state.thrust,
                                 self.state.time, self.state.yaw)  # fmt: skip
        self.navigator = Navigator(self.mav, config.nav, self.position)
        status = MissionStatus.from_dict(self.state.mission) if self.state.mission else None
        self.fsm = MissionFSM(plans, config.limits, status, config.link_lost_timeout, config.lost_action,
                              config.checkpoint_interval)  # fmt: skip
        self.compressor = Compressor(default_streams(), config.max_latency, config.max_silence)
        self.plume = PlumeDetector(self.fsm.status.params.get("plume_threshold", config.plume_threshold))
        key = auth.parse_key(config.key)
        window = auth.ReplayWindow.from_dict(self.state.replay)
        self.driver = modem.ModemDriver(modem.DriverSettings(url=config.modem_url, address=config.address,
                                                             log_path=config.modem_log or None))  # fmt: skip
        self.link = VehicleLink(
            self.driver, auth.ControlReceiver(key, config.address, window), config.shore_address
        )
        self.link.on_control = self._on_control
        self.link.on_repeat = self._on_repeat
        self._repeat_answered = -1e9
        self._report: CheckpointPacket | None = None  # the check-point of the last status change, until sent
        self.samples: deque[tuple[str, float, tuple]] = deque(maxlen=10_000)
        self.mav.listeners.append(self._on_mavlink)
        self.shore_heard_at: float | None = None
        self._polls_seen = 0
        self._dirty = True
        self._persisted_at = -1e9

    # --- inputs ---------------------------------------------------------------------------------

    def _on_mavlink(self, kind: str, msg: object) -> None:
        """MAVLink thread: hand samples to the loop (a deque is safe between threads)."""
        if kind == "RAW_IMU":
            self.samples.append(("imu", time.time(), self.mav.telemetry.imu))
        elif kind == "SCALED_PRESSURE2":
            self.samples.append(("env", time.time(), (self.mav.telemetry.temperature, self.mav.telemetry.depth,
                                                      self.mav.telemetry.oxygen)))  # fmt: skip

    def pose(self) -> Pose:
        tel = self.mav.telemetry
        return Pose(self.position.north, self.position.east, tel.depth, tel.heading)

    def _on_control(self, packet: ControlPacket) -> None:
        now = self.mav.telemetry.time
        status, reason = self.fsm.on_control(packet, self.pose(), now)
        self.shore_heard_at = now
        self.plume.threshold = self.fsm.status.params.get("plume_threshold", self.plume.threshold)
        log.info("control seq %d %s: %s %s", packet.seq, packet.command.name, status.name, reason.name)
        self.state.replay = self.link.receiver.window.to_dict()
        self._persist()  # the replay window is on disk before anything acts on the command

    def _on_repeat(self, seq: int) -> None:
        """The shore sent again a command we have: it did not hear our check-point. Say it again
        (once per 10 s of vehicle time at most: a replaying stranger cannot make us chatter)."""
        now = self.mav.telemetry.time
        if seq == self.fsm.status.last_command and now - self._repeat_answered >= 10.0:
            self._repeat_answered = now
            self.fsm.checkpoint_due = True

    def _drain_samples(self, pose: Pose) -> None:
        while self.samples:
            kind, stamp, values = self.samples.popleft()
            if kind == "imu" and values is not None:
                self.compressor.add(Stream.KINEMATIC, stamp, list(values))
            elif kind == "env" and values[0] is not None:
                temperature, depth, oxygen = values
                event = self.plume.add(self.mav.telemetry.time, pose.north, pose.east, temperature)
                self.compressor.add(Stream.ENVIRONMENTAL, stamp, [temperature, depth, oxygen],
                                    urgent=event is not None)  # fmt: skip
                if event is not None:
                    self._plume(event, pose)

    def _plume(self, event, pose: Pose) -> None:  # noqa: ANN001
        bearing = event.bearing if event.bearing is not None else pose.heading
        d = self.config.explore_distance
        target = (pose.north + d * math.cos(math.radians(bearing)), pose.east + d * math.sin(math.radians(bearing)),
                  pose.depth)  # fmt: skip
        log.warning("warm water: %.2f degC (baseline %.2f); turning to %.0f deg", event.temperature,
                    event.baseline, bearing)  # fmt: skip
        self.fsm.on_unpredictable(True, target)

    # --- outputs --------------------------------------------------------------------------------

    def _send_packets(self) -> None:
        for stream, encoded in self.compressor.ready(time.time()):
            urgent = encoded.packet.priority is Priority.TIME_SENSITIVE
            packet = with_seq(encoded.packet, self.state.packet_seq)
            self.state.packet_seq += 1
            self.link.send(packet.encode(), urgent, lambda ok, s=stream: self.compressor.resolve(s, ok))
            self.state.priority_count += 1
            log.info("priority packet seq %d (%s, %d ticks, %d surprises) queued", packet.seq,
                     stream.name.lower(), encoded.ticks, encoded.nonzero)  # fmt: skip
            if stream is Stream.ENVIRONMENTAL and encoded.nonzero and not urgent:
                self.fsm.on_unpredictable(False, None)

    def checkpoint(self) -> CheckpointPacket:
        tel, s, pose = self.mav.telemetry, self.fsm.status, self.pose()
        clip = lambda v, lo, hi: max(lo, min(hi, v))  # noqa: E731
        flags = (1 if self.position.source != "dead_reckoning" else 0) | (2 if tel.armed else 0) | (
            4 if s.state is MissionState.LINK_LOST else 0)  # fmt: skip
        return CheckpointPacket(
            seq=self.state.packet_seq % 256, time=int(time.time()), state=s.state, mission_id=s.mission or 0,
            waypoint=min(s.waypoint, 255), north=clip(pose.north, -3276.8, 3276.7),
            east=clip(pose.east, -3276.8, 3276.7), depth=clip(pose.depth, 0, 655.35),
            heading=round(pose.heading, 2) % 360.0,
            battery=clip(tel.battery, 0, 25.5), last_command=s.last_command, command_status=s.command_status,
            reason=s.reason, temperature=clip(tel.temperature or 0.0, -327.68, 327.67),
            oxygen=clip(tel.oxygen, 0, 655.34) if tel.oxygen is not None else OXYGEN_NONE,
            priority_count=self.state.priority_count % 65536, flags=flags)  # fmt: skip

    def _send_checkpoint(self) -> None:
        packet, report, self._report = self.checkpoint(), self._report, None
        same = report is not None and report.last_command == packet.last_command
        if same and report.command_status is packet.command_status:  # type: ignore[union-attr]
            packet = with_seq(report, packet.seq)  # the pose and time of the tick the status changed
        self.state.packet_seq += 1
        self.link.send(packet.encode(), urgent=True)
        self.fsm.checkpoint_sent(self.mav.telemetry.time)
        self._dirty = True
        log.info("check-point seq %d queued: %s, command %d %s", packet.seq, packet.state.name,
                 packet.last_command, packet.command_status.name)  # fmt: skip

    def _persist(self) -> None:
        self.state.mission = self.fsm.status.to_dict()
        self.state.north, self.state.east = self.position.north, self.position.east
        self.state.speed, self.state.thrust = self.position.speed, self.navigator.thrust
        self.state.yaw = self.mav.telemetry.yaw
        self.state.time = self.mav.telemetry.time if self.mav.telemetry.time else self.state.time
        self.state.save(self.state_path)
        self._dirty = False

    # --- the loop -------------------------------------------------------------------------------

    def tick(self) -> None:
        tel = self.mav.telemetry
        if not self.mav.connected or not tel.fresh("ATTITUDE") or not tel.fresh("SCALED_PRESSURE2", 5.0):
            return  # never steer, dead-reckon or report on default heading and depth
        self.navigator.step()
        pose = self.pose()
        if self.link.counters["polls"] != self._polls_seen:
            self._polls_seen = self.link.counters["polls"]
            self.shore_heard_at = tel.time
        if self.shore_heard_at is None or self.shore_heard_at > tel.time:
            self.shore_heard_at = tel.time  # counting starts now (or the autopilot rebooted)
        self._drain_samples(pose)
        before = self.fsm.status.to_dict()
        target = self.fsm.step(tel.time, pose, self.navigator.reached, self.shore_heard_at)
        if target != self.navigator.target:
            self.navigator.set_target(target)
        reported = (self.fsm.status.last_command, self.fsm.status.command_status.name)
        if reported != (before["last_command"], before["command_status"]):
            self._report = self.checkpoint()  # where and when it happened (e.g. arrival), even if sent later
        self._send_packets()
        if self.fsm.checkpoint_due and self.link.backlog < 4:
            self._send_checkpoint()
        if self._dirty or self.fsm.status.to_dict() != before or tel.time - self._persisted_at >= 1.0:
            self._persist()  # dead-reckoned position is state too: at least once a second of vehicle time
            self._persisted_at = tel.time

    async def run(self, stop: asyncio.Event) -> None:
        self.mav.start()
        await self.driver.start()
        log.info("agent %d up: modem %s, MAVLink %s, state %s", self.config.address, self.config.modem_url,
                 self.config.mavlink_url, self.fsm.state.name)  # fmt: skip
        try:
            while not stop.is_set():
                try:
                    self.tick()
                except Exception:  # the agent must not stop under water: log, hold on, go on
                    log.exception("agent tick failed")
                    self.navigator.set_target(
                        Target(self.position.north, self.position.east, self.mav.telemetry.depth)
                    )
                with_timeout = asyncio.wait_for(stop.wait(), 0.1 / self.config.time_scale)
                try:
                    await with_timeout
                except TimeoutError:
                    pass
        finally:
            self._persist()
            await self.driver.stop()
            self.mav.stop()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="the agent's TOML configuration")


def run(args: argparse.Namespace) -> int:
    try:
        config = AgentConfig.load(args.config)
        plans = config.plans(Path(args.config).resolve().parent)
    except (OSError, ValueError, TypeError, tomllib.TOMLDecodeError) as exc:
        print(f"tacit agent: {exc}", file=sys.stderr)
        return 2

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await Agent(config, plans).run(stop)

    asyncio.run(main())
    return 0
