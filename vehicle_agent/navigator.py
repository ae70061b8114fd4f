"""Steering the BlueROV2 to a target, with or without a position fix, and knowing where it is.

Without a fix (the usual BlueROV2): depth by ALT_HOLD depth targets, heading by attitude targets re-sent
twice a second (ArduSub drops them after 5 s), translation by MANUAL_CONTROL forward thrust while the
position is dead-reckoned along the measured heading with the dynamics of a quadratic-drag hull,
dv/dt = (cruise_speed^2 * thrust / cruise_thrust - v |v|) / drag_length, whose steady speed is
cruise_speed at cruise_thrust and which coasts for metres when the thrust stops (a BlueROV2 does: it has
almost no linear drag). On arrival the navigator brakes with reverse thrust until it has stopped. Calibrate
cruise_speed once per vehicle (time a run at cruise_thrust). At the surface each GPS fix pulls the
estimate towards it by ``gps_gain`` (a complementary filter: dead reckoning is smooth but drifts, GPS
does not drift but is noisy by a metre or more), the first fix sets it outright. With a fix (DVL/USBL: LOCAL_POSITION_NED): GUIDED and position targets.

Frames: the agent steers, plans and fences in its own frame, north and east of its home (a mission plan's
waypoints, RETURN_HOME, the geofence radius are all relative to home). A fleet shares one frame (one
origin) and each vehicle starts at ``home`` in it (``[nav] home = [north, east]``): what the vehicle
reports (check-points) and what a position source measures (LOCAL_POSITION_NED, in the fleet's frame) are
moved between the two here, and nowhere else. With GPS the first fix is the vehicle's home.

All times are the vehicle's own clock (``VehicleTelemetry.time``), so the same code runs against a simulator
running faster than real time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from tacit import navigation
from tacit.navigation import Origin, Pose, Target
from vehicle_agent.mavlink_io import MavlinkLink, VehicleTelemetry

ALT_HOLD, GUIDED = 2, 4
PILOT_TIMEOUT = 3.0  # s: ArduSub's FS_PILOT_TIMEOUT default; manual control older than this is neutral


@dataclass
class NavConfig:
    cruise_thrust: int = 400  # MANUAL_CONTROL x, -1000..1000
    cruise_speed: float = 0.95  # m/s at cruise_thrust (calibrate)
    drag_length: float = 1.1  # m: effective mass / quadratic drag coefficient (calibrate with a coast-down)
    arrive_radius: float = 0.5  # m
    heading_tolerance: float = 8.0  # deg: turn in place before moving when off by more
    depth_tolerance: float = 0.25  # m
    gps_gain: float = 0.1  # per fix (1 Hz): a ~10 s time constant
    home: tuple[float, float] = (0.0, 0.0)  # m north, east of the fleet's origin where this vehicle starts

    def __post_init__(self) -> None:
        north, east = self.home  # a TOML list of two numbers; anything else is a configuration error
        self.home = (float(north), float(east))


class PositionEstimate:
    def __init__(self, config: NavConfig, origin: Origin | None = None) -> None:
        self.config = config
        self.origin = origin
        self.north = 0.0
        self.east = 0.0
        self.speed = 0.0
        self.source = "dead_reckoning"
        self._last_time: float | None = None
        self._gps_used: float | None = None
        self._fix_used: float | None = None
        self._resumed_thrust: int | None = None
        self._resumed_yaw = 0.0

    def _integrate(self, dt: float, thrust: int, yaw: float) -> None:
        push = self.config.cruise_speed**2 * thrust / self.config.cruise_thrust
        steps = max(1, math.ceil(dt / 0.05))
        for _ in range(steps):
            self.speed += (push - self.speed * abs(self.speed)) / self.config.drag_length * (dt / steps)
            self.north += self.speed * math.cos(yaw) * (dt / steps)
            self.east += self.speed * math.sin(yaw) * (dt / steps)

    def resume(self, north: float, east: float, speed: float, thrust: int, time: float, yaw: float) -> None:
        """Start from a persisted estimate (an agent restart): the gap until the next update is
        integrated too, along the saved heading, at the last thrust until ArduSub's pilot-input
        timeout, then coasting."""
        self.north, self.east, self.speed, self._last_time = north, east, speed, time
        self._resumed_thrust, self._resumed_yaw = thrust, yaw

    def from_fleet(self, north: float, east: float) -> tuple[float, float]:
        """A point of the fleet's frame in this vehicle's (relative to its home)."""
        return north - self.config.home[0], east - self.config.home[1]

    def to_fleet(self, north: float, east: float) -> tuple[float, float]:
        """A point of this vehicle's frame in the fleet's."""
        return north + self.config.home[0], east + self.config.home[1]

    def in_fleet_frame(self, pose: Pose) -> Pose:
        """``pose`` as the vehicle reports it (check-points): in the fleet's frame."""
        north, east = self.to_fleet(pose.north, pose.east)
        return replace(pose, north=north, east=east)

    def update(self, tel: VehicleTelemetry, thrust: int) -> None:
        gap = 0.0 if self._last_time is None else max(0.0, tel.time - self._last_time)
        self._last_time = tel.time
        if gap > 1.0 and self._resumed_thrust is not None:  # the agent was down: what did the vehicle do?
            self._integrate(min(gap, PILOT_TIMEOUT), self._resumed_thrust, self._resumed_yaw)
            self._integrate(max(0.0, gap - PILOT_TIMEOUT), 0, self._resumed_yaw)
        else:
            self._integrate(min(gap, 1.0), thrust, tel.yaw)
        self._resumed_thrust = None
        self.source = "dead_reckoning"
        fix_time = tel.seen.get("LOCAL_POSITION_NED")
        if tel.position_fix is not None and fix_time != self._fix_used:  # a new fix: take it
            self._fix_used = fix_time
            self.north, self.east = self.from_fleet(tel.position_fix[0], tel.position_fix[1])
            self.source = "position_source"
            return
        gps_time = tel.seen.get("GPS_RAW_INT")
        if tel.gps_fix is not None and tel.depth < 0.3 and gps_time != self._gps_used:
            self._gps_used = gps_time
            first = self.origin is None
            if first:
                self.origin = Origin(*tel.gps_fix)
            north, east = self.origin.to_local(*tel.gps_fix)  # type: ignore[union-attr]
            gain = 1.0 if first else self.config.gps_gain
            self.north += gain * (north - self.north)
            self.east += gain * (east - self.east)
            self.source = "gps"


class Navigator:
    def __init__(self, link: MavlinkLink, config: NavConfig, position: PositionEstimate) -> None:
        self.link = link
        self.config = config
        self.position = position
        self.target: Target | None = None
        self.thrust = 0
        self.arrived = False
        self._sent: dict[str, float] = {}
        self._depth_sent: float | None = None

    def set_target(self, target: Target | None) -> None:
        self.target = target
        self.arrived = False

    @property
    def reached(self) -> Target | None:
        """The target the vehicle has arrived at (None while under way). ``arrived`` alone is about
        whatever was being steered to, which after a new command is the previous target."""
        return self.target if self.arrived else None

    def _due(self, what: str, period: float, now: float) -> bool:
        if now - self._sent.get(what, -math.inf) >= period or now < self._sent.get(what, 0.0):
            self._sent[what] = now
            return True
        return False

    def step(self) -> None:
        """One control step (call at 4 Hz or more of vehicle time)."""
        tel = self.link.telemetry
        now = tel.time
        self.position.update(tel, self.thrust)
        if self.target is None:
            self._manual(0, now)
            return
        if not tel.armed and self._due("arm", 2.0, now):
            self.link.arm(True)
        fix = tel.position_fix is not None and tel.depth >= 0.3  # at the surface GPS: ALT_HOLD still steers
        mode = GUIDED if fix else ALT_HOLD
        if tel.mode != mode and self._due("mode", 2.0, now):
            self.link.set_mode(mode)
        if fix:
            self._guided(tel, now)
        else:
            self._dead_reckoned(tel, now)

    def _depth(self, depth: float, now: float) -> None:
        if depth != self._depth_sent or self._due("depth", 5.0, now):
            self.link.depth_target(depth)
            self._depth_sent = depth

    def _manual(self, thrust: int, now: float) -> None:
        if thrust != self.thrust or self._due("manual", 0.25, now):
            self.link.manual(x=thrust)
        self.thrust = thrust

    def _guided(self, tel: VehicleTelemetry, now: float) -> None:
        target = self.target
        if self._due("position", 1.0, now):
            north, east = self.position.to_fleet(target.north, target.east)  # type: ignore[union-attr]
            self.link.position_target(north, east, target.depth)  # type: ignore[union-attr]
        self._check_arrival(tel)

    def _dead_reckoned(self, tel: VehicleTelemetry, now: float) -> None:
        target = self.target
        assert target is not None
        self._depth(target.depth, now)
        distance = math.hypot(target.north - self.position.north, target.east - self.position.east)
        if distance <= self.config.arrive_radius or self.arrived:
            heading = target.heading if target.heading is not None else tel.heading
            if self._due("heading", 0.5, now):
                self.link.heading_target(heading)
            braking = self.position.speed > 0.05
            self._manual(
                -int(self.config.cruise_thrust * min(1.0, self.position.speed / self.config.cruise_speed))
                if braking
                else 0,
                now,
            )
            self._check_arrival(tel)
            return
        bearing = math.degrees(
            math.atan2(target.east - self.position.east, target.north - self.position.north)
        )
        if self._due("heading", 0.5, now):
            self.link.heading_target(bearing % 360)
        error = abs(navigation.wrap180(bearing - tel.heading))
        if error > self.config.heading_tolerance:
            self._manual(0, now)
        else:
            slow = min(1.0, max(0.25, distance / 3.0))
            self._manual(int(self.config.cruise_thrust * slow * slow), now)

    def _check_arrival(self, tel: VehicleTelemetry) -> None:
        target = self.target
        assert target is not None
        close = (
            math.hypot(target.north - self.position.north, target.east - self.position.east)
            <= self.config.arrive_radius
        )
        self.arrived = self.arrived or (
            close and abs(tel.depth - target.depth) <= self.config.depth_tolerance
        )
