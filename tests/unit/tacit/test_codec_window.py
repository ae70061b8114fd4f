"""Version 4's window: several packets in flight, each coded on the state the one before it leaves. A
lost packet in the middle of the window, a duplicate and a reordering: every sample reaches the shore
once, within eps, and nothing is ever decoded on a state another branch left."""

from __future__ import annotations

import numpy as np
import pytest

from tacit.codec import CodecError, EncodedPacket, StreamDecoder, StreamEncoder, StreamSpec, UnknownBase
from tacit.codec.format import MAX_WINDOW
from tacit.packets import Stream

T0 = 1_700_000_000.0
SPEC = StreamSpec("imu", Stream.KINEMATIC, ("a", "b", "c"), (0.05, 0.05, 0.05), 0.25)


def noisy(n: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Samples the shore cannot predict (a random walk far above eps): every packet fills."""
    rng = np.random.default_rng(seed)
    return T0 + 0.25 * np.arange(n), np.cumsum(rng.normal(0, 0.5, (n, 3)), axis=0)


class Shore:
    """The shore's decoder and what it holds per sample serial (exactly once: a second copy fails)."""

    def __init__(self, truth: np.ndarray) -> None:
        self.dec, self.truth = StreamDecoder(SPEC, 4), truth
        self.held: dict[int, np.ndarray] = {}

    def receive(self, packet: EncodedPacket) -> None:
        span = self.dec.decode(packet.packet.payload, T0 + 1000, packet.packet.seq)
        assert span.lost is None  # version 4 codes a lost packet's samples again: it declares nothing
        for serial, row in zip(packet.serials[0], packet.rows[0], strict=True):
            assert serial not in self.held, f"sample {serial} decoded twice"
            self.held[serial] = span.values[row]
            assert np.all(np.abs(span.values[row] - self.truth[serial]) <= np.asarray(SPEC.eps))


def filled(window: int, n: int = 400) -> tuple[StreamEncoder, list[EncodedPacket], np.ndarray]:
    """A version 4 encoder with ``window`` packets taken and in flight (none resolved)."""
    times, values = noisy(n)
    enc = StreamEncoder(SPEC, max_latency=1.0, protocol=4)
    enc.set_window(window)
    taken: list[EncodedPacket] = []
    for t, x in zip(times, values, strict=True):
        enc.push(t, x)
        while enc.ready(t):
            taken.append(enc.take())
    assert len(taken) == window and not enc.ready(times[-1] + 60)  # the window is full
    return enc, taken, values


def drain(enc: StreamEncoder, shore: Shore, seen: set[int] | None = None) -> None:
    """Everything still pending, sent and delivered."""
    for _ in range(1000):
        if not (enc.pending or enc.in_flight):
            return
        while enc.pending and enc.ready(T0 + 10_000):
            shore.receive(enc.take())
        for flight in list(enc.in_flight):
            enc.resolve(True, flight.seq)
    raise AssertionError("never drained")


def test_a_window_delivers_every_sample_once_within_eps() -> None:
    enc, taken, values = filled(6)
    assert [p.packet.seq for p in taken] == list(range(6))
    assert len({p.packet.payload[0] for p in taken}) == 2  # the first from the initial state, then back 1
    shore = Shore(values)
    for packet in taken:
        shore.receive(packet)
        enc.resolve(True, packet.packet.seq)
    drain(enc, shore)
    assert sorted(shore.held) == list(range(len(values)))


def test_a_lost_frame_in_the_middle_of_a_window_is_coded_again_from_the_state_before_it() -> None:
    enc, taken, values = filled(6)
    shore = Shore(values)
    for packet in taken[:2]:
        shore.receive(packet)
        enc.resolve(True, packet.packet.seq)
    for packet in taken[3:]:  # they come, but the one they continue from did not: they wait, no restart
        with pytest.raises(UnknownBase) as caught:
            shore.dec.decode(packet.packet.payload, T0, packet.packet.seq)
        assert shore.dec.ahead(caught.value.base, packet.packet.seq)
    enc.resolve(True, 4)  # their ACKs are heard: they stay in flight behind the lost one
    assert enc.resolve(False, 2) == [3, 4, 5]  # the caller withdraws those: coded again
    assert enc.in_flight == []  # 0 and 1 delivered; 2 and those after it coded again
    again = enc.take(6)
    assert again.packet.seq == 6 and again.packet.payload[0] == 5  # back 5 seqs: packet 1's state
    assert again.serials[0][0] == taken[2].serials[0][0]  # the lost packet's first sample comes first
    shore.receive(again)
    enc.resolve(True, 6)
    drain(enc, shore)
    assert sorted(shore.held) == list(range(len(values)))  # nothing the vehicle held is lost
    for packet in taken[3:]:  # the abandoned branch's packets are never decoded on the new one
        with pytest.raises(UnknownBase):
            shore.dec.decode(packet.packet.payload, T0, packet.packet.seq)


def test_a_packet_the_vehicle_thinks_lost_but_the_shore_has_leaves_its_own_branch() -> None:
    """The ACK of packet 2 was lost four times, so the vehicle codes its samples again from packet 1's
    state, while the shore decoded packet 2 and holds its state: the new packets name packet 1's state by
    their own seqs, and packet 3 (on packet 2's state) still decodes on packet 2's, never on the new
    branch; every decoded value is within eps."""
    enc, taken, values = filled(4)
    shore = Shore(values)
    for packet in taken[:3]:
        shore.receive(packet)
    enc.resolve(True, 0), enc.resolve(True, 1)
    assert enc.resolve(False, 2) == [3]
    again = enc.take(4)
    redo = Shore(values)
    redo.dec.snapshots = dict(shore.dec.snapshots)  # the same shore, counted apart: its samples repeat
    redo.receive(again)
    assert again.packet.payload[0] == 3  # packet 1's state, 3 seqs back
    assert set(taken[2].serials[0]) <= set(redo.held)  # on packet 1's state, within eps
    shore.receive(taken[3])  # late, on packet 2's state: within eps (Shore.receive checks)


def test_a_duplicate_changes_nothing_and_a_reordering_waits_for_what_it_continues_from() -> None:
    enc, taken, values = filled(5)
    shore = Shore(values)
    shore.receive(taken[0])
    before = shore.dec.mark()
    copy = StreamDecoder(SPEC, 4)
    copy.snapshots = dict(before)
    first = copy.decode(taken[0].packet.payload, T0, 0)  # a duplicate decodes to the same values
    assert np.array_equal(first.values, shore.dec.decode(taken[0].packet.payload, T0, 0).values)
    shore.dec.undo(before)
    waiting = taken[2]
    with pytest.raises(UnknownBase) as caught:  # 2 before 1
        shore.dec.decode(waiting.packet.payload, T0, 2)
    assert shore.dec.ahead(caught.value.base, 2)
    shore.receive(taken[1])
    shore.receive(waiting)
    for packet in taken[3:]:
        shore.receive(packet)
    for packet in taken:
        enc.resolve(True, packet.packet.seq)
    drain(enc, shore)
    assert sorted(shore.held) == list(range(len(values)))


def test_a_base_too_far_back_to_name_starts_from_the_initial_state() -> None:
    """An hour of check-points between two priority packets: the next cannot name its base (63 seqs
    back at most), so it starts over, and the shore decodes it from the initial state."""
    times, values = noisy(8)
    enc, shore = StreamEncoder(SPEC, max_latency=1.0, protocol=4), Shore(values)
    enc.push(times[0], values[0])
    shore.receive(enc.take(10))
    enc.resolve(True)
    enc.push(times[1], values[1])
    later = enc.take(10 + 64)
    assert later.packet.payload[0] == 0
    shore.receive(later)


def test_the_window_is_version_4_s_and_at_most_its_limit() -> None:
    with pytest.raises(ValueError, match="protocol 3 keeps one packet in flight"):
        StreamEncoder(SPEC, protocol=3).set_window(2)
    enc = StreamEncoder(SPEC, protocol=4)
    enc.set_window(64)
    assert enc.window == MAX_WINDOW
    with pytest.raises(ValueError, match="seq"):
        StreamDecoder(SPEC, 4).decode(bytes(29), T0)
    with pytest.raises(CodecError, match="format version 3"):  # a version 3 payload to a version 4 shore
        StreamDecoder(SPEC, 4).decode(bytes([0xC0]) + bytes(28), T0, 0)


def test_predictable_until_is_the_oldest_surprise_the_shore_does_not_hold() -> None:
    """What a version-4 check-point says of the silence: the oldest sample the shore could not predict
    and does not hold (waiting or in flight), else now."""
    s = StreamSpec("t", Stream.ENVIRONMENTAL, ("t",), (0.05,), 1.0)
    enc = StreamEncoder(s, max_latency=10.0, max_silence=None, protocol=4)
    enc.push(T0, [10.0])
    assert enc.predictable_until(T0 + 1) == T0  # a first value far from the initial state's
    enc.take()
    assert enc.predictable_until(T0 + 1) == T0  # in flight: not delivered yet
    enc.resolve(True)
    for k in range(1, 30):  # quiet: predictable samples wait, no packet is due
        enc.push(T0 + k, [10.0])
    assert enc.pending and enc.deadline() is None and enc.predictable_until(T0 + 30) == T0 + 30
    enc.push(T0 + 30, [12.0])  # a surprise
    assert enc.predictable_until(T0 + 31) == T0 + 30
    enc.take()
    assert enc.predictable_until(T0 + 31) == T0 + 30  # in flight: not held yet
    enc.resolve(True)
    assert enc.predictable_until(T0 + 31) == T0 + 31
