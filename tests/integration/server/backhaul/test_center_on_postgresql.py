"""The center's pipeline on PostgreSQL with a vehicle's real packets: an IMU priority packet's samples
(ticks are UNIX time over the period, beyond a 32-bit INTEGER) and the check-point that vouches for it.
Found by bench/bench_backhaul.py: before migration 0009 PostgreSQL refused every IMU sample."""

from __future__ import annotations

import time

import numpy as np
from sqlalchemy import create_engine, text

from launch.split import throwaway_database as postgres_database
from server.backhaul.relay import RelayedIncoming
from server.backhaul.subjects import FrameMessage
from server.core.db import make_engine, migrate
from server.vehicles.schemas import VehicleIn
from server.vehicles.service import Vehicles
from tacit import auth
from tacit.codec import PacketEncoder
from tacit.packets import NEWEST, CheckpointPacket, MissionState, cover_bitmap, with_seq
from tacit.streams import default_streams
from tests.integration.server.backhaul.test_frames_and_commands import ingest_on

ADDRESS = 2


def signed(key: bytes) -> list[bytes]:
    """A priority packet of IMU samples (the codec's), then a check-point covering it, signed."""
    streams = list(default_streams().values())
    spec, rng = streams[0], np.random.default_rng(1)
    encoder = PacketEncoder(streams, max_latency=1.0, protocol=NEWEST)  # as the vehicle is registered
    t0, tick = time.time() - 60, 0
    while not encoder.ready(t0 + tick * spec.period):
        encoder.push(0, t0 + tick * spec.period, rng.normal(0, 10, len(spec.channels)))
        tick += 1
    encoded = encoder.take()
    encoder.resolve(True)
    priority = auth.tag_priority(with_seq(encoded.packet, 0), key, ADDRESS)
    cp = CheckpointPacket(
        seq=1, time=int(t0) + 30, state=MissionState.PREPROGRAMMED, covered=cover_bitmap(1, [0])
    )
    return [priority, auth.sign_checkpoint(cp, key, 1, ADDRESS, [auth.packet_hash(priority)])]


def test_the_center_stores_and_verifies_imu_samples_on_postgresql(postgres_server: str) -> None:
    with postgres_database(postgres_server) as url:
        migrate(url)
        vehicle = Vehicles(make_engine(url)).create(VehicleIn(name="rov1", address=ADDRESS))
        ingest = ingest_on(url)
        frames = [
            FrameMessage(f"ship-0a0b0c0d-{i}", "ship", ADDRESS, 0, data, at=time.time())
            for i, data in enumerate(signed(bytes.fromhex(vehicle.key_hex)))
        ]
        ingest.handle_batch([RelayedIncoming.of(f) for f in frames])
        assert ingest.stats["verified"] == 1 and ingest.stats["packets"] == 2
        with create_engine(url).connect() as c:
            ticks = c.execute(text("SELECT min(tick), count(*) FROM telemetry WHERE verified")).one()
        assert ticks[1] > 0 and ticks[0] > 2**31
