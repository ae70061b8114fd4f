"""A ground station joins the simulated BlueROV2 beside the agent, as QGroundControl or MAVProxy does: it
loads every parameter, reads and sets them, sees every sensor healthy, and the vehicle flies exactly as
it would without it (the agent's own messages aside, what the agent receives is the same)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from simulators.clock import VirtualScheduler
from simulators.environment import Environment
from simulators.mavlink_vehicle import SimulatedVehicle
from simulators.parameters import Parameters

AGENT, GCS = ("tcp", ("127.0.0.1", 40001)), ("udp", ("127.0.0.1", 40002))
ALT_HOLD = 2
#: MAVProxy's sensor groups: each present and enabled must be healthy, or its console shows it red
MAVPROXY_SENSORS = {
    "MAG": mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG,
    "INS": mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL | mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO,
    "AHRS": mavlink.MAV_SYS_STATUS_AHRS,
    "RC": mavlink.MAV_SYS_STATUS_SENSOR_RC_RECEIVER,
    "TERR": mavlink.MAV_SYS_STATUS_TERRAIN,
    "RNG": mavlink.MAV_SYS_STATUS_SENSOR_LASER_POSITION,
    "LOG": mavlink.MAV_SYS_STATUS_LOGGING,
    "PRX": mavlink.MAV_SYS_STATUS_SENSOR_PROXIMITY,
    "PRE": mavlink.MAV_SYS_STATUS_PREARM_CHECK,
    "FLO": mavlink.MAV_SYS_STATUS_SENSOR_OPTICAL_FLOW,
    "GPS": mavlink.MAV_SYS_STATUS_SENSOR_GPS,
    "BARO": mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE,
    "BAT": mavlink.MAV_SYS_STATUS_SENSOR_BATTERY,
}


class Peer:
    """One side of a MAVLink link to the vehicle: what it sends, parsed by the vehicle as from that peer."""

    def __init__(self, vehicle: SimulatedVehicle, address: object, sysid: int) -> None:
        self.vehicle, self.address = vehicle, address
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=190)
        self.parser = mavlink.MAVLink(None)
        self.received: list[mavlink.MAVLink_message] = []
        vehicle.links.senders[address] = lambda data: self.received.extend(
            self.parser.parse_buffer(data) or []
        )

    def send(self, msg: mavlink.MAVLink_message) -> None:
        self.vehicle.links.feed(self.address, msg.pack(self.mav))

    def of(self, kind: str) -> list[mavlink.MAVLink_message]:
        return [m for m in self.received if m.get_type() == kind]


def alarms(status: mavlink.MAVLink_sys_status_message) -> list[str]:
    """What MAVProxy would show red or say: a sensor present and enabled but not healthy; the fence
    unhealthy ("fence breach")."""
    red = [
        name
        for name, bits in MAVPROXY_SENSORS.items()
        if all(
            field & bits == bits
            for field in (status.onboard_control_sensors_present, status.onboard_control_sensors_enabled)
        )
        and status.onboard_control_sensors_health & bits != bits
    ]
    fence = mavlink.MAV_SYS_STATUS_GEOFENCE
    return red + (["fence breach"] if status.onboard_control_sensors_health & fence != fence else [])


def fly(ground_station: Callable[[VehicleScene], None] | None = None) -> VehicleScene:
    """The agent arms, dives and drives forward for 60 s; ``ground_station`` does its part beside."""
    scheduler = VirtualScheduler()
    vehicle = SimulatedVehicle(scheduler, Environment.generate(1))
    scene = VehicleScene(scheduler, vehicle, Peer(vehicle, AGENT, 255), Peer(vehicle, GCS, 255))
    agent = scene.agent
    agent.send(
        agent.mav.command_long_encode(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    )
    agent.send(agent.mav.set_mode_encode(1, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ALT_HOLD))

    def pilot() -> None:  # forward, down for the first 8 s, then holding that depth
        down = 700 if scheduler.now() < 8.0 else 500
        agent.send(agent.mav.manual_control_encode(1, 500, 0, down, 0, 0))
        scheduler.call_later(0.1, pilot)

    pilot()
    if ground_station is not None:
        ground_station(scene)
    vehicle.start()
    scheduler.run(until=60.0)
    return scene


class VehicleScene:
    def __init__(
        self, scheduler: VirtualScheduler, vehicle: SimulatedVehicle, agent: Peer, gcs: Peer
    ) -> None:
        self.scheduler, self.vehicle, self.agent, self.gcs = scheduler, vehicle, agent, gcs

    def at(self, when: float, msg: mavlink.MAVLink_message) -> None:
        self.scheduler.call_later(when, lambda: self.gcs.send(msg))


def join(scene: VehicleScene) -> None:
    """What a ground station does on joining: heartbeats, the whole parameter list, a read, a set."""
    gcs = scene.gcs.mav
    for second in range(60):
        scene.at(second, gcs.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4))
    scene.at(2.0, gcs.param_request_list_encode(1, 1))
    scene.at(20.0, gcs.param_request_read_encode(1, 1, b"", 3))
    scene.at(21.0, gcs.param_request_read_encode(1, 1, b"FS_PILOT_TIMEOUT", -1))
    scene.at(22.0, gcs.param_set_encode(1, 1, b"SURFACE_DEPTH", -12.5, mavlink.MAV_PARAM_TYPE_REAL32))
    scene.at(23.0, gcs.param_set_encode(1, 1, b"NO_SUCH_PARAM", 1.0, mavlink.MAV_PARAM_TYPE_REAL32))


def test_a_ground_station_loads_reads_and_sets_every_parameter() -> None:
    scene = fly(join)
    values = scene.gcs.of("PARAM_VALUE")
    table = Parameters.ardusub()
    listed, (read_index, read_name, set_echo) = values[: len(table)], values[len(table) :]
    assert [(v.param_index, v.param_id, v.param_value, v.param_type, v.param_count) for v in listed] == [
        (i, name, table[name], table.kinds[name], len(table)) for i, name in enumerate(table.names)
    ]
    assert (read_index.param_id, read_index.param_value) == ("SYSID_MYGCS", 255.0)
    assert (read_name.param_id, read_name.param_value) == ("FS_PILOT_TIMEOUT", 3.0)
    assert (set_echo.param_id, set_echo.param_value) == ("SURFACE_DEPTH", -12.5)
    assert scene.vehicle.rov.params["SURFACE_DEPTH"] == -12.5
    assert [(v.param_id, v.param_value) for v in scene.agent.of("PARAM_VALUE")] == [("SURFACE_DEPTH", -12.5)]


def test_a_healthy_ardusub_raises_no_alarm_at_the_surface_or_below() -> None:
    scene = fly(join)
    statuses = scene.gcs.of("SYS_STATUS")
    assert len(statuses) >= 59
    below = [s for s in statuses if s.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_GPS == 0]
    assert below and len(below) < len(statuses)  # the dive left the GPS's reach
    assert {tuple(alarms(s)) for s in statuses} == {(), ("GPS",)}
    assert all(alarms(s) == ["GPS"] for s in below)  # true: no fix under water, as ArduSub says


def test_the_vehicle_flies_as_it_would_without_the_ground_station() -> None:
    alone, joined = fly(), fly(join)
    assert (
        replace(joined.vehicle.rov, params=alone.vehicle.rov.params) == alone.vehicle.rov
    )  # all but one param
    assert alone.vehicle.rov.depth > 1.0 and alone.vehicle.rov.north > 10.0  # it did fly

    def seen(scene: VehicleScene) -> list[dict[str, object]]:
        return [m.to_dict() for m in scene.agent.received if m.get_type() != "PARAM_VALUE"]

    assert seen(alone) == seen(joined)
