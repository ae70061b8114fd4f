"""The simulated BlueROV2's MAVLink side: what ArduSub sends and accepts, over BlueOS-like endpoints.

Endpoints: a TCP server (as BlueOS's ``tcp:127.0.0.1:5777`` for companion programs), a UDP server that
answers whoever wrote to it (ground stations use ``udpout:HOST:PORT``), and optionally a UDP client
that pushes telemetry to a fixed address (as BlueOS does to the topside at 14550).

Telemetry (default rates, changeable with MAV_CMD_SET_MESSAGE_INTERVAL): HEARTBEAT, SYS_STATUS,
BATTERY_STATUS, ATTITUDE, RAW_IMU and SCALED_IMU2 (noise and a fixed bias per axis, seeded),
SCALED_PRESSURE2 (Bar30: absolute pressure and water temperature), VFR_HUD, GLOBAL_POSITION_INT,
GPS_RAW_INT (a fix only at the surface), LOCAL_POSITION_NED (only with a position estimate), and
NAMED_VALUE_FLOAT "DO" (dissolved oxygen, mg/L, as a companion sensor extension would publish it).
SYS_STATUS's sensor bits are a healthy ArduSub's (``SENSORS_PRESENT``).

Parameters are a real ArduSub's (``simulators.parameters``), for ground stations as ArduSub serves
them: PARAM_REQUEST_LIST streams every one, in order, to the peer that asked; PARAM_REQUEST_READ (by
name or index) answers that peer; a PARAM_SET that takes is echoed to every peer, one that does not (a
name ArduSub lacks, NaN) gets no answer.
"""

from __future__ import annotations

import asyncio
import logging
import math
import random
from collections.abc import Callable
from typing import cast

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from simulators.bluerov import MODE_NAMES, MODES, BlueROV2
from simulators.clock import Scheduler
from simulators.environment import Environment
from tacit.navigation import Origin

log = logging.getLogger("simulators.vehicle")

SYSTEM_ID = 1
COMPONENT_ID = 1
PHYSICS_HZ = 50.0
WATER_DENSITY = 1000.0  # fresh water (river, lake)
G = 9.80665
ATMOSPHERE_HPA = 1013.25
GPS_DEPTH = 0.3  # m: the GPS antenna has a fix above this depth only

DEFAULT_RATES_HZ: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 10.0,
    mavlink.MAVLINK_MSG_ID_RAW_IMU: 5.0,
    mavlink.MAVLINK_MSG_ID_SCALED_IMU2: 5.0,
    mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE2: 5.0,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 4.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 5.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 5.0,
    mavlink.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT: 1.0,
}


Reply = Callable[[bytes], None]  # sends to the peer a message came from


#: SYS_STATUS as a healthy ArduSub 4.1.1 reports it in MANUAL (tests/data/ardusub/small.tlog): sensors and
#: controllers present, and of those, what is enabled and what is healthy. The depth and position
#: controllers are present but neither enabled nor healthy; the geofence present, healthy, not enabled
#: (a ground station that sees it unhealthy says "fence breach"). The GPS is healthy with a fix (at the
#: surface), logging enabled while armed.
SENSORS_PRESENT = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mavlink.MAV_SYS_STATUS_GEOFENCE | mavlink.MAV_SYS_STATUS_AHRS
    | mavlink.MAV_SYS_STATUS_LOGGING | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY | mavlink.MAV_SYS_STATUS_PREARM_CHECK
)  # fmt: skip
CONTROLLERS = (
    mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
)
SENSORS_ENABLED = SENSORS_PRESENT & ~(
    CONTROLLERS | mavlink.MAV_SYS_STATUS_GEOFENCE | mavlink.MAV_SYS_STATUS_LOGGING
)
SENSORS_HEALTHY = SENSORS_PRESENT & ~(CONTROLLERS | mavlink.MAV_SYS_STATUS_SENSOR_GPS)
PARAMS_PER_TICK = 20  # PARAM_VALUEs a list request gets per physics step (1000/s), as a link's budget allows


class Links:
    """Every connected MAVLink peer; incoming bytes are parsed per peer, and each message is handled with
    a way to answer that peer alone."""

    def __init__(self, on_message: Callable[[mavlink.MAVLink_message, Reply], None]) -> None:
        self.on_message = on_message
        self.senders: dict[object, Callable[[bytes], None]] = {}
        self._parsers: dict[object, mavlink.MAVLink] = {}
        self.tcp_port = 0
        self.udp_port = 0
        self._servers: list[asyncio.base_events.Server] = []
        self._transports: list[asyncio.DatagramTransport] = []

    def broadcast(self, data: bytes) -> None:
        for send in list(self.senders.values()):
            send(data)

    def feed(self, peer: object, data: bytes) -> None:
        """Parse a peer's bytes and handle each message. Whatever a peer sends (garbage, a message the
        handlers cannot take) is logged and dropped: it must never reach the vehicle's loop."""
        parser = self._parsers.setdefault(peer, mavlink.MAVLink(None))
        parser.robust_parsing = True
        try:
            messages = parser.parse_buffer(data) or []
        except Exception as exc:  # pymavlink raises more than MAVError on some garbage
            log.warning("bad MAVLink from %s: %r", peer, exc)
            return
        reply: Reply = lambda data: self.senders.get(peer, _nowhere)(data)  # noqa: E731
        for msg in messages:
            if msg.get_type() == "BAD_DATA":
                continue
            try:
                self.on_message(msg, reply)
            except Exception as exc:
                log.warning("dropped %s from %s: %r", msg.get_type(), peer, exc)

    async def serve_tcp(self, host: str, port: int) -> None:
        async def client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            peer = writer.get_extra_info("peername")
            self.senders[peer] = lambda data: writer.write(data) if not writer.is_closing() else None
            try:
                while data := await reader.read(4096):
                    self.feed(peer, data)
            except (ConnectionError, asyncio.CancelledError):  # the peer left, or the simulator stops
                pass
            finally:
                self.senders.pop(peer, None)
                self._parsers.pop(peer, None)
                writer.close()

        server = await asyncio.start_server(client, host, port)
        self._servers.append(server)
        self.tcp_port = server.sockets[0].getsockname()[1]

    async def serve_udp(self, host: str, port: int, push_to: tuple[str, int] | None = None) -> int:
        links = self

        class Protocol(asyncio.DatagramProtocol):
            def connection_made(self, transport: asyncio.BaseTransport) -> None:
                # A datagram endpoint's transport; before Python 3.12 its class does not subclass
                # DatagramTransport, so it is not checked with isinstance.
                self.transport = cast(asyncio.DatagramTransport, transport)
                if push_to is not None:
                    links.senders[("udpout", push_to)] = lambda data: self.transport.sendto(data, push_to)

            def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
                links.senders.setdefault(("udp", addr), lambda d: self.transport.sendto(d, addr))
                links.feed(("udp", addr), data)

        loop = asyncio.get_running_loop()
        transport, _ = await loop.create_datagram_endpoint(Protocol, local_addr=(host, port))
        self._transports.append(transport)
        bound = transport.get_extra_info("sockname")[1]
        if push_to is None:
            self.udp_port = bound
        return bound

    def close(self) -> None:
        for server in self._servers:
            server.close()
        for transport in self._transports:
            transport.close()


def _nowhere(data: bytes) -> None:
    """A peer that left: what was meant for it goes nowhere."""


class SimulatedVehicle:
    """The BlueROV2 model, its sensors in the environment, and its MAVLink conversation."""

    def __init__(
        self,
        scheduler: Scheduler,
        environment: Environment,
        seed: int = 1,
        position_source: bool = False,
        origin: Origin | None = None,
        current: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self.scheduler = scheduler
        self.environment = environment
        self.origin = origin or Origin()
        self.rov = BlueROV2(position_source=position_source, current=current)
        self.rng = random.Random(seed)
        self.accel_bias = [self.rng.gauss(0, 8) for _ in range(3)]  # mG
        self.gyro_bias = [self.rng.gauss(0, 3) for _ in range(3)]  # mrad/s
        self.mav = mavlink.MAVLink(None, srcSystem=SYSTEM_ID, srcComponent=COMPONENT_ID)
        self.links = Links(self.handle)
        self.intervals: dict[int, float] = {mid: 1.0 / hz for mid, hz in DEFAULT_RATES_HZ.items()}
        self._next_due: dict[int, float] = {}
        self.counters = {"sent": 0, "received": 0, "ignored_manual_control": 0}
        self._running = False

    # --- time -------------------------------------------------------------------------------------

    def start(self) -> None:
        self._running = True
        self._tick()

    def stop(self) -> None:
        self._running = False

    def _tick(self) -> None:
        if not self._running:
            return
        self.scheduler.call_later(1.0 / PHYSICS_HZ, self._tick)  # first: a failing tick is not the last
        self.rov.step(1.0 / PHYSICS_HZ)
        now = self.scheduler.now()
        for mid, interval in self.intervals.items():
            due = self._next_due.get(mid, 0.0)
            if interval > 0 and now >= due:
                # an interval after it was due, not after this physics step: each wait would otherwise
                # stretch to the next step (4 Hz asked, 3.85 Hz sent, beating against the agent's tick
                # grid); after a stall, an interval from now (no burst to catch up)
                self._next_due[mid] = (due if now - due < interval else now) + interval
                self._send_telemetry(mid)

    # --- outgoing ---------------------------------------------------------------------------------

    def send(self, msg: mavlink.MAVLink_message) -> None:
        self.counters["sent"] += 1
        self.links.broadcast(msg.pack(self.mav))

    def _send_telemetry(self, mid: int) -> None:
        build = self._TELEMETRY.get(mid)
        if build is None:
            return
        msg = build(self)
        if msg is not None:
            self.send(msg)

    def _boot_ms(self) -> int:
        return int(self.scheduler.now() * 1000) & 0xFFFFFFFF

    def water_temperature(self) -> float:
        r = self.rov
        return self.environment.temperature(r.north, r.east, r.depth, self.scheduler.now()) + self.rng.gauss(
            0, 0.01
        )

    def _heartbeat(self) -> mavlink.MAVLink_message:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.rov.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        state = mavlink.MAV_STATE_ACTIVE if self.rov.armed else mavlink.MAV_STATE_STANDBY
        return self.mav.heartbeat_encode(
            mavlink.MAV_TYPE_SUBMARINE, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base, self.rov.mode, state
        )

    def _imu_values(self) -> tuple[list[int], list[int], list[int]]:
        r = self.rov
        ax, ay, az = r.accel_body
        force = [ax / G * 1000, ay / G * 1000, az / G * 1000 - 1000.0]  # specific force, mG, FRD
        accel = [int(a + b + self.rng.gauss(0, 6)) for a, b in zip(force, self.accel_bias, strict=True)]
        rate = [0.0, 0.0, r.yaw_rate * 1000]
        gyro = [int(g + b + self.rng.gauss(0, 2)) for g, b in zip(rate, self.gyro_bias, strict=True)]
        mag = [int(450 * math.cos(r.yaw)), int(-450 * math.sin(r.yaw)), 400]
        return accel, gyro, mag

    def _raw_imu(self) -> mavlink.MAVLink_message:
        a, g, m = self._imu_values()
        return self.mav.raw_imu_encode(self._boot_ms() * 1000, *a, *g, *m)

    def _scaled_imu2(self) -> mavlink.MAVLink_message:
        a, g, m = self._imu_values()
        return self.mav.scaled_imu2_encode(self._boot_ms(), *a, *g, *m)

    def _attitude(self) -> mavlink.MAVLink_message:
        r = self.rov
        yaw = (r.yaw + math.pi) % (2 * math.pi) - math.pi
        return self.mav.attitude_encode(self._boot_ms(), r.roll, r.pitch, yaw, 0.0, 0.0, r.yaw_rate)

    def _pressure(self) -> mavlink.MAVLink_message:
        depth = self.rov.depth
        press = ATMOSPHERE_HPA + WATER_DENSITY * G * depth / 100.0 + self.rng.gauss(0, 0.2)
        temp = int(round(self.water_temperature() * 100))
        return self.mav.scaled_pressure2_encode(self._boot_ms(), press, 0.0, temp)

    def _vfr_hud(self) -> mavlink.MAVLink_message:
        vn, ve, vz = self.rov.ground_velocity
        heading = int(math.degrees(self.rov.yaw)) % 360
        return self.mav.vfr_hud_encode(0.0, math.hypot(vn, ve), heading, 0, -self.rov.depth, -vz)

    def _global_position(self) -> mavlink.MAVLink_message:
        r = self.rov
        lat, lon = self.origin.to_global(r.north, r.east)
        vn, ve, vz = r.ground_velocity
        return self.mav.global_position_int_encode(
            self._boot_ms(),
            int(lat * 1e7),
            int(lon * 1e7),
            int(-r.depth * 1000),
            int(-r.depth * 1000),
            int(vn * 100),
            int(ve * 100),
            int(vz * 100),
            int(math.degrees(r.yaw) * 100) % 36000,
        )

    def _gps_raw(self) -> mavlink.MAVLink_message:
        r = self.rov
        at_surface = r.depth < GPS_DEPTH
        lat, lon = self.origin.to_global(r.north + self.rng.gauss(0, 1.0), r.east + self.rng.gauss(0, 1.0))
        fix = mavlink.GPS_FIX_TYPE_3D_FIX if at_surface else mavlink.GPS_FIX_TYPE_NO_FIX
        sats = 12 if at_surface else 0
        return self.mav.gps_raw_int_encode(
            self._boot_ms() * 1000,
            fix,
            int(lat * 1e7) if at_surface else 0,
            int(lon * 1e7) if at_surface else 0,
            0,
            90 if at_surface else 65535,
            65535,
            0,
            0,
            sats,
        )

    def _local_position(self) -> mavlink.MAVLink_message | None:
        r = self.rov
        if not r.has_position:
            return None
        vn, ve, vz = r.ground_velocity
        return self.mav.local_position_ned_encode(self._boot_ms(), r.north, r.east, r.depth, vn, ve, vz)

    def _sys_status(self) -> mavlink.MAVLink_message:
        r = self.rov
        remaining = int(max(0.0, min(100.0, (r.battery_v - 13.0) / 3.0 * 100)))
        enabled = SENSORS_ENABLED | (mavlink.MAV_SYS_STATUS_LOGGING if r.armed else 0)
        healthy = SENSORS_HEALTHY | (mavlink.MAV_SYS_STATUS_SENSOR_GPS if r.depth < GPS_DEPTH else 0)
        return self.mav.sys_status_encode(
            SENSORS_PRESENT, enabled, healthy, 100, int(r.battery_v * 1000), 150, remaining, 0, 0, 0, 0, 0, 0
        )

    def _battery(self) -> mavlink.MAVLink_message:
        volts = self.rov.battery_v
        cells = [int(volts * 1000)] + [65535] * 9
        remaining = int(max(0.0, min(100.0, (volts - 13.0) / 3.0 * 100)))
        return self.mav.battery_status_encode(0, 0, 0, 2500, cells, 150, -1, -1, remaining)

    def _oxygen(self) -> mavlink.MAVLink_message:
        r = self.rov
        value = self.environment.oxygen(r.north, r.east, r.depth, self.scheduler.now()) + self.rng.gauss(
            0, 0.02
        )
        return self.mav.named_value_float_encode(self._boot_ms(), b"DO", round(value, 2))

    _TELEMETRY: dict[int, Callable[[SimulatedVehicle], mavlink.MAVLink_message | None]] = {
        mavlink.MAVLINK_MSG_ID_HEARTBEAT: _heartbeat,
        mavlink.MAVLINK_MSG_ID_SYS_STATUS: _sys_status,
        mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: _battery,
        mavlink.MAVLINK_MSG_ID_ATTITUDE: _attitude,
        mavlink.MAVLINK_MSG_ID_RAW_IMU: _raw_imu,
        mavlink.MAVLINK_MSG_ID_SCALED_IMU2: _scaled_imu2,
        mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE2: _pressure,
        mavlink.MAVLINK_MSG_ID_VFR_HUD: _vfr_hud,
        mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: _global_position,
        mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: _gps_raw,
        mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: _local_position,
        mavlink.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT: _oxygen,
    }

    # --- incoming ---------------------------------------------------------------------------------

    def handle(self, msg: mavlink.MAVLink_message, reply: Reply = _nowhere) -> None:
        """A message from a peer; ``reply`` answers that peer alone (a parameter it asked for)."""
        self.counters["received"] += 1
        handler = self._HANDLERS.get(msg.get_type())
        if handler is not None and getattr(msg, "target_system", SYSTEM_ID) in (SYSTEM_ID, 0):
            handler(self, msg, reply)

    def _ack(self, command: int, result: int) -> None:
        self.send(self.mav.command_ack_encode(command, result))

    def _text(self, severity: int, text: str) -> None:
        self.send(self.mav.statustext_encode(severity, text.encode()[:50]))

    def _on_command_long(self, msg: mavlink.MAVLink_command_long_message, reply: Reply) -> None:
        command, r = msg.command, self.rov
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            r.arm(msg.param1 >= 0.5)
            self._text(mavlink.MAV_SEVERITY_INFO, "Armed" if r.armed else "Disarmed")
            return self._ack(command, mavlink.MAV_RESULT_ACCEPTED)
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            return self._ack(command, self._set_mode(int(msg.param2)))
        if command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            mid, interval_us = int(msg.param1), msg.param2
            if mid not in self._TELEMETRY:
                return self._ack(command, mavlink.MAV_RESULT_DENIED)
            default = 1.0 / DEFAULT_RATES_HZ.get(mid, 1.0)
            self.intervals[mid] = (
                -1.0 if interval_us < 0 else (default if interval_us == 0 else interval_us / 1e6)
            )
            self._next_due[mid] = 0.0
            return self._ack(command, mavlink.MAV_RESULT_ACCEPTED)
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) in self._TELEMETRY:
            self._send_telemetry(int(msg.param1))
            return self._ack(command, mavlink.MAV_RESULT_ACCEPTED)
        self._ack(command, mavlink.MAV_RESULT_UNSUPPORTED)

    def _set_mode(self, mode: int) -> int:
        accepted, reason = self.rov.set_mode(mode)
        if not accepted:
            self._text(mavlink.MAV_SEVERITY_WARNING, f"Mode change failed: {reason}")
            return mavlink.MAV_RESULT_FAILED
        return mavlink.MAV_RESULT_ACCEPTED

    def _on_set_mode(self, msg: mavlink.MAVLink_set_mode_message, reply: Reply) -> None:
        self._ack(mavlink.MAV_CMD_DO_SET_MODE, self._set_mode(int(msg.custom_mode)))

    def _on_manual_control(self, msg: mavlink.MAVLink_manual_control_message, reply: Reply) -> None:
        if not self.rov.manual_control(msg.get_srcSystem(), msg.x, msg.y, msg.z, msg.r):
            self.counters["ignored_manual_control"] += 1

    def _on_position_global(
        self, msg: mavlink.MAVLink_set_position_target_global_int_message, reply: Reply
    ) -> None:
        r = self.rov
        depth = -float(msg.alt)
        ignore_position = msg.type_mask & (
            mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
        )
        if r.mode == MODES["GUIDED"] and not ignore_position:
            north, east = self.origin.to_local(msg.lat_int / 1e7, msg.lon_int / 1e7)
            r.set_position_target(north, east, depth)
        else:
            r.set_depth_target(depth)

    def _on_position_local(
        self, msg: mavlink.MAVLink_set_position_target_local_ned_message, reply: Reply
    ) -> None:
        if not self.rov.set_position_target(msg.x, msg.y, msg.z):
            self._text(mavlink.MAV_SEVERITY_WARNING, "Position target needs GUIDED and a position estimate")

    def _on_attitude_target(self, msg: mavlink.MAVLink_set_attitude_target_message, reply: Reply) -> None:
        w, x, y, z = msg.q
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        self.rov.set_attitude_target(yaw)

    # --- parameters, as ArduSub answers a ground station ------------------------------------------

    def _on_param_set(self, msg: mavlink.MAVLink_param_set_message, reply: Reply) -> None:
        """Set, then tell every peer the new value (as ArduSub does); a name it lacks or a value that is
        not a number gets no answer."""
        name = _param_name(msg.param_id)
        if self.rov.params.set(name, msg.param_value):
            self.send(self._param_value(name))
        else:
            log.info("PARAM_SET %s = %r refused: no such parameter, or not a number", name, msg.param_value)

    def _on_param_read(self, msg: mavlink.MAVLink_param_request_read_message, reply: Reply) -> None:
        """One parameter, by index (``param_index`` >= 0) or by name, to the peer that asked."""
        params = self.rov.params
        if msg.param_index >= 0:
            if msg.param_index < len(params):
                self._reply(reply, self._param_value(params.names[msg.param_index]))
        elif (name := _param_name(msg.param_id)) in params:
            self._reply(reply, self._param_value(name))

    def _on_param_list(self, msg: mavlink.MAVLink_param_request_list_message, reply: Reply) -> None:
        """Every parameter, in order, to the peer that asked, a few per physics step."""
        self._send_params(reply, 0)

    def _send_params(self, reply: Reply, start: int) -> None:
        names = self.rov.params.names
        for name in names[start : start + PARAMS_PER_TICK]:
            self._reply(reply, self._param_value(name))
        if start + PARAMS_PER_TICK < len(names) and self._running:
            self.scheduler.call_later(
                1.0 / PHYSICS_HZ, lambda: self._send_params(reply, start + PARAMS_PER_TICK)
            )

    def _param_value(self, name: str) -> mavlink.MAVLink_message:
        params = self.rov.params
        return self.mav.param_value_encode(
            name.encode(), params[name], params.kinds[name], len(params), params.index(name)
        )

    def _reply(self, reply: Reply, msg: mavlink.MAVLink_message) -> None:
        self.counters["sent"] += 1
        reply(msg.pack(self.mav))

    _HANDLERS: dict[str, Callable[[SimulatedVehicle, mavlink.MAVLink_message, Reply], None]] = {
        "COMMAND_LONG": _on_command_long,
        "SET_MODE": _on_set_mode,
        "MANUAL_CONTROL": _on_manual_control,
        "SET_POSITION_TARGET_GLOBAL_INT": _on_position_global,
        "SET_POSITION_TARGET_LOCAL_NED": _on_position_local,
        "SET_ATTITUDE_TARGET": _on_attitude_target,
        "PARAM_SET": _on_param_set,
        "PARAM_REQUEST_READ": _on_param_read,
        "PARAM_REQUEST_LIST": _on_param_list,
    }

    def describe(self) -> dict[str, object]:
        r = self.rov
        return {
            "north": round(r.north, 2),
            "east": round(r.east, 2),
            "depth": round(r.depth, 2),
            "heading_deg": round(math.degrees(r.yaw) % 360, 1),
            "mode": MODE_NAMES.get(r.mode, r.mode),
            "armed": r.armed,
        }


def _param_name(param_id: str | bytes) -> str:
    return param_id if isinstance(param_id, str) else param_id.decode(errors="replace").rstrip("\0")
