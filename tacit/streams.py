"""The sample streams the vehicle sends and the shore decodes: both ends build them from here.

A stream's id travels in the priority packet header (2 bits), so both ends must agree on its channels,
error bounds and period; a deployment may override the bounds in its configuration (the same file is
read by the agent and the server).
"""

from __future__ import annotations

from tacit.codec import StreamSpec
from tacit.packets import Stream

IMU_CHANNELS = ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag")
ENV_CHANNELS = ("temperature", "depth", "oxygen")
WATER_CHANNELS = ("temperature", "oxygen")  # what the water does (depth is the vehicle's own motion)

DEFAULT_EPS = {
    # RAW_IMU units: mG, mrad/s, mGauss. About half a standard deviation of a BlueROV2 at rest.
    "xacc": 10.0, "yacc": 10.0, "zacc": 10.0, "xgyro": 15.0, "ygyro": 15.0, "zgyro": 5.0,
    "xmag": 10.0, "ymag": 10.0, "zmag": 10.0,
    # environment: degC, m, mg/L
    "temperature": 0.05, "depth": 0.05, "oxygen": 0.05,
}  # fmt: skip


def default_streams(eps: dict[str, float] | None = None, imu_period: float = 0.25,
                    env_period: float = 1.0) -> dict[Stream, StreamSpec]:  # fmt: skip
    """The kinematic (RAW_IMU, 4 Hz as in the paper) and environmental (1 Hz) streams."""
    bounds = {**DEFAULT_EPS, **(eps or {})}
    return {
        Stream.KINEMATIC: StreamSpec("imu", Stream.KINEMATIC, IMU_CHANNELS,
                                     tuple(bounds[c] for c in IMU_CHANNELS), imu_period),
        Stream.ENVIRONMENTAL: StreamSpec("env", Stream.ENVIRONMENTAL, ENV_CHANNELS,
                                         tuple(bounds[c] for c in ENV_CHANNELS), env_period,
                                         initial=(20.0, 0.0, 8.0)),
    }  # fmt: skip
