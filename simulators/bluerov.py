"""A BlueROV2 as ArduSub drives it: dynamics of a small ROV plus ArduSub's rules (GUIDED needs a
position fix; MANUAL_CONTROL is taken only from SYSID_MYGCS).

Dynamics (body frame, per axis): m_eff dv/dt = F_max * input - c_drag * v |v|; the water current adds
to the ground velocity. With F_max = 40 N and c_drag = 17.8 N s^2/m^2 the top speed is 1.5 m/s, as a
BlueROV2's. Yaw follows a rate command with a 0.3 s lag, at most 90 deg/s.

ArduSub's rules kept here:
- modes by number (STABILIZE 0 ... SURFTRAK 21); GUIDED, AUTO, POSHOLD, CIRCLE and SURFACE are refused
  without a position estimate (GPS at the surface, or a DVL/USBL when ``position_source`` is set);
- ALT_HOLD holds the depth it was entered at, or the depth set by SET_POSITION_TARGET_GLOBAL_INT;
- an attitude target (SET_ATTITUDE_TARGET) is followed for 5 s, then dropped;
- MANUAL_CONTROL from any system other than SYSID_MYGCS (255) is ignored; pilot input older than
  FS_PILOT_TIMEOUT (3 s) falls back to neutral;
- disarmed, the thrusters do nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from simulators.parameters import Parameters

MODES = {
    "STABILIZE": 0, "ACRO": 1, "ALT_HOLD": 2, "AUTO": 3, "GUIDED": 4, "CIRCLE": 7, "SURFACE": 9,
    "POSHOLD": 16, "MANUAL": 19, "MOTOR_DETECT": 20, "SURFTRAK": 21,
}  # fmt: skip
MODE_NAMES = {number: name for name, number in MODES.items()}
NEEDS_POSITION = {MODES[m] for m in ("GUIDED", "AUTO", "POSHOLD", "CIRCLE", "SURFACE")}
DEPTH_HOLD_MODES = {MODES[m] for m in ("ALT_HOLD", "GUIDED", "POSHOLD", "AUTO", "CIRCLE", "SURFTRAK")}

F_MAX = 40.0
C_DRAG = 17.8
M_EFF = 20.0
YAW_RATE_MAX = math.radians(90.0)
YAW_TAU = 0.3
ATTITUDE_TARGET_TIMEOUT = 5.0
PILOT_TIMEOUT = 3.0
SURFACE_DEPTH = 0.3


@dataclass
class Thrust:
    """Normalised inputs -1..1: forward, lateral (right), vertical (down), yaw rate (clockwise)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    r: float = 0.0


@dataclass
class BlueROV2:
    north: float = 0.0
    east: float = 0.0
    depth: float = 0.0
    yaw: float = 0.0  # rad, clockwise from north
    u: float = 0.0  # body forward speed through water
    v: float = 0.0  # body lateral speed
    w: float = 0.0  # down speed
    yaw_rate: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    armed: bool = False
    mode: int = MODES["MANUAL"]
    position_source: bool = False
    current: tuple[float, float] = (0.0, 0.0)  # m/s north, east
    battery_v: float = 16.0
    params: Parameters = field(default_factory=Parameters.ardusub)  # a real ArduSub's (SYSID_MYGCS 255, ...)
    depth_target: float | None = None
    yaw_target: float | None = None
    yaw_target_time: float = -math.inf
    position_target: tuple[float, float, float] | None = None
    pilot: Thrust = field(default_factory=Thrust)
    pilot_time: float = -math.inf
    time: float = 0.0
    accel_body: tuple[float, float, float] = (0.0, 0.0, 0.0)

    # --- ArduSub's command rules ------------------------------------------------------------------

    @property
    def has_position(self) -> bool:
        return self.position_source or self.depth < SURFACE_DEPTH

    def set_mode(self, mode: int) -> tuple[bool, str]:
        """Change mode as ArduSub would; returns (accepted, reason)."""
        if mode not in MODE_NAMES:
            return False, f"unknown mode {mode}"
        if mode in NEEDS_POSITION and not self.has_position:
            return False, f"{MODE_NAMES[mode]} requires a position estimate"
        if mode in DEPTH_HOLD_MODES and self.mode not in DEPTH_HOLD_MODES:
            self.depth_target = self.depth
        if mode == MODES["GUIDED"]:
            self.position_target = (self.north, self.east, self.depth)
        self.mode = mode
        return True, ""

    def arm(self, armed: bool) -> None:
        self.armed = armed
        if armed and self.mode in DEPTH_HOLD_MODES:
            self.depth_target = self.depth

    def manual_control(self, sender_sysid: int, x: int, y: int, z: int, r: int) -> bool:
        """MANUAL_CONTROL (x, y, r in -1000..1000; z 0..1000 with 500 neutral). False if ignored."""
        if sender_sysid != int(self.params["SYSID_MYGCS"]):
            return False
        clip = lambda value: max(-1.0, min(1.0, value))  # noqa: E731
        self.pilot = Thrust(clip(x / 1000), clip(y / 1000), clip((500 - z) / -500), clip(r / 1000))
        self.pilot_time = self.time
        return True

    def set_depth_target(self, depth: float) -> bool:
        """SET_POSITION_TARGET_GLOBAL_INT's altitude in a depth-holding mode."""
        if self.mode not in DEPTH_HOLD_MODES:
            return False
        self.depth_target = max(0.0, depth)
        return True

    def set_attitude_target(self, yaw: float) -> None:
        self.yaw_target = yaw % (2 * math.pi)
        self.yaw_target_time = self.time

    def set_position_target(self, north: float, east: float, depth: float) -> bool:
        if self.mode != MODES["GUIDED"] or not self.has_position:
            return False
        self.position_target = (north, east, max(0.0, depth))
        self.depth_target = max(0.0, depth)
        return True

    # --- dynamics ---------------------------------------------------------------------------------

    def _command(self) -> Thrust:
        timeout = self.params.get("FS_PILOT_TIMEOUT", PILOT_TIMEOUT)
        pilot = self.pilot if self.time - self.pilot_time <= timeout else Thrust()
        cmd = Thrust(pilot.x, pilot.y, pilot.z, pilot.r)
        if self.mode == MODES["GUIDED"] and self.position_target is not None:
            cmd = self._guided(cmd)
        if self.mode in DEPTH_HOLD_MODES and self.depth_target is not None:
            if abs(pilot.z) > 0.05:  # the pilot's vertical stick moves the held depth
                self.depth_target = max(0.0, self.depth + pilot.z)
            else:
                cmd.z = max(-1.0, min(1.0, 0.8 * (self.depth_target - self.depth) - 1.2 * self.w))
        if self.yaw_target is not None and self.time - self.yaw_target_time <= ATTITUDE_TARGET_TIMEOUT:
            error = (self.yaw_target - self.yaw + math.pi) % (2 * math.pi) - math.pi
            cmd.r = max(-1.0, min(1.0, 2.0 * error))
        return cmd

    def _guided(self, cmd: Thrust) -> Thrust:
        tn, te, _ = self.position_target  # type: ignore[misc]
        dn, de = tn - self.north, te - self.east
        distance = math.hypot(dn, de)
        if distance < 0.2:
            return Thrust(0.0, 0.0, cmd.z, cmd.r)
        speed = min(1.0, distance * 0.4)
        fwd = (dn * math.cos(self.yaw) + de * math.sin(self.yaw)) / distance
        lat = (-dn * math.sin(self.yaw) + de * math.cos(self.yaw)) / distance
        return Thrust(speed * fwd, speed * lat, cmd.z, cmd.r)

    def step(self, dt: float) -> None:
        cmd = self._command() if self.armed else Thrust()
        ax = (F_MAX * cmd.x - C_DRAG * self.u * abs(self.u)) / M_EFF
        ay = (F_MAX * cmd.y - C_DRAG * self.v * abs(self.v)) / M_EFF
        az = (F_MAX * cmd.z - C_DRAG * self.w * abs(self.w)) / M_EFF
        self.accel_body = (ax, ay, az)
        self.u += ax * dt
        self.v += ay * dt
        self.w += az * dt
        self.yaw_rate += (cmd.r * YAW_RATE_MAX - self.yaw_rate) * min(1.0, dt / YAW_TAU)
        self.yaw = (self.yaw + self.yaw_rate * dt) % (2 * math.pi)
        vn, ve, _ = self.ground_velocity
        self.north += vn * dt
        self.east += ve * dt
        self.depth = max(0.0, self.depth + self.w * dt)
        if self.depth == 0.0 and self.w < 0:
            self.w = 0.0
        self.roll = 0.02 * math.sin(self.time * 0.7)
        self.pitch = 0.05 * self.u / 1.5
        load = abs(cmd.x) + abs(cmd.y) + abs(cmd.z)
        self.battery_v = max(13.0, self.battery_v - dt * (0.00002 + 0.0001 * load))
        self.time += dt

    @property
    def ground_velocity(self) -> tuple[float, float, float]:
        vn = self.u * math.cos(self.yaw) - self.v * math.sin(self.yaw) + self.current[0]
        ve = self.u * math.sin(self.yaw) + self.v * math.cos(self.yaw) + self.current[1]
        return vn, ve, self.w
