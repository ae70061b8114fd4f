"""pymavlink as a ground station against the simulated BlueROV2 (and a replayed real dive)."""

from __future__ import annotations

import math
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from tests.conftest import tacit_process

ALT_HOLD, GUIDED, MANUAL = 2, 4, 19


def gcs(url: str, sysid: int = 255) -> mavutil.mavfile:
    conn = mavutil.mavlink_connection(url, source_system=sysid)
    assert conn.wait_heartbeat(timeout=10) is not None
    return conn


def command(conn: mavutil.mavfile, cmd: int, *params: float, texts: list[str] | None = None) -> int:
    """Send a COMMAND_LONG; return its ACK's result, collecting STATUSTEXTs seen on the way."""
    p = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(1, 1, cmd, 0, *p)
    while True:
        msg = conn.recv_match(type=["COMMAND_ACK", "STATUSTEXT"], blocking=True, timeout=10)
        assert msg is not None, "no COMMAND_ACK"
        if msg.get_type() == "STATUSTEXT":
            if texts is not None:
                texts.append(msg.text)
        elif msg.command == cmd:
            return msg.result


def set_mode(conn: mavutil.mavfile, mode: int, texts: list[str] | None = None) -> int:
    return command(conn, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode, texts=texts)


def latest(conn: mavutil.mavfile, kind: str, timeout: float = 5.0):
    """The newest message of ``kind`` after draining what is queued."""
    msg = conn.recv_match(type=kind, blocking=True, timeout=timeout)
    while (newer := conn.recv_match(type=kind, blocking=False)) is not None:
        msg = newer
    return msg


def wait_for(conn: mavutil.mavfile, kind: str, predicate, timeout: float) -> object:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = conn.recv_match(type=kind, blocking=True, timeout=1)
        if msg is not None and predicate(msg):
            return msg
    raise AssertionError(f"no {kind} satisfied the condition within {timeout} s")


def depth_target(conn: mavutil.mavfile, depth: float) -> None:
    ignore_all_but_z = 0b110111111011
    conn.mav.set_position_target_global_int_send(
        0, 1, 1, mav.MAV_FRAME_GLOBAL_INT, ignore_all_but_z, 0, 0, -depth, 0, 0, 0, 0, 0, 0, 0, 0
    )


def test_arm_alt_hold_depth_and_guided_refused_without_fix() -> None:
    with tacit_process("sim", "--time-scale", "5") as (_, info):
        conn = gcs(info["vehicle"]["mavlink"][0])
        assert command(conn, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
        hb = wait_for(conn, "HEARTBEAT", lambda m: m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED, 5)
        assert hb.type == mav.MAV_TYPE_SUBMARINE
        assert set_mode(conn, ALT_HOLD) == mav.MAV_RESULT_ACCEPTED
        depth_target(conn, 4.0)
        wait_for(conn, "VFR_HUD", lambda m: abs(m.alt + 4.0) < 0.03, timeout=20)
        pressure = latest(conn, "SCALED_PRESSURE2")
        assert pressure.press_abs == pytest.approx(1013.25 + 4.0 * 98.0665, abs=4)
        assert 1000 < pressure.temperature < 3000  # cdegC: water temperature from the Bar30
        gps = latest(conn, "GPS_RAW_INT")
        assert gps.fix_type < mav.GPS_FIX_TYPE_2D_FIX  # no GPS under water
        texts: list[str] = []
        assert set_mode(conn, GUIDED, texts) == mav.MAV_RESULT_FAILED
        assert any("position" in t for t in texts)


def test_guided_accepted_with_a_position_source() -> None:
    with tacit_process("sim", "--time-scale", "5", "--position-source") as (_, info):
        conn = gcs(info["vehicle"]["mavlink"][0])
        command(conn, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        set_mode(conn, ALT_HOLD)
        depth_target(conn, 2.0)
        wait_for(conn, "VFR_HUD", lambda m: abs(m.alt + 2.0) < 0.2, timeout=15)
        assert set_mode(conn, GUIDED) == mav.MAV_RESULT_ACCEPTED
        conn.mav.set_position_target_local_ned_send(
            0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 0b110111111000, 10.0, 5.0, 2.0, 0, 0, 0, 0, 0, 0, 0, 0
        )
        wait_for(conn, "LOCAL_POSITION_NED", lambda m: abs(m.x - 10) < 0.5 and abs(m.y - 5) < 0.5, timeout=30)


def north_after_manual_control(url: str, sysid: int) -> float:
    control = gcs(url, sysid)
    watch = gcs(url)
    command(watch, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    start = latest(watch, "GLOBAL_POSITION_INT").lat
    deadline = time.monotonic() + 2.0  # 10 simulated seconds at time scale 5
    while time.monotonic() < deadline:
        control.mav.manual_control_send(1, 600, 0, 500, 0, 0)
        time.sleep(0.05)
    return (latest(watch, "GLOBAL_POSITION_INT").lat - start) / 1e7 * 111_320.0


def test_manual_control_only_from_sysid_mygcs() -> None:
    with tacit_process("sim", "--time-scale", "5") as (_, info):
        assert north_after_manual_control(info["vehicle"]["mavlink"][0], sysid=200) == pytest.approx(
            0, abs=0.05
        )
    with tacit_process("sim", "--time-scale", "5") as (_, info):
        assert north_after_manual_control(info["vehicle"]["mavlink"][0], sysid=255) > 3.0


def test_attitude_target_turns_and_expires_after_five_seconds() -> None:
    with tacit_process("sim", "--time-scale", "5") as (_, info):
        url = info["vehicle"]["mavlink"][0]
        conn = gcs(url)
        command(conn, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        set_mode(conn, ALT_HOLD)
        yaw = 1.2
        q = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        conn.mav.set_attitude_target_send(
            0, 1, 1, mav.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE, q, 0, 0, 0, 0
        )
        wait_for(conn, "ATTITUDE", lambda m: abs(m.yaw - yaw) < 0.05, timeout=10)
        conn.mav.set_attitude_target_send(
            0, 1, 1, mav.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE, q, 0, 0, 0, 0
        )
        stick = gcs(url)
        start = time.monotonic()
        held = []
        while time.monotonic() - start < 2.4:  # 12 simulated seconds of yaw stick
            stick.mav.manual_control_send(1, 0, 0, 500, 400, 0)
            time.sleep(0.05)
            if time.monotonic() - start < 0.6:  # 3 s: the target still holds the heading
                held.append(latest(conn, "ATTITUDE").yaw)
        assert max(abs(h - yaw) for h in held) < 0.1
        assert abs(latest(conn, "ATTITUDE").yaw - yaw) > 0.5  # expired: the stick turned the vehicle


def test_message_interval_changes_the_stream_rate() -> None:
    with tacit_process("sim", "--time-scale", "1") as (_, info):
        conn = gcs(info["vehicle"]["mavlink"][0])
        assert command(conn, mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_RAW_IMU, 40_000) == 0
        latest(conn, "RAW_IMU")
        start, count = time.monotonic(), 0
        while time.monotonic() - start < 1.0:
            if conn.recv_match(type="RAW_IMU", blocking=True, timeout=0.5) is not None:
                count += 1
        assert 18 <= count <= 30  # 25 Hz asked


def test_replay_streams_a_real_dive(real_data) -> None:
    tlog = real_data / "ardusub" / "small.tlog"
    with tacit_process("sim", "--replay", str(tlog), "--time-scale", "20") as (_, info):
        conn = gcs(info["vehicle"]["mavlink"][0])
        seen: dict[str, object] = {}
        deadline = time.monotonic() + 10
        while len(seen) < 3 and time.monotonic() < deadline:
            msg = conn.recv_match(type=["RAW_IMU", "SCALED_PRESSURE2", "ATTITUDE"], blocking=True, timeout=1)
            if msg is not None:
                seen[msg.get_type()] = msg
        assert set(seen) == {"RAW_IMU", "SCALED_PRESSURE2", "ATTITUDE"}
        assert 500 < seen["SCALED_PRESSURE2"].temperature < 4000  # a real lake's temperature, cdegC
