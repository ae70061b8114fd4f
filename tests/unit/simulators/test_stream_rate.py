"""The simulated BlueROV2 sends a message at the rate asked for, not slower: the agent asks for each
sample stream's message at its tick rate, and a sensor a few per cent slower beats against the grid."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from simulators.clock import VirtualScheduler
from simulators.environment import Environment
from simulators.mavlink_vehicle import SimulatedVehicle


def test_a_message_interval_is_kept_on_the_physics_steps() -> None:
    scheduler = VirtualScheduler()
    vehicle = SimulatedVehicle(scheduler, Environment.generate(1))
    received: list[bytes] = []
    vehicle.links.senders["ground station"] = received.append
    gcs = mavlink.MAVLink(None, srcSystem=255)
    ask = gcs.command_long_encode(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                  mavlink.MAVLINK_MSG_ID_RAW_IMU, 250_000, 0, 0, 0, 0, 0)  # fmt: skip
    vehicle.handle(ask)
    vehicle.start()
    scheduler.run(until=60.0)
    parser = mavlink.MAVLink(None)
    stamps = [
        m.time_usec / 1e6 for b in received for m in parser.parse_buffer(b) or [] if m.get_type() == "RAW_IMU"
    ]
    intervals = np.diff(stamps)
    assert len(stamps) > 200
    assert abs(intervals.mean() - 0.25) < 1e-3  # 4 Hz asked, 4 Hz sent
    assert intervals.max() <= 0.25 + 0.02  # each within one physics step of its due time
