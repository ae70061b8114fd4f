"""Control-packet authentication: bad MACs, flipped bits, replays and stale packets are rejected."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tacit import auth
from tacit.auth import BadMac, ControlReceiver, OutOfWindow, Replayed, ReplayWindow
from tacit.packets import (
    CheckpointPacket,
    Command,
    ControlPacket,
    MissionState,
    PacketError,
    cover_bitmap,
    decode,
)

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


# --- key epochs, SYNC, the fresh-window floor ---------------------------------------------------

NEW = bytes(range(32, 64))


def test_old_and_new_key_are_both_valid_by_the_epoch_they_name() -> None:
    receiver = ControlReceiver({1: KEY, 2: NEW}, 2)
    packet = ControlPacket(Command.HOLD, seq=1, time=NOW)
    assert receiver.accept(auth.sign(packet, KEY, 2, epoch=1), NOW).key_epoch == 1
    assert receiver.accept(auth.sign(ControlPacket(Command.HOLD, seq=2, time=NOW), NEW, 2, epoch=2), NOW)
    with pytest.raises(BadMac):  # the right key under the wrong epoch
        receiver.accept(auth.sign(ControlPacket(Command.HOLD, seq=3, time=NOW), NEW, 2, epoch=1), NOW)
    with pytest.raises(BadMac, match="epoch 3"):
        receiver.accept(auth.sign(ControlPacket(Command.HOLD, seq=4, time=NOW), NEW, 2, epoch=3), NOW)


def test_sync_corrects_the_clock_within_limits_and_never_replays() -> None:
    receiver = ControlReceiver(KEY, 2, sync=auth.SyncWindow(max_correction=3600))
    skewed = NOW - 1500  # the vehicle's clock is 25 minutes slow: commands would be out of window
    sync = auth.sign(ControlPacket(Command.SYNC, seq=1, time=NOW), KEY, 2)
    assert receiver.accept(sync, skewed).time == NOW
    with pytest.raises(Replayed):
        receiver.accept(sync, skewed)
    with pytest.raises(OutOfWindow):  # commands use the corrected clock: without the offset, too old
        receiver.accept(frame(1), skewed)
    assert receiver.accept(frame(1), skewed, offset=NOW - skewed).seq == 1
    far = auth.sign(ControlPacket(Command.SYNC, seq=2, time=NOW + 7200), KEY, 2)
    with pytest.raises(OutOfWindow, match="corrected"):
        receiver.accept(far, NOW)


def test_a_fresh_window_refuses_frames_stamped_before_the_restart() -> None:
    captured = frame(1, stamp=NOW - 60)  # recorded a minute before the agent lost its state
    receiver = ControlReceiver(KEY, 2, ReplayWindow(floor=NOW - 5))
    with pytest.raises(Replayed, match="before the replay window"):
        receiver.accept(captured, NOW)
    assert receiver.accept(frame(1, stamp=NOW), NOW).seq == 1  # the shore re-signs each attempt


# --- check-points ---------------------------------------------------------------------------------


def _checkpoint(covered_seqs: list[int], seq: int = 20) -> CheckpointPacket:
    return CheckpointPacket(
        seq=seq,
        time=NOW,
        state=MissionState.PREPROGRAMMED,
        north=12.5,
        covered=cover_bitmap(seq, covered_seqs),
    )


PRIORITY = [bytes([0xC0 | 0x20, s, 0]) + bytes([s]) * 29 for s in range(20)]


def test_checkpoint_mac_covers_itself_and_the_priority_packets() -> None:
    cp = _checkpoint([17, 18, 19])
    frame_ = auth.sign_checkpoint(cp, KEY, 1, 2, [auth.packet_hash(PRIORITY[s]) for s in (17, 18, 19)])
    decoded = decode(frame_)
    assert decoded.covered_seqs() == [17, 18, 19]
    hashes = [[auth.packet_hash(PRIORITY[s])] for s in decoded.covered_seqs()]
    assert auth.verify_checkpoint(decoded, {1: KEY}, 2, hashes)[0] == 1
    forged_priority = [[auth.packet_hash(PRIORITY[17])], [auth.packet_hash(PRIORITY[0])], hashes[2]]
    with pytest.raises(BadMac):
        auth.verify_checkpoint(decoded, {1: KEY}, 2, forged_priority)
    with pytest.raises(BadMac):  # another vehicle's address
        auth.verify_checkpoint(decoded, {1: KEY}, 3, hashes)
    with pytest.raises(BadMac):  # a packet never received cannot be vouched for
        auth.verify_checkpoint(decoded, {1: KEY}, 2, [[], *hashes[1:]])
    # a forged copy of seq 18 arrived too: both candidates are tried, the genuine one matches
    two = [hashes[0], [auth.packet_hash(PRIORITY[0]), hashes[1][0]], hashes[2]]
    assert auth.verify_checkpoint(decoded, {1: KEY}, 2, two)[1][1] == hashes[1][0]
    many = [[auth.packet_hash(PRIORITY[i]) for i in range(3)]] * 3
    with pytest.raises(BadMac, match="at most"):
        auth.verify_checkpoint(decoded, {1: KEY}, 2, many)


@given(st.integers(0, 255))
def test_any_flipped_bit_in_a_checkpoint_is_rejected(bit: int) -> None:
    cp = _checkpoint([19])
    data = bytearray(auth.sign_checkpoint(cp, KEY, 1, 2, [auth.packet_hash(PRIORITY[19])]))
    data[bit // 8] ^= 1 << (bit % 8)
    try:
        decoded = decode(bytes(data))
    except PacketError:
        return
    if not isinstance(decoded, CheckpointPacket):
        return
    hashes = [[auth.packet_hash(PRIORITY[s % 20])] for s in decoded.covered_seqs()]
    with pytest.raises(BadMac):
        auth.verify_checkpoint(decoded, {1: KEY, 2: NEW}, 2, hashes)


def test_checkpoint_key_parity_selects_old_or_new_key() -> None:
    cp = _checkpoint([])
    decoded = decode(auth.sign_checkpoint(cp, NEW, 2, 2, []))
    assert decoded.key_parity == 0
    assert auth.verify_checkpoint(decoded, {1: KEY, 2: NEW}, 2, [])[0] == 2
    with pytest.raises(BadMac):
        auth.verify_checkpoint(decoded, {1: KEY}, 2, [])


def test_a_priority_tag_weeds_out_forged_twins() -> None:
    from tacit.packets import Priority, PriorityPacket, Stream

    frame = auth.tag_priority(PriorityPacket(7, Priority.ROUTINE, Stream.KINEMATIC, bytes(range(29))), KEY, 2)
    assert auth.tag_matches(frame, {1: KEY}, 2) and decode(frame).payload == bytes(range(29))
    assert not auth.tag_matches(frame, {1: NEW}, 2) or not auth.tag_matches(frame, {1: KEY}, 3)
    twins = [
        bytes(b ^ (1 << i % 8) if k == 3 + i // 8 else b for k, b in enumerate(frame)) for i in range(232)
    ]
    assert sum(auth.tag_matches(twin, {1: KEY}, 2) for twin in twins) <= 4  # 1 in 256 expected
