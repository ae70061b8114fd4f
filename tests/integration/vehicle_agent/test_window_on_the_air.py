"""The version-4 window on the real parts: ``tacit sim``'s Micro-Modems on their ptys, the shore's modem
driver polling at rate 5, the vehicle's link answering each data request with what its compressor keeps
in flight. A rate-5 poll brings several packets; every sample reaches the shore once, within eps."""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

import numpy as np

from tacit import auth
from tacit.codec import PacketDecoder
from tacit.link import capacity, from_frame
from tacit.modem import DriverSettings, ModemDriver, ReceivedFrame
from tacit.packets import Stream, decode
from tacit.streams import default_streams
from tests.conftest import tacit_process
from vehicle_agent.compressor import Compressor
from vehicle_agent.link import VehicleLink

SHORE, VEHICLE = 1, 2
KEY = bytes(range(32))
RATE = 5


def sim_config(tmp_path: Path) -> Path:
    config = {
        "seed": 3,
        "time_scale": 4.0,
        "channel": {"noise_level_db": 90.0},  # 150 m: an SNR far above rate 5's threshold
        "modems": [
            {"address": SHORE, "name": "shore", "position": [0.0, 0.0, 1.0]},
            {"address": VEHICLE, "name": "auv", "position": [150.0, 0.0, 1.0]},
        ],
    }
    path = tmp_path / "sim.json"
    path.write_text(json.dumps(config))
    return path


def test_a_rate_5_poll_brings_the_packets_the_window_keeps_in_flight(tmp_path: Path) -> None:
    streams = default_streams()
    imu = streams[Stream.KINEMATIC]
    rng = np.random.default_rng(7)
    start = time.time() - 120.0
    truth = {k: start + 0.25 * k for k in range(200)}  # 50 s of an IMU the shore cannot predict
    rows = {k: np.cumsum(rng.normal(0, 5 * max(imu.eps), (200, len(imu.channels))), axis=0)[k] for k in truth}

    async def run(ptys: dict[int, str]) -> tuple[list[int], dict[int, np.ndarray]]:
        shore = ModemDriver(DriverSettings(url=ptys[SHORE], address=SHORE, keepalive=60))
        vehicle = ModemDriver(DriverSettings(url=ptys[VEHICLE], address=VEHICLE, keepalive=60))
        await shore.start()
        await vehicle.start()
        link = VehicleLink(vehicle, auth.ControlReceiver(KEY, VEHICLE), SHORE)
        compressor = Compressor(streams, max_latency=1.0, protocol=4)
        decoder = PacketDecoder(list(streams.values()), 4)
        per_poll: list[int] = []
        held: dict[int, np.ndarray] = {}
        seq = 0

        def heard(event: object) -> None:
            if isinstance(event, ReceivedFrame) and event.src == VEHICLE:
                chunks = from_frame(event.data)
                per_poll[-1] += len(chunks)
                for chunk in chunks:
                    packet = decode(chunk)
                    for span in decoder.decode(packet.payload, time.time(), packet.seq):  # type: ignore[union-attr]
                        if span.spec.name == imu.name:  # each sample by its time (within T/2)
                            for at, values in zip(span.times, span.values, strict=True):
                                k = round((float(at) - start) / imu.period)
                                assert k not in held, "a sample decoded twice"
                                held[k] = values

        shore.add_listener(heard)
        for k, t in truth.items():
            compressor.add(Stream.KINEMATIC, t, list(rows[k]))
        try:
            for _ in range(30):
                compressor.follow(link.capacity)
                for _, encoded in compressor.ready(time.time(), seq):
                    seq += 1
                    packet = encoded.packet
                    link.send(packet.encode(), on_result=lambda ok, q=packet.seq: compressor.resolve(q, ok))
                per_poll.append(0)
                await shore.poll(VEHICLE, RATE, ack=True, frames=8)
                deadline = time.monotonic() + 30.0  # the frames, their ACK: however busy the machine
                while compressor.in_flight() and time.monotonic() < deadline:
                    await asyncio.sleep(0.05)
                if not compressor.encoder.pending and not compressor.in_flight():
                    break
        finally:
            await vehicle.stop()
            await shore.stop()
        return per_poll, held

    with tacit_process("sim", "--config", str(sim_config(tmp_path))) as (_, info):
        ptys = {m["address"]: m["pty"] for m in info["modems"]}
        per_poll, held = asyncio.run(asyncio.wait_for(run(ptys), 120))
    assert max(per_poll) > 1 and max(per_poll) <= capacity(RATE)  # a poll brought several packets
    assert sorted(held) == sorted(truth)  # every sample once
    for k, values in held.items():
        assert np.all(np.abs(values - rows[k]) <= np.asarray(imu.eps)), k
