"""The simulator's UDP MAVLink endpoint, as QGroundControl uses it: the ground station writes first (a
HEARTBEAT), the vehicle answers whoever wrote. Nothing a ground station sends stops the vehicle."""

from __future__ import annotations

import json
import time

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from tests.conftest import tacit_process


def udp_url(info: dict[str, object]) -> str:
    vehicle = info["vehicle"]
    assert isinstance(vehicle, dict)
    return next(url for url in vehicle["mavlink"] if url.startswith("udpout:"))


def streaming(conn: mavutil.mavfile, seconds: float = 2.0) -> set[str]:
    """The kinds of message the vehicle sent over ``seconds``."""
    kinds: set[str] = set()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        msg = conn.recv_match(blocking=True, timeout=0.2)
        if msg is not None:
            kinds.add(msg.get_type())
    return kinds


def test_a_ground_station_over_udp_gets_heartbeats_and_telemetry_whatever_it_sends() -> None:
    with tacit_process("sim", "--time-scale", "2") as (proc, info):
        gcs = mavutil.mavlink_connection(udp_url(info), source_system=255, source_component=190)
        gcs.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)
        vehicle = gcs.wait_heartbeat(timeout=10)
        assert vehicle is not None and vehicle.type == mav.MAV_TYPE_SUBMARINE
        assert {"HEARTBEAT", "ATTITUDE", "SCALED_PRESSURE2"} <= streaming(gcs)

        gcs.write(b"\xfd\x09garbage, not MAVLink \x00\xff" * 3)  # a datagram no parser can take
        gcs.mav.command_long_send(1, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, float("nan"), 0, 0, 0, 0, 0, 0)
        gcs.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)
        streaming(gcs, 0.5)  # what was already on its way
        assert {"HEARTBEAT", "ATTITUDE", "SCALED_PRESSURE2"} <= streaming(gcs)
        assert proc.poll() is None
    assert proc.stderr is not None
    assert "Traceback" not in proc.stderr.read()


def test_the_first_line_of_sim_json_is_the_json_object() -> None:
    with tacit_process("sim") as (proc, info):
        assert {"modems", "vehicles", "vehicle"} <= set(info)  # tacit_process parsed the first line
        udp = mavutil.mavlink_connection(udp_url(info), source_system=255)
        udp.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)
        assert udp.wait_heartbeat(timeout=10) is not None
    assert proc.stdout is not None and proc.stderr is not None
    assert "report" in json.loads(proc.stdout.readline())  # the only other line: the report at exit
    assert "Traceback" not in proc.stderr.read()


def test_a_ground_station_over_udp_loads_every_parameter_and_sees_no_alarm() -> None:
    """As QGroundControl and MAVProxy join: the whole list over UDP (none lost to the burst), each sensor
    present and enabled healthy, the geofence too (MAVProxy says "fence breach" otherwise)."""
    with tacit_process("sim", "--time-scale", "2") as (_, info):
        gcs = mavutil.mavlink_connection(udp_url(info), source_system=255, source_component=190)
        gcs.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)
        assert gcs.wait_heartbeat(timeout=10) is not None
        gcs.mav.param_request_list_send(1, 1)
        values: dict[int, tuple[str, float]] = {}
        count = None
        deadline = time.monotonic() + 30
        while (count is None or len(values) < count) and time.monotonic() < deadline:
            msg = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=1)
            if msg is not None:
                values[msg.param_index], count = (msg.param_id, msg.param_value), msg.param_count
        assert count is not None and sorted(values) == list(range(count)), f"{len(values)} of {count}"
        assert values[3] == ("SYSID_MYGCS", 255.0)
        status = gcs.recv_match(type="SYS_STATUS", blocking=True, timeout=5)
        assert status is not None
        present, enabled = status.onboard_control_sensors_present, status.onboard_control_sensors_enabled
        assert present & enabled & ~status.onboard_control_sensors_health == 0
        assert status.onboard_control_sensors_health & mav.MAV_SYS_STATUS_GEOFENCE
