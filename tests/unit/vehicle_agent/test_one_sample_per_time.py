"""Every sample the vehicle measured reaches the shore once, at its own time: the rate the agent asks
ArduSub for each stream's message is its stream's tick rate, so no tick holds two samples dated alike."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from tacit.codec import PacketDecoder, PacketEncoder
from tacit.packets import Stream
from tacit.streams import default_streams
from vehicle_agent.mavlink_io import STREAMS_HZ

MESSAGE_OF = {
    Stream.KINEMATIC: mav.MAVLINK_MSG_ID_RAW_IMU,
    Stream.ENVIRONMENTAL: mav.MAVLINK_MSG_ID_SCALED_PRESSURE2,
}


def test_the_agent_asks_for_each_stream_at_its_tick_rate() -> None:
    for stream, spec in default_streams().items():
        assert STREAMS_HZ[MESSAGE_OF[stream]] * spec.period == 1.0


def test_a_sensor_at_its_streams_rate_gives_one_sample_per_time() -> None:
    """The Bar30 at the rate the agent asks, with jitter: as many distinct times on the shore as samples
    measured, each within half a tick of when it was measured."""
    streams = default_streams()
    spec = streams[Stream.ENVIRONMENTAL]
    rng = np.random.default_rng(3)
    measured = 1_700_000_000.0 + np.arange(600) / STREAMS_HZ[MESSAGE_OF[Stream.ENVIRONMENTAL]]
    measured = measured + rng.uniform(-0.1, 0.1, measured.size) * spec.period
    encoder = PacketEncoder(list(streams.values()), max_latency=10.0)
    decoder = PacketDecoder(list(streams.values()))
    times: list[float] = []
    for t in measured:
        encoder.push(1, float(t), [20.0 + 0.01 * rng.normal(), 2.0, 8.0])
        while encoder.ready(float(t)):
            encoded = encoder.take()
            encoder.resolve(True)
            for span in decoder.decode(encoded.packet.payload, float(t)):
                if span.spec.name == spec.name:
                    times += [float(x) for x in span.times]
    assert len(times) == len(set(times)) > 500
    errors = np.abs(np.array(times) - measured[: len(times)])
    assert errors.max() <= spec.period / 2
