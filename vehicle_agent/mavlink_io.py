"""The agent's MAVLink side: read ArduSub's telemetry, send commands as the ground station (id 255).

A reader thread keeps the latest of each message the agent uses and hands samples to listeners; every
message received is also written to a ``.tlog`` (a UNIX-microsecond stamp and the raw frame, as
pymavlink's logs are), since ``setup_logfile`` writes nothing on network links. If the link drops the
reader reconnects with backoff; callers see ``connected`` go false, never an exception.

Commands follow ArduSub's rules: MANUAL_CONTROL is only accepted from SYSID_MYGCS
(255), so the agent uses that system id; depth targets are SET_POSITION_TARGET_GLOBAL_INT in a
depth-holding mode; headings are SET_ATTITUDE_TARGET with the throttle ignored, which ArduSub follows
for 5 s only; with a position fix, GUIDED and SET_POSITION_TARGET_LOCAL_NED.
"""

from __future__ import annotations

import logging
import math
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from tacit.private import open_private
from tacit.streams import ENV_PERIOD, IMU_PERIOD

log = logging.getLogger("tacit.agent.mavlink")

GCS_SYSTEM_ID = 255
STREAMS_HZ = {  # the sample streams' messages at their streams' rates (tacit.streams), the rest as navigation needs
    mav.MAVLINK_MSG_ID_RAW_IMU: 1 / IMU_PERIOD, mav.MAVLINK_MSG_ID_ATTITUDE: 10.0,
    mav.MAVLINK_MSG_ID_SCALED_PRESSURE2: 1 / ENV_PERIOD,
    mav.MAVLINK_MSG_ID_VFR_HUD: 4.0, mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 4.0, mav.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
    mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 4.0, mav.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
}  # fmt: skip
ATMOSPHERE_HPA = 1013.25
WATER_HPA_PER_M = 98.0665  # fresh water


@dataclass
class VehicleTelemetry:
    """The latest of what the vehicle reports; ``time`` is the vehicle's own clock (s since boot)."""

    time: float = 0.0
    yaw: float = 0.0  # rad
    depth: float = 0.0
    temperature: float | None = None
    oxygen: float | None = None
    battery: float = 0.0
    armed: bool = False
    mode: int = -1
    local: tuple[float, float, float] | None = None  # north, east, down with a position estimate
    gps: tuple[float, float] | None = None  # lat, lon with a 3D fix
    imu: tuple[int, ...] | None = None
    heartbeats: int = 0
    seen: dict[str, float] = field(default_factory=dict)  # message type -> vehicle time last received

    def fresh(self, kind: str, max_age: float = 2.5) -> bool:
        """A fix is only as good as its last message: a position source that stopped talking is gone."""
        return self.time - self.seen.get(kind, -1e9) <= max_age

    @property
    def position_fix(self) -> tuple[float, float, float] | None:
        return self.local if self.local is not None and self.fresh("LOCAL_POSITION_NED", 0.8) else None

    @property
    def gps_fix(self) -> tuple[float, float] | None:
        return self.gps if self.gps is not None and self.fresh("GPS_RAW_INT") else None

    @property
    def heading(self) -> float:
        return math.degrees(self.yaw) % 360.0


def _closed() -> None:
    raise ConnectionError("the vehicle closed the connection")


def _raise_on_close(conn: mavutil.mavfile) -> None:
    """A stream socket's end (TCP, Unix) as an error: pymavlink prints "EOF on TCP socket" and returns no
    data, which a blocking read asks for again in a loop (tens of thousands of lines until its timeout)."""
    for name in ("handle_eof", "handle_disconnect"):
        if hasattr(conn, name):
            setattr(conn, name, _closed)


class MavlinkLink:
    def __init__(self, url: str, tlog: str | Path | None = None, reconnect_max: float = 10.0) -> None:
        self.url = url
        self.telemetry = VehicleTelemetry()
        self.connected = False
        self.listeners: list[Callable[[str, object], None]] = []
        self.reconnect_max = reconnect_max
        self._conn: mavutil.mavfile | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._write_lock = threading.Lock()
        self._tlog = open_private(tlog, "ab") if tlog else None
        self._updated = time.monotonic()

    # --- lifecycle ------------------------------------------------------------------------------

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="mavlink", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread:
            self._thread.join(timeout=5)
        if self._conn:
            self._conn.close()
        if self._tlog:
            self._tlog.close()

    def wait_connected(self, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not self.connected and time.monotonic() < deadline:
            time.sleep(0.05)
        return self.connected

    def _run(self) -> None:
        delay = 0.5
        while not self._stop.is_set():
            try:
                self._conn = mavutil.mavlink_connection(
                    self.url,
                    source_system=GCS_SYSTEM_ID,
                    source_component=190,
                    autoreconnect=False,
                    robust_parsing=True,
                )
                _raise_on_close(self._conn)
                if self._conn.wait_heartbeat(timeout=10) is None:
                    raise ConnectionError("no heartbeat")
                self.connected = True
                delay = 0.5
                log.info("MAVLink connected to %s (system %d)", self.url, self._conn.target_system)
                self._request_streams()
                self._read()
            except (OSError, ConnectionError, mav.MAVError) as exc:
                log.warning("MAVLink %s: %s; reconnecting in %.1f s", self.url, exc, delay)
            self.connected = False
            if self._conn:
                self._conn.close()
            self._stop.wait(delay)
            delay = min(delay * 2, self.reconnect_max)

    def _read(self) -> None:
        silent_since = time.monotonic()
        while not self._stop.is_set():
            msg = self._conn.recv_match(blocking=True, timeout=0.5)  # type: ignore[union-attr]
            if msg is None:
                if time.monotonic() - silent_since > 5:
                    raise ConnectionError("no MAVLink message for 5 s")
                continue
            silent_since = time.monotonic()
            if msg.get_type() == "BAD_DATA":
                continue
            if self._tlog:
                self._tlog.write(struct.pack(">Q", int(msg._timestamp * 1e6)) + bytes(msg.get_msgbuf()))
            self._apply(msg)

    def _request_streams(self) -> None:
        for mid, hz in STREAMS_HZ.items():
            self.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mid, 1e6 / hz)

    # --- telemetry ------------------------------------------------------------------------------

    def _apply(self, msg: mav.MAVLink_message) -> None:
        t = self.telemetry
        kind = msg.get_type()
        stamp = getattr(msg, "time_boot_ms", None)
        if stamp is None and hasattr(msg, "time_usec") and kind == "RAW_IMU":
            stamp = msg.time_usec / 1000
        if stamp:
            t.time = stamp / 1000.0
        t.seen[kind] = t.time
        if kind == "HEARTBEAT" and msg.get_srcSystem() == (self._conn.target_system if self._conn else 1):
            t.armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
            t.mode = msg.custom_mode
            t.heartbeats += 1
        elif kind == "ATTITUDE":
            t.yaw = msg.yaw
        elif kind == "SCALED_PRESSURE2":
            t.depth = max(0.0, (msg.press_abs - ATMOSPHERE_HPA) / WATER_HPA_PER_M)
            t.temperature = msg.temperature / 100.0
        elif kind == "NAMED_VALUE_FLOAT" and msg.name.rstrip("\0") == "DO":
            t.oxygen = msg.value
        elif kind == "SYS_STATUS":
            t.battery = msg.voltage_battery / 1000.0
        elif kind == "LOCAL_POSITION_NED":
            t.local = (msg.x, msg.y, msg.z)
        elif kind == "GPS_RAW_INT":
            t.gps = (msg.lat / 1e7, msg.lon / 1e7) if msg.fix_type >= mav.GPS_FIX_TYPE_3D_FIX else None
        elif kind == "RAW_IMU":
            t.imu = (
                msg.xacc,
                msg.yacc,
                msg.zacc,
                msg.xgyro,
                msg.ygyro,
                msg.zgyro,
                msg.xmag,
                msg.ymag,
                msg.zmag,
            )
        self._updated = time.monotonic()
        for listener in self.listeners:
            listener(kind, msg)

    # --- commands -------------------------------------------------------------------------------

    def _send(self, build: Callable[[mavutil.mavfile], None]) -> bool:
        conn = self._conn
        if conn is None or not self.connected:
            return False
        try:
            with self._write_lock:
                build(conn)
            return True
        except OSError as exc:
            log.warning("MAVLink send failed: %s", exc)
            return False

    def command(self, command: int, *params: float) -> bool:
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        return self._send(
            lambda c: c.mav.command_long_send(c.target_system, c.target_component, command, 0, *p)
        )

    def arm(self, armed: bool = True) -> bool:
        return self.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1 if armed else 0)

    def set_mode(self, mode: int) -> bool:
        return self.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode)

    def depth_target(self, depth: float) -> bool:
        mask = 0b110111111011  # only z
        return self._send(
            lambda c: c.mav.set_position_target_global_int_send(
                0,
                c.target_system,
                c.target_component,
                mav.MAV_FRAME_GLOBAL_INT,
                mask,
                0,
                0,
                -depth,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
            )
        )

    def heading_target(self, heading_deg: float) -> bool:
        half = math.radians(heading_deg) / 2
        q = [math.cos(half), 0.0, 0.0, math.sin(half)]
        return self._send(
            lambda c: c.mav.set_attitude_target_send(
                0,
                c.target_system,
                c.target_component,
                mav.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE,
                q,
                0,
                0,
                0,
                0,
            )
        )

    def manual(self, x: int = 0, y: int = 0, z: int = 500, r: int = 0) -> bool:
        return self._send(lambda c: c.mav.manual_control_send(c.target_system, x, y, z, r, 0))

    def position_target(self, north: float, east: float, depth: float) -> bool:
        mask = 0b110111111000  # position only
        return self._send(
            lambda c: c.mav.set_position_target_local_ned_send(
                0,
                c.target_system,
                c.target_component,
                mav.MAV_FRAME_LOCAL_NED,
                mask,
                north,
                east,
                depth,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
            )
        )
