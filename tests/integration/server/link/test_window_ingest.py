"""The shore's ingest of a version-4 vehicle's window, on a real SQLite store: a packet that comes before
the one it continues from waits, asks for no chain restart, and is decoded when that one comes; after a
loss in the middle of a window the vehicle's packets coded again are decoded, the abandoned ones never,
and every sample is stored once, certain and within eps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sqlmodel import Session, select

from server.core.config import Settings
from server.core.events import Bus
from server.link.ingest import Ingest
from server.link.state import IncomingFrame
from server.telemetry.models import Telemetry
from server.vehicles.models import Vehicle
from tacit import auth
from tacit.codec import EncodedPacket, PacketEncoder
from tacit.packets import Stream
from tacit.streams import default_streams
from tests.support.shore import store_with

KEY, ADDRESS, T0 = bytes(range(32)), 2, 1_800_000_000.0
STREAMS = list(default_streams().values())
IMU = default_streams()[Stream.KINEMATIC]


@pytest.fixture
def ingest(tmp_path: Path):
    db = store_with(tmp_path, Vehicle(name="rov1", address=ADDRESS, key_hex=KEY.hex(), protocol=4))
    shore = Ingest(db, Bus(), default_streams(), Settings())
    shore.load_vehicles()
    yield shore
    db.dispose()


class Vehicle4:
    """A version-4 vehicle's encoder with a window, fed an IMU the shore cannot predict."""

    def __init__(self, window: int) -> None:
        self.enc = PacketEncoder(STREAMS, max_latency=1.0, protocol=4)
        self.enc.set_window(window)
        rng = np.random.default_rng(4)
        self.truth = np.cumsum(rng.normal(0, 5 * max(IMU.eps), (160, len(IMU.channels))), axis=0)
        self.taken: list[EncodedPacket] = []
        for k, row in enumerate(self.truth):
            self.enc.push(0, T0 + IMU.period * k, row)
            while self.enc.ready(T0 + IMU.period * k):
                self.taken.append(self.enc.take())

    def more(self) -> list[EncodedPacket]:
        """What is left, taken as the window frees (every packet delivered)."""
        out = []
        while self.enc.pending or self.enc.in_flight:
            while self.enc.pending and self.enc.ready(T0 + 1e4):
                out.append(self.enc.take())
            for flight in list(self.enc.in_flight):
                self.enc.resolve(True, flight.seq)
        return out


def send(ingest: Ingest, packet: EncodedPacket) -> None:
    frame = auth.tag_priority(packet.packet, KEY, ADDRESS)
    ingest.handle(IncomingFrame(ADDRESS, 1, frame, at=T0 + 100))


def stored_once_within_eps(ingest: Ingest, truth: np.ndarray) -> None:
    with Session(ingest.db) as s:
        rows = s.exec(select(Telemetry).where(Telemetry.stream == IMU.name)).all()
    assert all(r.certain for r in rows)
    ticks = sorted(round((r.time - T0) / IMU.period) for r in rows)
    assert ticks == list(range(len(truth)))  # every sample once
    for r in rows:
        k = round((r.time - T0) / IMU.period)
        assert np.all(np.abs(np.array(r.values) - truth[k]) <= np.asarray(IMU.eps) + 1e-6), k


def test_a_packet_before_the_one_it_continues_from_waits_for_it_without_a_restart(ingest: Ingest) -> None:
    vehicle = Vehicle4(window=5)
    first, second, third, *rest = vehicle.taken
    send(ingest, first)
    send(ingest, third)  # the second is late (a retransmission will bring it)
    v = ingest.vehicles[ADDRESS]
    assert not v.link.needs_restart and len(v.link.waiting) == 1
    send(ingest, second)  # and the third is decoded after it
    assert not v.link.waiting
    for packet in rest:
        send(ingest, packet)
    for packet in vehicle.taken:
        vehicle.enc.resolve(True, packet.packet.seq)
    for packet in vehicle.more():
        send(ingest, packet)
    assert not v.link.needs_restart
    stored_once_within_eps(ingest, vehicle.truth)


def test_a_loss_in_the_middle_of_a_window_is_coded_again_and_nothing_is_stored_twice(ingest: Ingest) -> None:
    vehicle = Vehicle4(window=5)
    for packet in vehicle.taken[:2]:
        send(ingest, packet)
        vehicle.enc.resolve(True, packet.packet.seq)
    for packet in vehicle.taken[3:]:  # the third never comes; those after it wait for it
        send(ingest, packet)
    v = ingest.vehicles[ADDRESS]
    assert not v.link.needs_restart and len(v.link.waiting) == 2
    assert vehicle.enc.resolve(False, 2) == [3, 4]  # the modem gave it up: coded again
    for packet in vehicle.more():
        send(ingest, packet)
    assert not v.link.needs_restart
    stored_once_within_eps(ingest, vehicle.truth)
