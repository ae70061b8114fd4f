"""The sample streams the vehicle sends and the shore decodes: both ends build them from here.

A stream's id travels in the priority packet header (2 bits), so both ends must agree on its channels,
error bounds and period: they are defined here only, and changing one is changing the protocol (vehicle
and shore are updated together).
"""

from __future__ import annotations

from tacit.codec import StreamSpec
from tacit.packets import Stream

IMU_CHANNELS = ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag")
ENV_CHANNELS = ("temperature", "depth", "oxygen")
WATER_CHANNELS = ("temperature", "oxygen")  # what the water does (depth is the vehicle's own motion)
#: Each channel's unit (RAW_IMU: mG, mrad/s, mGauss; environment: degC, m, mg/L).
UNITS = {
    "xacc": "mG",
    "yacc": "mG",
    "zacc": "mG",
    "xgyro": "mrad/s",
    "ygyro": "mrad/s",
    "zgyro": "mrad/s",
    "xmag": "mGauss",
    "ymag": "mGauss",
    "zmag": "mGauss",
    "temperature": "°C",
    "depth": "m",
    "oxygen": "mg/L",
}

DEFAULT_EPS = {
    # RAW_IMU units: mG, mrad/s, mGauss. About half a standard deviation of a BlueROV2 at rest.
    "xacc": 10.0, "yacc": 10.0, "zacc": 10.0, "xgyro": 15.0, "ygyro": 15.0, "zgyro": 5.0,
    "xmag": 10.0, "ymag": 10.0, "zmag": 10.0,
    # environment: degC, m, mg/L
    "temperature": 0.05, "depth": 0.05, "oxygen": 0.05,
}  # fmt: skip


#: Each stream's tick period, s: the rate the agent asks ArduSub for the stream's message is 1 / period, so a
#: tick holds one sample and every sample keeps its own time (a sensor faster than its stream's grid would
#: put two samples, dated alike, in one tick).
IMU_PERIOD = 0.25  # RAW_IMU at 4 Hz, as in the paper
ENV_PERIOD = 0.5  # SCALED_PRESSURE2 (Bar30: depth, water temperature) at 2 Hz


def default_streams(
    eps: dict[str, float] | None = None, imu_period: float = IMU_PERIOD, env_period: float = ENV_PERIOD
) -> dict[Stream, StreamSpec]:
    """The kinematic (RAW_IMU) and environmental (depth, water temperature, oxygen) streams; the
    environmental stream's depth channel is what protocol 4 predicts its water's profiles by. Both ends
    date samples by the wall clock (the vehicle's when the autopilot measured them, ``tacit.sampletime``):
    a simulation run k times faster than real time delivers k samples per tick (each kept, dated within
    the tick); at real time every sample has its own tick."""
    bounds = {**DEFAULT_EPS, **(eps or {})}
    return {
        Stream.KINEMATIC: StreamSpec("imu", Stream.KINEMATIC, IMU_CHANNELS,
                                     tuple(bounds[c] for c in IMU_CHANNELS), imu_period),
        Stream.ENVIRONMENTAL: StreamSpec("env", Stream.ENVIRONMENTAL, ENV_CHANNELS,
                                         tuple(bounds[c] for c in ENV_CHANNELS), env_period,
                                         initial=(20.0, 0.0, 8.0), depth="depth"),
    }  # fmt: skip
