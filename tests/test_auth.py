"""Control-packet authentication: bad MACs, flipped bits, replays and stale packets are rejected."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tacit import auth
from tacit.auth import BadMac, ControlReceiver, OutOfWindow, Replayed, ReplayWindow
from tacit.packets import Command, ControlPacket, PacketError

KEY = bytes(range(32))
NOW = 1_800_000_000


def frame(seq: int, stamp: int = NOW, key: bytes = KEY, address: int = 2) -> bytes:
    return auth.sign(ControlPacket(Command.MOVE, seq=seq, time=stamp, distance=10), key, address)


def test_valid_packet_is_accepted_once() -> None:
    receiver = ControlReceiver(KEY, 2)
    assert receiver.accept(frame(1), NOW).distance == 10
    with pytest.raises(Replayed):
        receiver.accept(frame(1), NOW)


@given(st.integers(0, 255))
def test_any_flipped_bit_is_rejected(bit: int) -> None:
    data = bytearray(frame(5))
    data[bit // 8] ^= 1 << (bit % 8)
    with pytest.raises(PacketError):
        ControlReceiver(KEY, 2).accept(bytes(data), NOW)


def test_wrong_key_and_wrong_vehicle_are_rejected() -> None:
    with pytest.raises(BadMac):
        ControlReceiver(KEY, 2).accept(frame(1, key=bytes(32)), NOW)
    with pytest.raises(BadMac):
        ControlReceiver(KEY, 3).accept(frame(1, address=2), NOW)


def test_stale_and_future_packets_are_out_of_window() -> None:
    receiver = ControlReceiver(KEY, 2, ReplayWindow(max_age=600))
    with pytest.raises(OutOfWindow):
        receiver.accept(frame(1, stamp=NOW - 601), NOW)
    with pytest.raises(OutOfWindow):
        receiver.accept(frame(2, stamp=NOW + 601), NOW)


def test_late_retransmission_within_window_counts_once() -> None:
    window = ReplayWindow()
    for seq in (10, 12, 11):
        window.accept(seq, NOW, NOW)
    for seq in (10, 11, 12):
        with pytest.raises(Replayed):
            window.accept(seq, NOW, NOW)
    window.accept(100, NOW, NOW)
    with pytest.raises(Replayed, match="older than the window"):
        window.accept(20, NOW, NOW)


@given(st.lists(st.integers(1, 300), max_size=60))
def test_window_accepts_each_sequence_at_most_once(seqs: list[int]) -> None:
    window = ReplayWindow()
    accepted: list[int] = []
    for seq in seqs:
        try:
            window.accept(seq, NOW, NOW)
            accepted.append(seq)
        except Replayed:
            pass
    assert len(accepted) == len(set(accepted))


def test_window_state_survives_a_restart() -> None:
    window = ReplayWindow()
    window.accept(7, NOW, NOW)
    restored = ReplayWindow.from_dict(window.to_dict())
    with pytest.raises(Replayed):
        restored.accept(7, NOW, NOW)
    restored.accept(8, NOW, NOW)


def test_key_parsing_errors_are_clear() -> None:
    assert auth.parse_key(KEY.hex()) == KEY
    with pytest.raises(ValueError, match="hex"):
        auth.parse_key("not hex")
    with pytest.raises(ValueError, match="16 bytes"):
        auth.parse_key("00ff")
