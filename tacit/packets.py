"""The 32-byte packets of the Tacit protocol: control, check-point and priority.

Every packet is exactly one rate-0 Micro-Modem frame (32 bytes). Integers are big-endian.
Byte 0 is a header common to all packets::

    bit 7-6  version code: 3 = version 3, 1 = version 4, 0 = a later version, named by byte 1 (its
             layout after that byte is its own), 2 = version 2 (refused: ``OldVersion``). Version 2 had
             no check-point state flags and ordered SYNCs by time; version 1 had no key epoch in control
             packets and no MAC in check-points
    bit 5-4  type: 0 control (shore -> vehicle), 1 check-point, 2 priority (vehicle -> shore)
    bit 3-0  type-specific: control flags; check-point flags and key parity; priority: priority
             level (bits 3-2) and stream (bits 1-0)

Each vehicle speaks one version (``VERSIONS``), registered with it on the shore and set in its agent's
configuration, so a fleet moves to a new version one vehicle at a time. What version 4 changes:

- the check-point says the silence (``quiet``, below) and carries oxygen on one byte;
- the priority payload names states by packet seq, so a vehicle keeps a window of packets in flight
  (``tacit.codec.format``);
- control packets are unchanged: the shore sends them with the version 3 code to every vehicle, and a
  version 4 agent takes both codes.

Both directions are authenticated with the vehicle's key (``tacit.auth``): a control packet carries a
64-bit MAC; a check-point carries a 32-bit MAC that also covers the priority packets it lists, so a
priority packet spends only a one-byte tag of its own (it weeds out forged twins on arrival).

Control packet (shore -> vehicle), authenticated (see ``tacit.auth``):

==========  ====  =================  ==========================  ============  ==========
field       off   type               range                       resolution    unit
==========  ====  =================  ==========================  ============  ==========
header      0     u8                 flags: bit0 absolute angle, bit1 delay-sensitive, bit2 scheduled
                                     (a SYNC only, below)
command     1     u8                 ``Command``
seq         2     u32                0 .. 4294967295             1             -
time        6     u32                0 .. 4294967295             1             s (UNIX)
distance    10    u16                0 .. 6553.5                 0.1           m
angle       12    i16                -180 .. 180                 0.01          deg
depth       14    i16                -327.68 .. 327.67           0.01          m
speed       16    u8                 0 .. 2.55 (0 = default)     0.01          m/s
param_id    17    u8                 0 .. 255                    1             -
param_value 18    f32                finite float32                            -
key_epoch   22    u8                 0 .. 255                    1             key version mod 256
reserved    23    1 byte, zero
mac         24    8 bytes            truncated HMAC-SHA256 (64 bits)
==========  ====  =================  ==========================  ============  ==========

``angle`` is the heading change relative to the vehicle's heading (the paper's control packet),
or a true bearing from north when the absolute-angle flag is set. ``depth`` is the vertical
difference for MOVE (positive = deeper) and the target depth for GOTO_DEPTH. ``key_epoch`` names
the key the MAC was made with, so old and new keys can both be valid during a rotation.

A SYNC control packet (command 10) is the shore's authenticated "I am here", with its own layout:

==========  ====  =================  =============================================================
field       off   type               meaning
==========  ====  =================  =============================================================
header      0     u8                 flags zero, or bit 2 *scheduled*: pre-signed for its time (below)
command     1     u8                 10 (SYNC)
seq         2     u32                the SYNC counter: per vehicle, persisted by the shore, only grows
time        6     u32                the shore's clock, s (UNIX)
(zero)      10    7 bytes            distance, angle, depth, speed: zero
param_id    17    u8                 bit 0: restart the sample chains (the shore lost their state)
echo        18    4 bytes            the MAC of the unsynced check-point this SYNC answers; zero if none
key_epoch   22    u8                 as in every control packet
reserved    23    1 byte, zero
mac         24    8 bytes            truncated HMAC-SHA256 (64 bits), as in every control packet
==========  ====  =================  =============================================================

Only authentic control packets, SYNC included, reset the vehicle's link-lost timer: an
unauthenticated Micro-Modem poll ($CCCYC) is answered but proves nothing.

A *scheduled* SYNC is one the center signed in advance for a gateway to send when its time comes (the
SYNC budget, docs/backhaul.md): its counter is its time, it echoes nothing and restarts nothing, and the
vehicle accepts it only within ``tacit.auth.SCHEDULED_WINDOW`` of its own clock and never corrects its
clock by it. The flag is in the header, which the MAC covers; an agent that predates it refuses it as an
unknown flag (it then never takes a pre-signed SYNC), which is why no version change was needed.

Check-point packet (vehicle -> shore): "still here, still predictable", the state the shore's
predictors resynchronise on, the final statuses of recent commands, and the MAC that vouches for it
and for the priority packets sent before it:

==============  ====  ====  ==========================  ============  ==========
field           off   type  range                       resolution    unit
==============  ====  ====  ==========================  ============  ==========
header          0     u8    type 1; bits 2-0 flags: bit0 position fix, bit1 armed, bit2 link-lost
                            mode; bit 3 key parity (key version mod 2)
seq             1     u8    0 .. 255 (vehicle packet counter, wraps)
time            2     u32   0 .. 4294967295             1             s (UNIX)
state           6     u8    bits 3-0 ``MissionState``; bit 4 unsynced (the vehicle lost its state and
                            waits for a SYNC echoing this MAC); bit 5 holds_next_key (it has the key
                            after the one it signs with); bits 6-7 zero
mission_id      7     u8    0 .. 255                    1             -
waypoint        8     u8    0 .. 255                    1             -
north           9     i16   -3276.8 .. 3276.7           0.1           m from home
east            11    i16   -3276.8 .. 3276.7           0.1           m from home
depth           13    u16   0 .. 655.35                 0.01          m
heading         15    u16   0 .. 359.99                 0.01          deg
battery         17    u8    0 .. 25.5                   0.1           V
last_command    18    u16   0 .. 65535 (control seq mod 65536; the shore takes its latest match)
outcome         20    u8    bits 7-4 ``CommandStatus`` of last_command, bits 3-0 ``Reason``
settled         21    u8    2 bits each for last_command-1 (bits 1-0) .. last_command-4 (bits 7-6):
                            0 unknown, 1 executed, 2 refused, 3 superseded (a final status)
temperature     22    i16   -327.68 .. 327.67           0.01          degC
oxygen          24    u16   0 .. 655.34 (655.35 = none) 0.01          mg/L
covered         26    u16   bit i set: the priority packet with seq (seq - 1 - i) mod 256 is covered
mac             28    4 B   HMAC-SHA256 truncated to 32 bits over bytes 0-27, the vehicle address and
                            the SHA-256 of each covered priority packet, oldest first
==============  ====  ====  ==========================  ============  ==========

Version 4's check-point differs in two bytes (the rest, and the MAC, as above):

==============  ====  ====  ==========================  ============  ==========
oxygen          24    u8    0 .. 25.4 (25.5 = none)     0.1           mg/L (the stream's eps is 0.05)
quiet           25    u8    0 .. 254 (255 = not known)  1             s before ``time``
==============  ====  ====  ==========================  ============  ==========

``quiet`` is the silence the check-point says: every stream of the vehicle was predictable within its
eps up to ``time - quiet``, which is never later than the oldest sample the vehicle has not delivered
(``tacit.codec.PacketEncoder.predictable_until``); 255: the mark is more than 254 s back. The MAC covers
it as it covers every field.

Priority packet (vehicle -> shore), the paper's "two bytes of priority/type, thirty bytes of
samples" less one: byte 0 header (priority level 0-3, stream 0-3), byte 1 seq (u8, shared counter with
check-points), byte 2 tag (a one-byte MAC of the other 31 bytes, ``tacit.auth.priority_tag``: a forged
packet fails it with probability 255/256 and is never decoded), bytes 3-31 the samples as encoded by
the sample codec.

Decoding never raises anything but ``PacketError`` subclasses; encoding an out-of-range value
raises ``FieldRangeError`` (no silent wrap or clamp).
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass, fields, replace
from dataclasses import field as dataclass_field
from enum import IntEnum
from typing import Any, ClassVar, TypeVar

PACKET_SIZE = 32
VERSION = 3  # the version a packet is made in unless told otherwise (control packets: always)
VERSIONS = (3, 4)  # what this end speaks; each vehicle speaks one of them
NEWEST = VERSIONS[-1]  # what a vehicle registered or configured today speaks unless told otherwise
_CODES = {3: 3, 4: 1}  # version -> the header's 2-bit code
_EXTENDED = 0  # the code of a version named by byte 1
_OLD = 2  # version 2's code
OXYGEN_NONE_V4 = 25.5  # version 4's "no oxygen reading" on its one-byte field
QUIET_UNKNOWN = 255  # a check-point's ``quiet``: no silence to say
MAC_SIZE = 8
CHECKPOINT_MAC_SIZE = 4
ECHO = slice(18, 22)  # a SYNC's echo: where other commands carry param_value
COVER_BITS = 16  # how far back (in vehicle packet seqs) a check-point's MAC can reach
PAYLOAD_SIZE = 29
OXYGEN_NONE = 655.35
FLOAT32_MAX = struct.unpack(">f", b"\x7f\x7f\xff\xff")[0]


class PacketError(ValueError):
    """A frame that is not a valid Tacit packet."""


class OldVersion(PacketError):
    """A packet of the protocol version before this one: its sender needs updating, not a closer look."""


class FieldRangeError(PacketError):
    """A value outside the documented range of its field."""

    def __init__(self, field: str, value: object, lo: float, hi: float, unit: str) -> None:
        self.field, self.value, self.lo, self.hi, self.unit = field, value, lo, hi, unit
        super().__init__(f"{field}={value!r} is outside {lo} .. {hi} {unit}".rstrip())


class PacketType(enum.IntEnum):
    CONTROL = 0
    CHECKPOINT = 1
    PRIORITY = 2


class Command(enum.IntEnum):
    """What a control packet asks of the vehicle."""

    MOVE = 1  # distance, angle, depth change
    GOTO_DEPTH = 2  # depth = target depth
    HOLD = 3
    RESUME = 4  # resume the pre-programmed mission
    START_MISSION = 5  # param_id = mission id
    ABORT_MISSION = 6
    RETURN_HOME = 7
    SET_PARAM = 8  # param_id, param_value
    REQUEST_CHECKPOINT = 9
    SYNC = 10  # the shore's authenticated heartbeat (own layout: counter, time, restart bit, echo)

    @property
    def from_operator(self) -> bool:
        """An operator may send it (SYNC is the shore's own heartbeat)."""
        return self is not Command.SYNC

    @property
    def stops(self) -> bool:
        """It halts the vehicle (abort, hold): the shore sends it before every other command."""
        return self in (Command.HOLD, Command.ABORT_MISSION)

    @property
    def sets_course(self) -> bool:
        """The vehicle steers by it from now on: a course an older command set is abandoned."""
        return self in _COURSE

    @property
    def has_target(self) -> bool:
        """It names where to go (a move, a depth, home): its run ends on arrival."""
        return self in _TARGETED

    @property
    def ends_run(self) -> bool:
        """Executed at once, it ends the run of the command the vehicle was steering by."""
        return self.sets_course and not self.has_target


_TARGETED = frozenset({Command.MOVE, Command.GOTO_DEPTH, Command.RETURN_HOME})
_COURSE = _TARGETED | {Command.HOLD, Command.RESUME, Command.START_MISSION, Command.ABORT_MISSION}


SYNC_RESTART_CHAINS = 1
UNSYNCED = 0x10  # check-point state byte flags (bits 3-0 are the MissionState)
HOLDS_NEXT_KEY = 0x20


class ControlFlag(enum.IntFlag):
    ABSOLUTE_ANGLE = 1
    DELAY_SENSITIVE = 2
    SCHEDULED = 4  # a SYNC only: pre-signed for its time (the SYNC budget)


class MissionState(enum.IntEnum):
    """States of the vehicle's mission state machine (the paper's Algorithm 2)."""

    WAITING = 0
    PREPROGRAMMED = 1
    SELF_DETERMINED = 2
    AWAITING_COMMAND = 3
    COMMANDED = 4
    HOLDING = 5
    RETURNING = 6
    LINK_LOST = 7
    FINISHED = 8
    ABORTED = 9


class CommandStatus(enum.IntEnum):
    NONE = 0
    EXECUTING = 1
    EXECUTED = 2
    REFUSED = 3
    SUPERSEDED = 4


# The check-point's ``settled`` byte: 2-bit codes of final statuses.
SETTLED_CODES = {CommandStatus.EXECUTED: 1, CommandStatus.REFUSED: 2, CommandStatus.SUPERSEDED: 3}
SETTLED_STATUS = {code: status for status, code in SETTLED_CODES.items()}


def pack_settled(statuses: list[CommandStatus | None]) -> int:
    """The ``settled`` byte for the final statuses of last_command-1, -2, -3, -4 (None: unknown)."""
    out = 0
    for i, status in enumerate(statuses[:4]):
        out |= SETTLED_CODES.get(status, 0) << (2 * i) if status is not None else 0
    return out


def unpack_settled(byte: int) -> list[CommandStatus | None]:
    """The final statuses of last_command-1 .. -4 (None: unknown) from a ``settled`` byte."""
    return [SETTLED_STATUS.get((byte >> (2 * i)) & 3) for i in range(4)]


class Reason(enum.IntEnum):
    OK = 0
    OUT_OF_LIMITS = 1
    GEOFENCE = 2
    NO_POSITION_FIX = 3
    UNKNOWN_MISSION = 4
    UNKNOWN_PARAM = 5
    NOT_ARMED = 6
    VEHICLE_REFUSED = 7
    TIMEOUT = 8


class Priority(enum.IntEnum):
    ROUTINE = 0
    NOTABLE = 1
    IMPORTANT = 2
    TIME_SENSITIVE = 3


class Stream(enum.IntEnum):
    ENVIRONMENTAL = 0
    KINEMATIC = 1
    POSITION = 2
    MIXED = 3


@dataclass(frozen=True)
class Field:
    """One fixed-point field: stored integer = round(value / resolution)."""

    name: str
    fmt: str
    lo: float
    hi: float
    resolution: float = 1.0
    unit: str = ""
    enum: type[enum.IntEnum] | None = None

    @property
    def size(self) -> int:
        return struct.calcsize(">" + self.fmt)

    def encode(self, value: float) -> int | float:
        if self.enum is not None:
            member = int(value) if isinstance(value, float) and value.is_integer() else value
            try:
                if isinstance(member, int):
                    return int(self.enum(member))
            except ValueError:
                pass
            raise FieldRangeError(self.name, value, min(self.enum), max(self.enum), "")
        if self.fmt == "f":
            try:
                struct.pack(">f", value)
            except (OverflowError, struct.error):
                raise FieldRangeError(self.name, value, self.lo, self.hi, self.unit) from None
            if not math.isfinite(value):
                raise FieldRangeError(self.name, value, self.lo, self.hi, self.unit)
            return float(value)
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            raise FieldRangeError(self.name, value, self.lo, self.hi, self.unit)
        if not (self.lo - self.resolution / 2 <= value <= self.hi + self.resolution / 2):
            raise FieldRangeError(self.name, value, self.lo, self.hi, self.unit)
        raw = round(value / self.resolution)
        lo_raw, hi_raw = round(self.lo / self.resolution), round(self.hi / self.resolution)
        if not lo_raw <= raw <= hi_raw:
            raise FieldRangeError(self.name, value, self.lo, self.hi, self.unit)
        return raw

    def decode(self, raw: int | float) -> float | int | IntEnum:
        if self.enum is not None:
            try:
                return self.enum(int(raw))
            except ValueError:
                raise PacketError(f"{self.name}: unknown value {raw}") from None
        if self.fmt == "f":
            return raw
        if self.resolution == 1.0:
            return int(raw)
        value = raw * self.resolution
        if not self.lo - self.resolution / 2 <= value <= self.hi + self.resolution / 2:
            raise PacketError(f"{self.name}: {value} outside {self.lo} .. {self.hi} {self.unit}")
        return round(value, 10)


def _u(
    name: str, fmt: str, res: float = 1.0, unit: str = "", lo: float = 0, hi: float | None = None
) -> Field:
    """An unsigned/signed integer field whose range is the format's, unless given."""
    bits = struct.calcsize(">" + fmt) * 8
    if fmt.islower():
        lo_raw, hi_raw = -(2 ** (bits - 1)), 2 ** (bits - 1) - 1
        lo = lo_raw * res if lo == 0 else lo
    else:
        hi_raw = 2**bits - 1
    return Field(name, fmt, lo, hi_raw * res if hi is None else hi, res, unit)


def _e(name: str, kind: type[enum.IntEnum]) -> Field:
    return Field(name, "B", min(kind), max(kind), enum=kind)


@dataclass(frozen=True)
class _Packet:
    """Base of the three packet kinds: a header byte plus a table of fixed-point fields."""

    TYPE: ClassVar[PacketType]
    FIELDS: ClassVar[tuple[Field, ...]]
    TAIL: ClassVar[int]  # bytes after the fields (reserved zero, MAC or payload)

    version: int = dataclass_field(default=VERSION, kw_only=True)  # the protocol version (``VERSIONS``)

    def _header_low(self) -> int:
        return 0

    @classmethod
    def fields_of(cls, version: int) -> tuple[Field, ...]:
        """The field table of this kind of packet in ``version``."""
        return cls.FIELDS

    def _wire_value(self, name: str) -> float:
        return getattr(self, name)

    def _body(self) -> bytes:
        if self.version not in _CODES:
            raise FieldRangeError("version", self.version, min(VERSIONS), max(VERSIONS), "")
        table = self.fields_of(self.version)
        values = [f.encode(self._wire_value(f.name)) for f in table]
        fmt = ">" + "".join(f.fmt for f in table)
        header = (_CODES[self.version] << 6) | (int(self.TYPE) << 4) | self._header_low()
        return bytes([header]) + struct.pack(fmt, *values)

    @classmethod
    def _unpack_fields(cls, frame: bytes, version: int = VERSION) -> dict[str, Any]:
        # Any: each value's type is its field's (int, float or the field's enum), known from the table.
        table = cls.fields_of(version)
        fmt = ">" + "".join(f.fmt for f in table)
        size = struct.calcsize(fmt)
        raws = struct.unpack(fmt, frame[1 : 1 + size])
        return {f.name: f.decode(raw) for f, raw in zip(table, raws, strict=True)}

    @classmethod
    def body_size(cls, version: int = VERSION) -> int:
        return 1 + struct.calcsize(">" + "".join(f.fmt for f in cls.fields_of(version)))

    @classmethod
    def field(cls, name: str, version: int = VERSION) -> Field:
        """The field table's entry for ``name``: its range, resolution and unit (one source for the API's
        bounds, the screens' inputs and the agent's clamps)."""
        return next(f for f in cls.fields_of(version) if f.name == name)

    @classmethod
    def clamped(cls, version: int = VERSION, **values: float) -> dict[str, float]:
        """Measured values brought inside their fields' ranges in ``version`` (a sensor reading past what
        the packet can say is sent as the nearest value it can say, instead of refusing the whole
        packet)."""
        ranges = {f.name: (f.lo, f.hi) for f in cls.fields_of(version)}
        return {name: min(max(value, ranges[name][0]), ranges[name][1]) for name, value in values.items()}


@dataclass(frozen=True)
class ControlPacket(_Packet):
    """Shore -> vehicle: the paper's command, distance, angle and vertical difference."""

    command: Command
    seq: int
    time: int
    distance: float = 0.0
    angle: float = 0.0
    depth: float = 0.0
    speed: float = 0.0
    param_id: int = 0
    param_value: float = 0.0
    flags: ControlFlag = ControlFlag(0)
    key_epoch: int = 0
    echo: bytes = bytes(CHECKPOINT_MAC_SIZE)  # SYNC only, in param_value's bytes

    TYPE: ClassVar = PacketType.CONTROL
    FIELDS: ClassVar = (
        _e("command", Command),
        _u("seq", "I"),
        _u("time", "I", unit="s"),
        _u("distance", "H", 0.1, "m"),
        Field("angle", "h", -180.0, 180.0, 0.01, "deg"),
        _u("depth", "h", 0.01, "m"),
        _u("speed", "B", 0.01, "m/s"),
        _u("param_id", "B"),
        Field("param_value", "f", -FLOAT32_MAX, FLOAT32_MAX),
        _u("key_epoch", "B"),
    )
    TAIL: ClassVar = 1 + MAC_SIZE

    def _header_low(self) -> int:
        if self.flags & ControlFlag.SCHEDULED and self.command is not Command.SYNC:
            raise FieldRangeError("flags", int(self.flags), 0, 3, "(only a SYNC is scheduled)")
        return int(self.flags) & 0x0F

    def _body(self) -> bytes:
        """The fields; a SYNC's echo takes param_value's bytes (which a SYNC leaves at zero)."""
        body = super()._body()
        if self.command is not Command.SYNC:
            if any(self.echo):
                raise FieldRangeError("echo", self.echo.hex(), 0, 0, "(only a SYNC echoes)")
            return body
        if len(self.echo) != CHECKPOINT_MAC_SIZE or self.param_value:
            raise FieldRangeError("echo", bytes(self.echo).hex(), 4, 4, "bytes (a SYNC has no param_value)")
        return body[: ECHO.start] + bytes(self.echo) + body[ECHO.stop :]

    def signed_part(self) -> bytes:
        """The 24 bytes the MAC covers."""
        return self._body() + bytes(1)


@dataclass(frozen=True)
class CheckpointPacket(_Packet):
    """Vehicle -> shore heartbeat and predictor resynchronisation point (MAC: ``tacit.auth``)."""

    seq: int
    time: int
    state: MissionState
    mission_id: int = 0
    waypoint: int = 0
    north: float = 0.0
    east: float = 0.0
    depth: float = 0.0
    heading: float = 0.0
    battery: float = 0.0
    last_command: int = 0  # low 16 bits of the control seq
    command_status: CommandStatus = CommandStatus.NONE
    reason: Reason = Reason.OK
    settled: int = 0  # see ``pack_settled``
    temperature: float = 0.0
    oxygen: float = OXYGEN_NONE
    covered: int = 0
    flags: int = 0
    key_parity: int = 0
    unsynced: bool = False
    holds_next_key: bool = False
    mac: bytes = bytes(CHECKPOINT_MAC_SIZE)
    quiet: int = QUIET_UNKNOWN  # version 4: predictable up to ``time - quiet`` (s); see the table above

    TYPE: ClassVar = PacketType.CHECKPOINT
    FIELDS: ClassVar = (
        _u("seq", "B"),
        _u("time", "I", unit="s"),
        _u("state_byte", "B"),
        _u("mission_id", "B"),
        _u("waypoint", "B"),
        _u("north", "h", 0.1, "m"),
        _u("east", "h", 0.1, "m"),
        _u("depth", "H", 0.01, "m"),
        Field("heading", "H", 0.0, 359.99, 0.01, "deg"),
        _u("battery", "B", 0.1, "V"),
        _u("last_command", "H"),
        _u("outcome", "B"),
        _u("settled", "B"),
        _u("temperature", "h", 0.01, "degC"),
        _u("oxygen", "H", 0.01, "mg/L"),
        _u("covered", "H"),
    )
    FIELDS_V4: ClassVar = (
        *FIELDS[:-2],
        _u("oxygen", "B", 0.1, "mg/L"),
        _u("quiet", "B"),
        FIELDS[-1],
    )
    TAIL: ClassVar = CHECKPOINT_MAC_SIZE

    @classmethod
    def fields_of(cls, version: int) -> tuple[Field, ...]:
        return cls.FIELDS_V4 if version >= 4 else cls.FIELDS

    def _wire_value(self, name: str) -> float:
        """Version 4's oxygen says "none" with its own value; version 3 has no ``quiet`` to say."""
        if name == "oxygen" and self.version >= 4 and self.oxygen == OXYGEN_NONE:
            return OXYGEN_NONE_V4
        if name == "oxygen" and self.version >= 4 and self.oxygen >= OXYGEN_NONE_V4 - 0.05:
            raise FieldRangeError("oxygen", self.oxygen, 0, OXYGEN_NONE_V4 - 0.1, "mg/L")
        if self.version < 4 and self.quiet != QUIET_UNKNOWN:
            raise FieldRangeError("quiet", self.quiet, QUIET_UNKNOWN, QUIET_UNKNOWN, "(version 3 has none)")
        return super()._wire_value(name)

    @property
    def outcome(self) -> int:
        return (int(CommandStatus(self.command_status)) << 4) | int(Reason(self.reason))

    @property
    def state_byte(self) -> int:
        """The state and its flags, as the wire carries them."""
        flags = (UNSYNCED if self.unsynced else 0) | (HOLDS_NEXT_KEY if self.holds_next_key else 0)
        return int(MissionState(self.state)) | flags

    def _header_low(self) -> int:
        if not 0 <= self.flags <= 7:
            raise FieldRangeError("flags", self.flags, 0, 7, "")
        return self.flags | ((self.key_parity & 1) << 3)

    def signed_part(self) -> bytes:
        """The 28 bytes the MAC covers (with the covered priority packets' hashes)."""
        return self._body()

    def encode(self) -> bytes:
        if len(self.mac) != CHECKPOINT_MAC_SIZE:
            raise FieldRangeError("mac", f"{len(self.mac)} bytes", 4, 4, "bytes")
        return self._body() + bytes(self.mac)

    def covered_seqs(self) -> list[int]:
        """The seqs of the priority packets the MAC covers, oldest first."""
        return [(self.seq - 1 - i) % 256 for i in reversed(range(COVER_BITS)) if self.covered >> i & 1]


def quiet_of(time: int, until: float | None) -> int:
    """A version-4 check-point's ``quiet`` byte: the check-point made at ``time`` says its streams were
    predictable up to ``until`` (``tacit.codec.PacketEncoder.predictable_until``), rounded down to whole
    seconds so it never says more; ``QUIET_UNKNOWN`` for None or further back than 254 s."""
    if until is None or time - until > QUIET_UNKNOWN - 1:
        return QUIET_UNKNOWN
    return max(0, math.ceil(time - until))


def cover_bitmap(checkpoint_seq: int, seqs: list[int]) -> int:
    """The ``covered`` bitmap of a check-point with seq ``checkpoint_seq`` for priority packet ``seqs``
    (those further back than ``COVER_BITS`` are left out)."""
    bitmap = 0
    for seq in seqs:
        back = (checkpoint_seq - 1 - seq) % 256
        if back < COVER_BITS:
            bitmap |= 1 << back
    return bitmap


@dataclass(frozen=True)
class PriorityPacket(_Packet):
    """Vehicle -> shore: unpredictable samples (29 bytes, as the sample codec packs them) and their tag
    (set by ``tacit.auth.tag_priority``)."""

    seq: int
    priority: Priority
    stream: Stream
    payload: bytes
    tag: int = 0

    TYPE: ClassVar = PacketType.PRIORITY
    FIELDS: ClassVar = (_u("seq", "B"), _u("tag", "B"))
    TAIL: ClassVar = PAYLOAD_SIZE

    def _header_low(self) -> int:
        return (int(self.priority) << 2) | int(self.stream)

    def encode(self) -> bytes:
        Priority(self.priority), Stream(self.stream)
        if len(self.payload) > PAYLOAD_SIZE:
            raise FieldRangeError("payload", f"{len(self.payload)} bytes", 0, PAYLOAD_SIZE, "bytes")
        return self._body() + bytes(self.payload).ljust(PAYLOAD_SIZE, b"\0")


VehiclePacket = CheckpointPacket | PriorityPacket
_V = TypeVar("_V", CheckpointPacket, PriorityPacket)
Packet = ControlPacket | CheckpointPacket | PriorityPacket


def packet_version(frame: bytes) -> int:
    """The protocol version of a frame, after checking its length; ``PacketError`` (``OldVersion`` for
    version 2) for a version this end does not speak."""
    if not isinstance(frame, (bytes, bytearray)):
        raise PacketError(f"a packet is bytes, not {type(frame).__name__}")
    if len(frame) != PACKET_SIZE:
        raise PacketError(f"a packet is {PACKET_SIZE} bytes, got {len(frame)}")
    code = frame[0] >> 6
    if code == _OLD:
        raise OldVersion(f"protocol version 2 (this end speaks {VERSION} and later): update its agent")
    if code == _EXTENDED:
        speaks = ", ".join(map(str, VERSIONS))
        raise PacketError(f"unknown packet version {frame[1]} (byte 1; this end speaks {speaks})")
    return next(v for v, c in _CODES.items() if c == code)


def packet_type(frame: bytes) -> PacketType:
    """The type of a frame, after checking its length and version."""
    packet_version(frame)
    try:
        return PacketType((frame[0] >> 4) & 0x03)
    except ValueError:
        raise PacketError(f"unknown packet type {(frame[0] >> 4) & 0x03}") from None


def _check_zero(frame: bytes, start: int, end: int) -> None:
    if any(frame[start:end]):
        raise PacketError(f"reserved bytes {start}..{end - 1} are not zero")


def decode_control(frame: bytes) -> ControlPacket:
    """Decode a control packet's fields. The MAC is checked by ``tacit.auth``, not here."""
    values = ControlPacket._unpack_fields(frame)
    values["version"] = packet_version(frame)
    flags = frame[0] & 0x0F
    if flags & ~int(ControlFlag.ABSOLUTE_ANGLE | ControlFlag.DELAY_SENSITIVE | ControlFlag.SCHEDULED):
        raise PacketError(f"unknown control flags {flags:#x}")
    _check_zero(frame, 23, 24)
    if flags & ControlFlag.SCHEDULED and values["command"] is not Command.SYNC:
        raise PacketError(f"{values['command'].name} is flagged scheduled: only a SYNC is")
    if values["command"] is Command.SYNC:
        return ControlPacket(flags=ControlFlag(flags), **{**values, "param_value": 0.0}, echo=frame[ECHO])
    if not math.isfinite(values["param_value"]):
        raise PacketError("param_value is not finite")
    return ControlPacket(flags=ControlFlag(flags), **values)


def _state_flags(byte: int) -> dict[str, Any]:
    """A check-point's state byte as its fields (the state and its two flags)."""
    if byte & 0xC0:
        raise PacketError(f"state byte {byte:#04x}: bits 6-7 are not zero")
    try:
        state = MissionState(byte & 0x0F)
    except ValueError:
        raise PacketError(f"state: unknown value {byte & 0x0F}") from None
    return {"state": state, "unsynced": bool(byte & UNSYNCED), "holds_next_key": bool(byte & HOLDS_NEXT_KEY)}


def decode(frame: bytes) -> Packet:
    """Decode any 32-byte frame; raises ``PacketError`` for anything that is not a valid packet."""
    kind, version = packet_type(frame), packet_version(frame)
    frame = bytes(frame)
    if kind is PacketType.CONTROL:
        return decode_control(frame)
    if kind is PacketType.CHECKPOINT:
        values = CheckpointPacket._unpack_fields(frame, version)
        if version >= 4 and values["oxygen"] == OXYGEN_NONE_V4:
            values["oxygen"] = OXYGEN_NONE
        values.update(_state_flags(values.pop("state_byte")))
        outcome = values.pop("outcome")
        try:
            status, reason = CommandStatus(outcome >> 4), Reason(outcome & 0x0F)
        except ValueError:
            raise PacketError(f"outcome: unknown status/reason {outcome:#04x}") from None
        return CheckpointPacket(
            **values,
            command_status=status,
            reason=reason,
            flags=frame[0] & 0x07,
            key_parity=frame[0] >> 3 & 1,
            mac=frame[28:32],
            version=version,
        )
    return PriorityPacket(
        seq=frame[1],
        priority=Priority((frame[0] >> 2) & 0x03),
        stream=Stream(frame[0] & 0x03),
        payload=frame[3:],
        tag=frame[2],
        version=version,
    )


def with_seq(packet: _V, seq: int) -> _V:
    """A copy of a vehicle packet with another sequence number (u8, wraps)."""
    return replace(packet, seq=seq % 256)


def as_dict(packet: Packet) -> dict[str, object]:
    """A JSON-friendly view of a packet (enums by name, payload as hex)."""
    out: dict[str, object] = {"type": packet.TYPE.name.lower()}
    for f in fields(packet):
        value = getattr(packet, f.name)
        if isinstance(value, enum.Enum):
            value = value.name.lower() if not isinstance(value, enum.IntFlag) else int(value)
        elif isinstance(value, bytes):
            value = value.hex()
        out[f.name] = value
    if isinstance(packet, CheckpointPacket) and packet.version >= 4:  # the silence it says, as a time
        out["predictable_until"] = None if packet.quiet == QUIET_UNKNOWN else packet.time - packet.quiet
    return out


assert ControlPacket.body_size() == 23 and ControlPacket.body_size() + ControlPacket.TAIL == PACKET_SIZE
assert all(CheckpointPacket.body_size(v) + CheckpointPacket.TAIL == PACKET_SIZE for v in VERSIONS)
assert PriorityPacket.body_size() + PriorityPacket.TAIL == PACKET_SIZE
