"""32-byte packets: round trips, ranges, and garbage never escaping as anything but PacketError."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacit import auth, packets
from tacit.packets import (
    PACKET_SIZE,
    CheckpointPacket,
    Command,
    CommandStatus,
    ControlFlag,
    ControlPacket,
    FieldRangeError,
    MissionState,
    PacketError,
    Priority,
    PriorityPacket,
    Reason,
    Stream,
)


def fixed(lo: float, hi: float, res: float) -> st.SearchStrategy[float]:
    """Values already on the field's grid, so a round trip is exact."""
    return st.integers(round(lo / res), round(hi / res)).map(lambda n: round(n * res, 10))


controls = st.builds(
    ControlPacket,
    command=st.sampled_from([c for c in Command if c is not Command.SYNC]),
    seq=st.integers(0, 2**32 - 1),
    time=st.integers(0, 2**32 - 1),
    distance=fixed(0, 6553.5, 0.1),
    angle=fixed(-180, 180, 0.01),
    depth=fixed(-327.68, 327.67, 0.01),
    speed=fixed(0, 2.55, 0.01),
    param_id=st.integers(0, 255),
    param_value=st.floats(width=32, allow_nan=False, allow_infinity=False),
    flags=st.sampled_from([ControlFlag(0), ControlFlag.ABSOLUTE_ANGLE, ControlFlag.DELAY_SENSITIVE]),
)
syncs = st.builds(
    ControlPacket,
    command=st.just(Command.SYNC),
    seq=st.integers(0, 2**32 - 1),
    time=st.integers(0, 2**32 - 1),
    param_id=st.integers(0, 255),
    key_epoch=st.integers(0, 255),
    echo=st.binary(min_size=4, max_size=4),
)
checkpoints = st.builds(
    CheckpointPacket,
    seq=st.integers(0, 255),
    time=st.integers(0, 2**32 - 1),
    state=st.sampled_from(MissionState),
    mission_id=st.integers(0, 255),
    waypoint=st.integers(0, 255),
    north=fixed(-3276.8, 3276.7, 0.1),
    east=fixed(-3276.8, 3276.7, 0.1),
    depth=fixed(0, 655.35, 0.01),
    heading=fixed(0, 359.99, 0.01),
    battery=fixed(0, 25.5, 0.1),
    last_command=st.integers(0, 2**16 - 1),
    command_status=st.sampled_from(CommandStatus),
    reason=st.sampled_from(Reason),
    temperature=fixed(-327.68, 327.67, 0.01),
    oxygen=fixed(0, 655.35, 0.01),
    settled=st.integers(0, 255),
    covered=st.integers(0, 65535),
    flags=st.integers(0, 7),
    key_parity=st.integers(0, 1),
    unsynced=st.booleans(),
    holds_next_key=st.booleans(),
    mac=st.binary(min_size=4, max_size=4),
)
priorities = st.builds(
    PriorityPacket,
    seq=st.integers(0, 255),
    priority=st.sampled_from(Priority),
    stream=st.sampled_from(Stream),
    payload=st.binary(min_size=29, max_size=29),
    tag=st.integers(0, 255),
)


@given(st.one_of(controls, syncs))
def test_control_round_trip(packet: ControlPacket) -> None:
    frame = packet.signed_part() + bytes(8)
    assert len(frame) == PACKET_SIZE
    assert packets.decode(frame) == packet


@given(checkpoints)
def test_checkpoint_round_trip(packet: CheckpointPacket) -> None:
    frame = packet.encode()
    assert len(frame) == PACKET_SIZE
    assert packets.decode(frame) == packet


@given(priorities)
def test_priority_round_trip(packet: PriorityPacket) -> None:
    frame = packet.encode()
    assert len(frame) == PACKET_SIZE and frame[2] == packet.tag and frame[3:] == packet.payload
    assert packets.decode(frame) == packet


@given(st.binary(min_size=0, max_size=64))
@settings(max_examples=500)
def test_random_bytes_decode_or_raise_packet_error(frame: bytes) -> None:
    try:
        decoded = packets.decode(frame)
    except PacketError:
        return
    assert len(frame) == PACKET_SIZE
    assert isinstance(decoded, (ControlPacket, CheckpointPacket, PriorityPacket))


@given(checkpoints, st.integers(0, 31), st.integers(0, 7))
def test_bit_flipped_checkpoint_never_crashes(packet: CheckpointPacket, byte: int, bit: int) -> None:
    frame = bytearray(packet.encode())
    frame[byte] ^= 1 << bit
    try:
        packets.decode(bytes(frame))
    except PacketError:
        pass


@pytest.mark.parametrize(
    "changes, field",
    [
        ({"angle": 180.01}, "angle"),
        ({"angle": -181}, "angle"),
        ({"distance": -0.1}, "distance"),
        ({"distance": 6553.6}, "distance"),
        ({"depth": 400}, "depth"),
        ({"speed": 3}, "speed"),
        ({"seq": 2**32}, "seq"),
        ({"seq": -1}, "seq"),
        ({"param_value": float("nan")}, "param_value"),
        ({"param_value": float("inf")}, "param_value"),
        ({"distance": float("nan")}, "distance"),
    ],
)
def test_out_of_range_values_raise_with_the_field_named(changes: dict, field: str) -> None:
    packet = ControlPacket(**{"command": Command.MOVE, "seq": 1, "time": 1, **changes})
    with pytest.raises(FieldRangeError) as info:
        packet.signed_part()
    assert info.value.field == field and field in str(info.value)


def test_checkpoint_out_of_range_raises() -> None:
    with pytest.raises(FieldRangeError, match="depth"):
        CheckpointPacket(seq=0, time=0, state=MissionState.WAITING, depth=-1).encode()
    with pytest.raises(FieldRangeError, match="seq"):
        CheckpointPacket(seq=256, time=0, state=MissionState.WAITING).encode()


def test_values_are_rounded_to_resolution_not_wrapped() -> None:
    packet = ControlPacket(Command.MOVE, seq=1, time=1, distance=12.34, angle=-45.678, depth=1.005)
    decoded = packets.decode(packet.signed_part() + bytes(8))
    assert decoded.distance == pytest.approx(12.3) and decoded.angle == pytest.approx(-45.68)


@pytest.mark.parametrize(
    "frame, message",
    [
        (b"\x40" * 31, "32 bytes"),
        (bytes([0x00]) + bytes(31), "version"),
        (bytes([0xF0]) + bytes(31), "type"),
        (bytes([0x70]) + bytes(31), "type 3"),  # code 1 is version 4 now
        (bytes([0x00, 5]) + bytes(30), "unknown packet version 5 .byte 1"),
        (bytes([0x90]) + bytes(31), "protocol version 2 .*update its agent"),
        (bytes([0xC0, 0xEE]) + bytes(30), "command"),
        (bytes([0xD0, 0]) + bytes(4) + bytes([0x0E]) + bytes(25), "state"),
        (bytes([0xD0, 0]) + bytes(4) + bytes([0x40]) + bytes(25), "bits 6-7"),
        (bytes([0xD0, 0]) + bytes(18) + bytes([0xF0]) + bytes(11), "outcome"),
    ],
)
def test_bad_frames_raise_typed_errors(frame: bytes, message: str) -> None:
    with pytest.raises(PacketError, match=message):
        packets.decode(frame)


def test_reserved_bytes_must_be_zero() -> None:
    frame = bytearray(ControlPacket(Command.HOLD, seq=1, time=1).signed_part() + bytes(8))
    frame[23] = 1
    with pytest.raises(PacketError, match="reserved"):
        packets.decode(bytes(frame))


def test_layout_offsets_match_the_documented_table() -> None:
    frame = ControlPacket(
        Command.MOVE,
        seq=0x01020304,
        time=0x0A0B0C0D,
        distance=10.0,
        angle=-1.0,
        depth=2.5,
        speed=0.5,
        param_id=7,
        param_value=1.5,
    ).signed_part()
    assert frame[1] == Command.MOVE
    assert struct.unpack(">I", frame[2:6])[0] == 0x01020304
    assert struct.unpack(">I", frame[6:10])[0] == 0x0A0B0C0D
    assert struct.unpack(">H", frame[10:12])[0] == 100
    assert struct.unpack(">h", frame[12:14])[0] == -100
    assert struct.unpack(">h", frame[14:16])[0] == 250
    assert frame[16] == 50 and frame[17] == 7
    assert struct.unpack(">f", frame[18:22])[0] == 1.5
    assert ControlPacket(Command.HOLD, seq=1, time=1, key_epoch=7).signed_part()[22] == 7
    cp = CheckpointPacket(
        seq=9,
        time=5,
        state=MissionState.PREPROGRAMMED,
        temperature=21.5,
        covered=300,
        last_command=0x1234,
        command_status=CommandStatus.REFUSED,
        reason=Reason.GEOFENCE,
        settled=0xB1,
        flags=5,
        key_parity=1,
        mac=b"WXYZ",
    )
    encoded = cp.encode()
    assert encoded[0] == (3 << 6) | (1 << 4) | 8 | 5 and encoded[1] == 9
    assert struct.unpack(">H", encoded[18:20])[0] == 0x1234 and encoded[20] == 0x32 and encoded[21] == 0xB1
    assert struct.unpack(">h", encoded[22:24])[0] == 2150
    assert struct.unpack(">H", encoded[26:28])[0] == 300 and encoded[28:] == b"WXYZ"
    pp = PriorityPacket(seq=4, priority=Priority.TIME_SENSITIVE, stream=Stream.KINEMATIC, payload=b"")
    assert pp.encode()[0] == (3 << 6) | (2 << 4) | (3 << 2) | 1


def test_sync_and_checkpoint_flags_have_their_documented_places() -> None:
    sync = ControlPacket(Command.SYNC, seq=7, time=9, param_id=1, echo=b"WXYZ").signed_part()
    assert sync[17] == 1 and sync[18:22] == b"WXYZ"
    with pytest.raises(FieldRangeError, match="echo"):  # only a SYNC echoes
        ControlPacket(Command.HOLD, seq=1, time=1, echo=b"WXYZ").signed_part()
    with pytest.raises(FieldRangeError, match="echo"):  # a SYNC's param_value bytes are its echo
        ControlPacket(Command.SYNC, seq=1, time=1, param_value=1.0).signed_part()
    cp = CheckpointPacket(seq=1, time=2, state=MissionState.HOLDING, unsynced=True, holds_next_key=True)
    assert cp.encode()[6] == 0x10 | 0x20 | MissionState.HOLDING


def test_as_dict_is_json_friendly() -> None:
    cp = CheckpointPacket(seq=1, time=2, state=MissionState.HOLDING)
    view = packets.as_dict(cp)
    assert view["type"] == "checkpoint" and view["state"] == "holding"


def test_only_a_sync_is_scheduled() -> None:
    """The scheduled flag (a SYNC pre-signed for its time) on any other command is refused both ways."""
    key = bytes(range(32))
    hold = ControlPacket(Command.HOLD, seq=1, time=1, flags=ControlFlag.SCHEDULED)
    with pytest.raises(PacketError, match="only a SYNC"):
        auth.sign(hold, key, 2)
    sync = auth.sign(ControlPacket(Command.SYNC, seq=1, time=1, flags=ControlFlag.SCHEDULED), key, 2)
    assert packets.decode_control(sync).flags == ControlFlag.SCHEDULED
    with pytest.raises(PacketError, match="HOLD is flagged scheduled"):
        packets.decode_control(sync[:1] + bytes([Command.HOLD]) + sync[2:])


checkpoints_v4 = st.builds(
    CheckpointPacket,
    seq=st.integers(0, 255),
    time=st.integers(0, 2**32 - 1),
    state=st.sampled_from(MissionState),
    oxygen=st.one_of(fixed(0, 25.4, 0.1), st.just(packets.OXYGEN_NONE)),
    quiet=st.integers(0, 255),
    covered=st.integers(0, 65535),
    mac=st.binary(min_size=4, max_size=4),
    version=st.just(4),
)


@given(checkpoints_v4)
def test_version_4_checkpoint_round_trip(packet: CheckpointPacket) -> None:
    assert packets.decode(packet.encode()) == packet


@given(st.builds(PriorityPacket, seq=st.integers(0, 255), priority=st.sampled_from(Priority),
                 stream=st.sampled_from(Stream), payload=st.binary(min_size=29, max_size=29),
                 tag=st.integers(0, 255), version=st.just(4)))  # fmt: skip
def test_version_4_priority_round_trip(packet: PriorityPacket) -> None:
    assert packets.decode(packet.encode()) == packet


def test_version_4_header_code_and_checkpoint_layout() -> None:
    """Version 4 is code 1 in the header's two bits; its check-point has oxygen on byte 24 (0.1 mg/L,
    25.5 none) and the silence it says on byte 25; version 3's bytes are unchanged (golden)."""
    cp = CheckpointPacket(seq=9, time=5, state=MissionState.PREPROGRAMMED, temperature=21.5, oxygen=8.3,
                          quiet=42, covered=300, flags=5, key_parity=1, mac=b"WXYZ", version=4)  # fmt: skip
    encoded = cp.encode()
    assert encoded[0] == (1 << 6) | (1 << 4) | 8 | 5
    assert encoded[24] == 83 and encoded[25] == 42 and struct.unpack(">H", encoded[26:28])[0] == 300
    golden_v3 = "dd0900000005010000000000000000000000000000000866ffff012c5758595a"
    assert replace_version(cp, 3).encode().hex() == golden_v3
    golden_v4 = "5d0900000005010000000000000000000000000000000866532a012c5758595a"
    assert encoded.hex() == golden_v4
    none = packets.decode(replace_version(cp, 4, oxygen=packets.OXYGEN_NONE).encode())
    assert isinstance(none, CheckpointPacket) and none.oxygen == packets.OXYGEN_NONE
    with pytest.raises(FieldRangeError, match="oxygen"):
        replace_version(cp, 4, oxygen=30.0).encode()
    with pytest.raises(FieldRangeError, match="quiet"):  # version 3 cannot say a silence
        replace_version(cp, 3, quiet=10, oxygen=8.3).encode()


def replace_version(cp: CheckpointPacket, version: int, **changes: object) -> CheckpointPacket:
    from dataclasses import replace

    base = {"oxygen": packets.OXYGEN_NONE, "quiet": packets.QUIET_UNKNOWN} if version == 3 else {}
    return replace(cp, version=version, **{**base, **changes})  # type: ignore[arg-type]


def test_an_agent_of_either_version_takes_a_version_3_control_packet() -> None:
    """Control packets keep version 3's layout and code in version 4: one shore signs for every vehicle."""
    key = bytes(range(32))
    frame = auth.sign(ControlPacket(Command.HOLD, seq=1, time=1), key, 2)
    assert frame[0] >> 6 == 3 and packets.decode_control(frame).version == 3
    four = ControlPacket(Command.HOLD, seq=1, time=1, version=4).signed_part()
    assert four[0] >> 6 == 1 and four[1:] == frame[1:24]


def test_quiet_never_says_more_than_it_knows() -> None:
    assert packets.quiet_of(100, 99.5) == 1 and packets.quiet_of(100, 100.0) == 0  # rounded towards the past
    assert packets.quiet_of(100, 100.4) == 0  # a mark after the whole second: the second
    assert packets.quiet_of(1000, 746.0) == 254
    assert packets.quiet_of(1000, 745.5) == packets.QUIET_UNKNOWN  # too far back to say
    assert packets.quiet_of(1000, None) == packets.QUIET_UNKNOWN
    cp = CheckpointPacket(seq=1, time=1000, state=MissionState.HOLDING, quiet=40, version=4)
    assert packets.as_dict(cp)["predictable_until"] == 960
