"""``tacit agent``: the vehicle's service between ArduSub (MAVLink) and its Micro-Modem.

Every tick (10 Hz of vehicle time) it steers towards the mission state machine's target, feeds what
the vehicle measured to the compressor, answers the shore's polls with what is queued, applies the
shore's authenticated control packets, and persists its state. It never stops on a bad packet, a lost
link or a restart: the MAVLink and modem links reconnect with backoff while the vehicle holds.

Trust: only authentic control packets (commands, or the shore's SYNC heartbeat) reset the link-lost
timer; a SYNC's time corrects the clock (up to ``max_clock_correction``, both ways) and can ask the
compressor to restart its chains; a scheduled SYNC (pre-signed, sent by a gateway cut off from the
center) only keeps the link alive, within ``tacit.auth.SCHEDULED_WINDOW`` of the clock. An agent that lost its state is unsynced: its check-points say so,
and it accepts nothing until a SYNC echoes one of their MACs (``tacit.auth.SyncWindow``), which sets
its clock. Check-points are signed with the vehicle's key and cover the priority packets
delivered since the last delivered check-point (at most 16 packet seqs back: a check-point is due
before the oldest would fall out of reach). Key rotation is staged: the agent holds ``key`` (version
``key_version``) and optionally ``next_key`` (version + 1), accepts both, and signs with the newest the
shore has used, which tells the shore the vehicle has it. Each check-point names the final statuses of
the four commands before its last one. What waits to be sent is persisted with the state.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import math
import signal
import time
import tomllib
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from tacit import auth, modem
from tacit.codec import EncodedPacket
from tacit.codec.format import MAX_WINDOW
from tacit.config import check_keys
from tacit.limits import Limits
from tacit.navigation import Pose, Target
from tacit.packets import (
    CHECKPOINT_MAC_SIZE,
    COVER_BITS,
    NEWEST,
    OXYGEN_NONE,
    QUIET_UNKNOWN,
    SYNC_RESTART_CHAINS,
    CheckpointPacket,
    Command,
    CommandStatus,
    ControlFlag,
    ControlPacket,
    MissionState,
    Priority,
    Stream,
    cover_bitmap,
    pack_settled,
    quiet_of,
    with_seq,
)
from tacit.params import CHECKPOINT_INTERVAL
from tacit.private import private_dir
from tacit.sampletime import SampleClock, boot_seconds
from tacit.streams import WATER_CHANNELS, default_streams
from vehicle_agent.compressor import Compressor, PlumeDetector, PlumeEvent
from vehicle_agent.link import VehicleLink
from vehicle_agent.mavlink_io import MavlinkLink
from vehicle_agent.mission import MissionFSM, MissionPlan, MissionProgress
from vehicle_agent.navigator import NavConfig, Navigator, PositionEstimate
from vehicle_agent.state import AgentState, Queued, Settled, Uncovered

log = logging.getLogger("tacit.agent")
CLOCK_DEADBAND = 30.0  # s: travel and airtime are seconds; a synced clock is corrected beyond this


@dataclass
class AgentConfig:
    address: int = 2
    shore_address: int = 1
    gateways: list[int] = field(default_factory=list)  # a split shore's other modems (docs/backhaul.md)
    key: str = ""
    key_version: int = 1
    next_key: str = ""  # the key of version key_version + 1, installed before a rotation at sea
    max_clock_correction: float = auth.MAX_CORRECTION  # s the shore's SYNC time may move the clock
    modem_url: str = "/dev/ttyUSB0"
    mavlink_url: str = "tcp:127.0.0.1:5777"
    state_file: str = "/var/lib/tacit/agent-state.json"
    tlog_dir: str = ""
    modem_log: str = ""
    time_scale: float = 1.0  # only for simulations that run faster than real time
    link_lost_timeout: float = 300.0
    lost_action: str = "hold"
    checkpoint_interval: float = CHECKPOINT_INTERVAL
    plume_threshold: float = 0.5
    explore_distance: float = 10.0
    max_latency: float = 10.0
    max_silence: float = 60.0
    protocol: int = NEWEST  # the protocol version it speaks: the shore's registration of it must agree
    limits: Limits = field(default_factory=Limits)
    nav: NavConfig = field(default_factory=NavConfig)
    missions: list[dict] = field(default_factory=lambda: [{"builtin": "square", "number": 1}])

    @classmethod
    def load(cls, path: str | Path) -> AgentConfig:
        """The settings as written (``vehicle_agent.check`` says what is wrong with their values)."""
        data = tomllib.loads(Path(path).read_text())
        check_keys(str(path), data, cls)
        limits, nav = data.pop("limits", {}), data.pop("nav", {})
        check_keys(f"{path} [limits]", limits, Limits)
        check_keys(f"{path} [nav]", nav, NavConfig)
        return cls(**data, limits=Limits(**limits), nav=NavConfig(**nav))

    def keys(self) -> dict[int, bytes]:
        keys = {self.key_version: auth.parse_key(self.key)}
        if self.next_key:
            keys[self.key_version + 1] = auth.parse_key(self.next_key)
        return keys

    def plans(self, base: Path) -> dict[int, MissionPlan]:
        return {plan.number: plan for plan in (self.plan(entry, base) for entry in self.missions)}

    @staticmethod
    def plan(entry: dict, base: Path) -> MissionPlan:
        """One entry of ``missions``: a file (relative to ``base``, the configuration's folder) or a
        built-in plan with its arguments."""
        entry = dict(entry)
        if "file" in entry:
            return MissionPlan.load(base / entry["file"])
        builtin = entry.pop("builtin")
        builders: dict[str, Callable[..., MissionPlan]] = {
            "square": MissionPlan.square,
            "lawnmower": MissionPlan.lawnmower,
        }
        if builtin not in builders:
            raise ValueError(f"no built-in mission {builtin!r} (there are {', '.join(builders)})")
        return builders[builtin](**entry)


class Agent:
    def __init__(self, config: AgentConfig, plans: dict[int, MissionPlan]) -> None:
        self.config = config
        self.state_path = Path(config.state_file)
        self.state = AgentState.load(self.state_path)
        self.keys = config.keys()
        if self.state.key_epoch not in self.keys:
            self.state.key_epoch = config.key_version
        tlog = Path(config.tlog_dir) / time.strftime("agent-%Y%m%d-%H%M%S.tlog") if config.tlog_dir else None
        if tlog:
            private_dir(tlog.parent)
        self.mav = MavlinkLink(config.mavlink_url, tlog)
        self.position = PositionEstimate(config.nav)
        if self.state.time is not None:
            self.position.resume(
                self.state.north,
                self.state.east,
                self.state.speed,
                self.state.thrust,
                self.state.time,
                self.state.yaw,
            )
        self.navigator = Navigator(self.mav, config.nav, self.position)
        try:
            status = MissionProgress.from_dict(self.state.mission) if self.state.mission else None
        except (KeyError, TypeError, ValueError) as exc:
            log.error("saved mission status unreadable (%s): starting safe, waiting", exc)
            status = None
        self.fsm = MissionFSM(
            plans,
            config.limits,
            status,
            config.link_lost_timeout,
            config.lost_action,
            config.checkpoint_interval,
        )
        self.streams = default_streams()
        self.compressor = Compressor(
            self.streams, config.max_latency, config.max_silence, protocol=config.protocol
        )
        self.plume = PlumeDetector(self.fsm.status.params.get("plume_threshold", config.plume_threshold))
        window = auth.ReplayWindow.from_dict(self.state.replay)
        sync = auth.SyncWindow(config.max_clock_correction, self.state.sync_counter)
        self.driver = modem.ModemDriver(
            modem.DriverSettings(
                url=config.modem_url, address=config.address, log_path=config.modem_log or None
            )
        )
        self.link = VehicleLink(
            self.driver,
            auth.ControlReceiver(self.keys, config.address, window, sync),
            [config.shore_address, *config.gateways],
        )
        self.link.offset = self.state.clock_offset
        for queued in self.state.outbox:  # what a SIGKILL interrupted goes out again, byte for byte
            self.link.send(queued.data, queued.urgent, self._on_delivered(queued.data))
        if self.state.outbox:
            log.info("%d packet(s) restored to the send queue", len(self.state.outbox))
        self.link.on_control = self._on_control
        self.link.on_repeat = self._on_repeat
        self._repeat_answered = -1e9
        self._challenged = -1e9  # vehicle time of the last check-point sent unsynced
        self._report: CheckpointPacket | None = None  # the check-point of the last status change, until sent
        self._flying: dict[int, bytes] = {}  # priority packets in flight, by seq (to withdraw them)
        self._vouching: set[int] = set()  # delivered packets a check-point on its way covers, by seq
        self.samples: deque[tuple[str, float, tuple]] = deque(maxlen=10_000)
        self._clocks = {"RAW_IMU": SampleClock(), "SCALED_PRESSURE2": SampleClock()}  # MAVLink thread's
        self.mav.listeners.append(self._on_mavlink)
        self.shore_heard_at: float | None = None
        self._dirty = True
        self._persisted_at = -1e9

    # --- inputs ---------------------------------------------------------------------------------

    def _on_mavlink(self, kind: str, msg: object) -> None:
        """MAVLink thread: hand samples to the loop (a deque is safe between threads), each dated when
        the autopilot measured it (``tacit.sampletime``), not when it arrived."""
        imu = self.mav.telemetry.imu
        if kind == "RAW_IMU" and imu is not None:
            self.samples.append(("imu", self._measured(kind, msg), imu))
        elif kind == "SCALED_PRESSURE2":
            self.samples.append(
                (
                    "env",
                    self._measured(kind, msg),
                    (self.mav.telemetry.temperature, self.mav.telemetry.depth, self.mav.telemetry.oxygen),
                )
            )

    def _measured(self, kind: str, msg: object) -> float:
        """When a sample message was measured, on the local clock corrected by the shore's SYNC time
        (pymavlink stamps each message ``_timestamp`` as it parses it: its arrival)."""
        arrival = float(getattr(msg, "_timestamp", None) or time.time())
        return self._clocks[kind].date(boot_seconds(msg), arrival) + self.link.offset

    def pose(self) -> Pose:
        tel = self.mav.telemetry
        return Pose(self.position.north, self.position.east, tel.depth, tel.heading)

    def _on_control(self, packet: ControlPacket) -> None:
        now = self.mav.telemetry.time
        self.shore_heard_at = now  # only authentic packets get here
        if packet.key_epoch > self.state.key_epoch % 256 and packet.key_epoch in {v % 256 for v in self.keys}:
            self.state.key_epoch = next(v for v in self.keys if v % 256 == packet.key_epoch)
            log.warning(
                "shore uses key version %d: check-points signed with it from now on (confirms it)",
                self.state.key_epoch,
            )
            self.fsm.checkpoint_due = True
        if packet.command is Command.SYNC:
            self._on_sync(packet)
            return
        previous = (self.fsm.status.last_command, self.fsm.status.command_status)
        status, reason = self.fsm.on_control(packet, self.pose(), now)
        if previous[0] and previous[0] != packet.seq and previous[0] != self.fsm.status.commanded:
            # the previous command is over (a move still steered to is reported when it arrives)
            final = (
                previous[1]
                if previous[1] in (CommandStatus.EXECUTED, CommandStatus.REFUSED)
                else (CommandStatus.SUPERSEDED)
            )
            self.state.settled = [*self.state.settled, Settled(previous[0], final.name)][-16:]
        self.plume.threshold = self.fsm.status.params.get("plume_threshold", self.plume.threshold)
        log.info("control seq %d %s: %s %s", packet.seq, packet.command.name, status.name, reason.name)
        self._persist()  # the replay window is on disk before anything acts on the command

    def _on_sync(self, packet: ControlPacket) -> None:
        """The shore's authenticated heartbeat: its clock, corrected both ways when it is off by more
        than the SYNC's own error (whole seconds, stamped before its seconds of travel and airtime: a
        smaller correction would move the samples' clock back and forth for nothing), and maybe a request
        to restart the chains. The replay floor is the receiver's: a SYNC never moves it back. A
        scheduled SYNC moves nothing: its stamp is when it was due, not the shore's clock when it left."""
        if packet.flags & ControlFlag.SCHEDULED:
            log.info(
                "scheduled SYNC %d (due %d): the shore's gateway is cut off from its center",
                packet.seq,
                packet.time,
            )
            self._persist()
            return
        local = time.time()
        error = packet.time - (local + self.link.offset)
        if abs(error) > CLOCK_DEADBAND:
            self.link.offset = self.state.clock_offset = packet.time - local
            log.warning(
                "clock corrected by %+.0f s from the shore's SYNC (offset now %+.0f s)",
                error,
                self.link.offset,
            )
        if packet.param_id & SYNC_RESTART_CHAINS:
            log.warning("shore asked to restart the sample chains (it lost their state)")
            forgotten = self.compressor.restart_chains()  # they continue from states the shore lost
            self.link.withdraw([self._flying.pop(q) for q in forgotten if q in self._flying])
        self._persist()

    def _on_delivered(self, packet: bytes) -> Callable[[bool], None]:
        """What to do when a priority packet is delivered: remember it for the next check-point's MAC."""

        def done(delivered: bool) -> None:
            if delivered:
                self.state.uncovered = [*self.state.uncovered, Uncovered(packet[1], auth.packet_hash(packet))]
                self._dirty = True

        return done

    def now(self) -> float:
        """The local clock corrected by the shore's SYNC time."""
        return time.time() + self.link.offset

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
                self.compressor.add(
                    Stream.ENVIRONMENTAL, stamp, [temperature, depth, oxygen], urgent=event is not None
                )
                if event is not None:
                    self._plume(event, pose)

    def _plume(self, event: PlumeEvent, pose: Pose) -> None:
        bearing = event.bearing if event.bearing is not None else pose.heading
        d = self.config.explore_distance
        target = (
            pose.north + d * math.cos(math.radians(bearing)),
            pose.east + d * math.sin(math.radians(bearing)),
            pose.depth,
        )
        log.warning(
            "warm water: %.2f degC (baseline %.2f); turning to %.0f deg",
            event.temperature,
            event.baseline,
            bearing,
        )
        self.fsm.on_unpredictable(True, target)

    # --- outputs --------------------------------------------------------------------------------

    def _unvouched(self) -> list[int]:
        """The seqs of the delivered packets no check-point covers yet, nor one on its way."""
        return [u.seq for u in self.state.uncovered if u.seq not in self._vouching]

    def _room(self) -> int:
        """How many priority packets may be numbered now: a check-point numbered after them must still
        reach (``COVER_BITS`` back) every delivered one no check-point on its way covers, and every one in
        flight (a check-point lost for good leaves those it covered out of reach: unverifiable)."""
        outstanding = self._unvouched() + self.compressor.in_flight()
        used = max(((self.state.packet_seq - q) % 256 for q in outstanding), default=0)
        return max(0, MAX_WINDOW - used)

    def _send_packets(self) -> None:
        self.compressor.follow(self.link.capacity)
        self.compressor.silence_said(self.fsm.status.params["checkpoint_interval"])
        for stream, encoded in self.compressor.ready(self.now(), self.state.packet_seq, self._room()):
            urgent = encoded.packet.priority is Priority.TIME_SENSITIVE
            packet = encoded.packet  # numbered with the vehicle's counter: version 4 names states by it
            self.state.packet_seq += 1
            frame = auth.tag_priority(packet, self.keys[self.state.key_epoch], self.config.address)
            covered = self._on_delivered(frame)
            self._flying[packet.seq] = frame

            def resolved(ok: bool, seq: int = packet.seq, covered: Callable[[bool], None] = covered) -> None:
                self._flying.pop(seq, None)
                again = self.compressor.resolve(seq, ok)
                covered(ok)
                if again:  # coded again after a loss in the window: the old packets go no more
                    self.link.withdraw([self._flying.pop(q) for q in again if q in self._flying])
                    log.info("packets seq %s withdrawn: coded again after packet %d was lost", again, seq)

            self.link.send(frame, urgent, resolved)
            self.state.priority_count += 1
            self._dirty = True
            log.info(
                "priority packet seq %d (%s, %d ticks, %d surprises) queued",
                packet.seq,
                stream.name.lower(),
                encoded.ticks,
                encoded.nonzero,
            )
            if self._water_surprised(encoded) and not urgent:
                self.fsm.on_unpredictable(False, None)

    def _water_surprised(self, encoded: EncodedPacket) -> bool:
        """Whether the packet carries water the shore could not predict (temperature, oxygen): the
        paper's unpredictable environmental data. The vehicle's own motion (its depth in the same
        stream, its IMU sharing the packet) is not."""
        spec = self.streams[Stream.ENVIRONMENTAL]
        counts = encoded.surprises.get(spec.name, [])
        return any(n for channel, n in zip(spec.channels, counts, strict=False) if channel in WATER_CHANNELS)

    def settled(self, last: int) -> int:
        """The check-point's ``settled`` byte: final statuses of the four commands before ``last``."""
        finals = {s.seq: CommandStatus[s.status] for s in self.state.settled}
        return pack_settled([finals.get(last - k) for k in range(1, 5)])

    def checkpoint(self) -> CheckpointPacket:
        tel, s, pose = self.mav.telemetry, self.fsm.status, self.position.in_fleet_frame(self.pose())
        flags = (
            (1 if self.position.source != "dead_reckoning" else 0)
            | (2 if tel.armed else 0)
            | (4 if s.state is MissionState.LINK_LOST else 0)
        )
        version = self.config.protocol
        oxygen = CheckpointPacket.field("oxygen", version)  # its top value says "none"
        measured = CheckpointPacket.clamped(
            version,
            north=pose.north,
            east=pose.east,
            depth=pose.depth,
            battery=tel.battery,
            temperature=tel.temperature or 0.0,
            oxygen=min(tel.oxygen, oxygen.hi - oxygen.resolution) if tel.oxygen is not None else oxygen.hi,
        )
        now = int(self.now())
        quiet = (
            quiet_of(now, self.compressor.predictable_until(self.now())) if version >= 4 else QUIET_UNKNOWN
        )
        return CheckpointPacket(
            seq=self.state.packet_seq % 256,
            time=now,
            quiet=quiet,
            state=s.state,
            mission_id=s.mission or 0,
            waypoint=min(s.waypoint, 255),
            heading=round(pose.heading, 2) % 360.0,
            last_command=s.last_command & 0xFFFF,
            command_status=s.command_status,
            reason=s.reason,
            settled=self.settled(s.last_command),
            flags=flags,
            north=measured["north"],
            east=measured["east"],
            depth=measured["depth"],
            battery=measured["battery"],
            temperature=measured["temperature"],
            oxygen=measured["oxygen"] if tel.oxygen is not None else OXYGEN_NONE,
            version=version,
        )

    def _reachable(self, seq: int) -> list[Uncovered]:
        """The uncovered packets a check-point with ``seq`` can still cover (the others are dropped)."""
        keep = [u for u in self.state.uncovered if (seq - 1 - u.seq) % 256 < COVER_BITS]
        if len(keep) < len(self.state.uncovered):
            log.warning(
                "%d delivered packet(s) fell out of reach of any check-point: they stay unverified",
                len(self.state.uncovered) - len(keep),
            )
            self.state.uncovered = keep
        return keep

    def _send_checkpoint(self) -> None:
        packet, report, self._report = self.checkpoint(), self._report, None
        if (
            report is not None
            and report.last_command == packet.last_command
            and report.command_status is packet.command_status
        ):
            packet = with_seq(report, packet.seq)  # the pose and time of the tick the status changed
        covered = self._reachable(packet.seq)
        sync = self.link.receiver.sync
        packet = replace(
            packet,
            covered=cover_bitmap(packet.seq, [u.seq for u in covered]),
            unsynced=sync.unsynced,
            holds_next_key=self.state.key_epoch + 1 in self.keys,
        )
        oldest_first = sorted(covered, key=lambda u: (packet.seq - 1 - u.seq) % 256, reverse=True)
        hashes = [u.hash for u in oldest_first]
        frame = auth.sign_checkpoint(
            packet, self.keys[self.state.key_epoch], self.state.key_epoch, self.config.address, hashes
        )
        if sync.unsynced:
            sync.challenge(frame[-CHECKPOINT_MAC_SIZE:])
            self._challenged = self.mav.telemetry.time

        self._vouching.update(u.seq for u in covered)

        def delivered(ok: bool, done: list[Uncovered] = covered) -> None:
            self._vouching.difference_update(u.seq for u in done)
            if ok:  # the shore holds the MAC for these now: no later check-point needs to cover them
                self.state.uncovered = [u for u in self.state.uncovered if u not in done]
                self._dirty = True

        self.state.packet_seq += 1
        self.link.send(frame, urgent=True, on_result=delivered)
        self.fsm.checkpoint_sent(self.mav.telemetry.time)
        self._dirty = True
        log.info(
            "check-point seq %d queued: %s, command %d %s",
            packet.seq,
            packet.state.name,
            packet.last_command,
            packet.command_status.name,
        )

    def _persist(self) -> None:
        self.state.mission = self.fsm.status.to_dict()
        self.state.north, self.state.east = self.position.north, self.position.east
        self.state.speed, self.state.thrust = self.position.speed, self.navigator.thrust
        self.state.yaw = self.mav.telemetry.yaw
        self.state.time = self.mav.telemetry.time if self.mav.telemetry.time else self.state.time
        self.state.outbox = [Queued(urgent, data) for urgent, data in self.link.pending()]
        self.state.replay = self.link.receiver.window.to_dict()  # the answering SYNC set its floor
        self.state.sync_counter = self.link.receiver.sync.counter
        self.state.save(self.state_path)
        self._dirty = False

    # --- the loop -------------------------------------------------------------------------------

    def tick(self) -> None:
        tel = self.mav.telemetry
        if not self.mav.connected or not tel.fresh("ATTITUDE") or not tel.fresh("SCALED_PRESSURE2", 5.0):
            return  # never steer, dead-reckon or report on default heading and depth
        self.navigator.step()
        pose = self.pose()
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
        oldest = max(((self.state.packet_seq - q) % 256 for q in self._unvouched()), default=0)
        if oldest >= COVER_BITS - 4:  # a check-point now, while the oldest delivered packet is in reach
            self.fsm.checkpoint_due = True
        if (
            self.link.receiver.sync.unsynced
            and tel.time - self._challenged >= self.fsm.status.params["checkpoint_interval"]
        ):
            self.fsm.checkpoint_due = True  # even while waiting: a new challenge until one is answered
        if self.fsm.checkpoint_due and self.link.backlog < 4 + self.compressor.window:
            self._send_checkpoint()
        if self._dirty or self.fsm.status.to_dict() != before or tel.time - self._persisted_at >= 1.0:
            self._persist()  # dead-reckoned position is state too: at least once a second of vehicle time
            self._persisted_at = tel.time

    async def run(self, stop: asyncio.Event) -> None:
        self.mav.start()
        await self.driver.start()
        log.info(
            "agent %d up: modem %s, MAVLink %s, state %s",
            self.config.address,
            self.config.modem_url,
            self.config.mavlink_url,
            self.fsm.state.name,
        )
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
    parser.add_argument(
        "--check",
        action="store_true",
        help="check the configuration, the modem's serial port and the autopilot before a dive: each "
        "problem on one line, exit 0 if ready, 1 if not",
    )


def run(args: argparse.Namespace) -> int:
    from vehicle_agent import check  # it reads AgentConfig from here

    if args.check:
        return check.check(args.config)
    loaded = check.starting(args.config)
    if loaded is None or loaded.config is None:
        return check.EXIT_CONFIG
    config, plans = loaded.config, loaded.plans

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await Agent(config, plans).run(stop)

    asyncio.run(main())
    return 0
