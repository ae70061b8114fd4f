"""Authentication of both directions of the acoustic link, and the replay defences.

Anyone with a Micro-Modem in the water can transmit, claiming any address, in either direction.

Shore -> vehicle. Each control packet carries a 64-bit truncated HMAC-SHA256 under the vehicle's key
of the epoch it names (byte 22: key version mod 256). 64 bits is longer than MAVLink 2 signing's 48:
at 80 bit/s an attacker gets well under one guess per second, so forging by brute force would take
~10^11 years; the cost is 8 of 32 bytes, affordable because a control packet has few fields. The MAC
also covers the destination address (not transmitted), so a packet signed for one vehicle cannot be
replayed to another sharing the key.

Replays of commands are stopped by the sequence number (a sliding window remembers which of the last
64 were seen, as IPsec does, so a retransmission that arrives late still counts once), by the time
stamp (older or newer than ``max_age`` seconds against the vehicle's corrected clock is rejected) and
by a time floor (nothing stamped before the SYNC that answered the vehicle's challenge, below).

SYNC packets (the shore's heartbeat and clock) have their own counter, persisted by the shore per
vehicle: it must grow, and a SYNC's time may differ from the vehicle's clock by at most
``max_correction``. Ordering by counter rather than by time lets a shore clock that stepped ahead and
was fixed be heard again at its next SYNC.

A *scheduled* SYNC (flag ``SCHEDULED``: pre-signed by the center for a gateway to send during a
backhaul outage, docs/backhaul.md) is held to a much narrower window: its time within
``SCHEDULED_WINDOW`` of the vehicle's corrected clock (local clock plus the offset the center's own
SYNCs set). It resets the link-lost timer and raises the counter, but never moves the clock: its stamp is
the time it was due, not a reading of the shore's clock, so the window stays anchored to the center's
last SYNC and no run of scheduled SYNCs can walk the clock away. The window is two minutes because a
gateway sends each within one budget step (at most a minute, ``SCHEDULED_WINDOW / 2``) after its time,
with seconds of travel and airtime; the vehicle's clock is within the agent's 30 s correction dead band
of the last fresh SYNC's time (a fresh SYNC goes within seconds of its stamp: the center stamps it for
its gateway's slot). A recording of one the vehicle missed is refused when replayed later than that; one
the vehicle heard, or older than one it heard, by its counter. A captured gateway can release one at
most two minutes early (its counter then makes the vehicle refuse the center's SYNCs stamped before it,
for those two minutes at most).

A vehicle that lost its state (no SYNC counter: *unsynced*) accepts no command and no SYNC but one that
echoes the MAC of a check-point it signed since it started (``SyncWindow.challenge``): a recorded SYNC
cannot echo a MAC that did not exist when it was recorded. That SYNC sets the counter and the command
window's floor (its time minus ``FLOOR_SLACK``); the floor never moves back afterwards.

Vehicle -> shore. A check-point carries a 32-bit MAC over its 28 bytes, the vehicle's address and the
SHA-256 of every priority packet it lists as covered (a 16-bit map of the seqs before it), so one
32-bit tag vouches for the check-point and for up to 16 priority packets: a priority packet spends no
bits on authentication beyond a one-byte tag (``priority_tag``) that weeds out forged twins before
anything decodes them, and its data is shown as unverified until a check-point covers it. Forgery
odds: 2^-32 per attempt. A forged frame is one rate-0 transmission (>= 3.2 s of airtime at 80 bit/s
plus the cycle), so a transmitter sending nothing else makes at most ~27,000 attempts a day; the shore
tries at most ``MAX_COMBINATIONS`` candidate sets per check-point (when two packets claim one seq), so
the odds of one success are at most 27,000 x 4 x 2^-32 = 2.5e-5 a day (one in ~110 years), and every
failed attempt is logged. The key parity bit (key version mod 2) in the header says which of the two
keys of a staged rotation signed it.

"""

from __future__ import annotations

import hashlib
import hmac
import itertools
import os
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

from tacit.packets import (
    CHECKPOINT_MAC_SIZE,
    MAC_SIZE,
    CheckpointPacket,
    Command,
    ControlFlag,
    ControlPacket,
    PacketError,
    PacketType,
    PriorityPacket,
    decode_control,
    packet_type,
)

KEY_SIZE = 32
MAX_KEY_SIZE = 64
_DOMAIN = b"tacit-control-v2"
_CP_DOMAIN = b"tacit-checkpoint-v2"
_TAG_DOMAIN = b"tacit-priority-v3"
MAX_COMBINATIONS = 4
MAX_CORRECTION = 86400.0 + 3600.0  # s a SYNC may move a clock: one set a whole day wrong, with its
# travel and an hour of drift on top (a bound of exactly a day refused the SYNC that would fix it)
CHALLENGES = 8  # the MACs of its latest check-points an unsynced vehicle takes an echo of
FLOOR_SLACK = 5  # s: a command stamped this much before the answering SYNC's time still counts
SCHEDULED_WINDOW = 120.0  # s: a scheduled SYNC is accepted this close to the vehicle's corrected clock


class AuthError(PacketError):
    """A control packet that failed authentication."""


class BadMac(AuthError):
    pass


class Unverifiable(BadMac):
    """A check-point covers a priority packet this shore never received (its modem acknowledged it while
    the shore was down): it may well be genuine, but its MAC cannot be checked, so it is not applied."""


class Replayed(AuthError):
    pass


class OutOfWindow(AuthError):
    pass


class Unsynced(AuthError):
    """Refused by a vehicle that lost its state, until a SYNC answers one of its check-points."""


def new_key() -> bytes:
    """A fresh random per-vehicle key."""
    return os.urandom(KEY_SIZE)


def parse_key(text: str) -> bytes:
    """A key from its hex form, with a clear error."""
    try:
        key = bytes.fromhex(text.strip())
    except ValueError:
        raise ValueError("a vehicle key is hex text") from None
    if len(key) < 16:
        raise ValueError(f"a vehicle key needs at least 16 bytes, got {len(key)}")
    if len(key) > MAX_KEY_SIZE:
        raise ValueError(f"a vehicle key has at most {MAX_KEY_SIZE} bytes, got {len(key)}")
    return key


def mac(key: bytes, address: int, signed: bytes) -> bytes:
    """The truncated MAC of a control packet's first 24 bytes for the vehicle at ``address``."""
    return hmac.new(key, _DOMAIN + bytes([address & 0xFF]) + signed, hashlib.sha256).digest()[:MAC_SIZE]


def sign(packet: ControlPacket, key: bytes, address: int, epoch: int | None = None) -> bytes:
    """The 32-byte frame of a control packet, signed for the vehicle at ``address`` (with the key of
    ``epoch``, stamped in the packet, when given)."""
    if epoch is not None:
        packet = replace(packet, key_epoch=epoch % 256)
    signed = packet.signed_part()
    return signed + mac(key, address, signed)


Keys = Mapping[int, bytes]  # key version -> key


def verify(frame: bytes, key: bytes | Keys, address: int) -> ControlPacket:
    """Decode a control frame whose MAC is valid under the key of the epoch it names (or ``key``, if
    one key is given); raises ``BadMac`` or ``PacketError`` otherwise."""
    if packet_type(frame) is not PacketType.CONTROL:
        raise PacketError("not a control packet")
    frame = bytes(frame)
    if isinstance(key, (bytes, bytearray)):
        candidates = [bytes(key)]
    else:
        candidates = [k for version, k in key.items() if version % 256 == frame[22]]
        if not candidates:
            raise BadMac(f"control packet names key epoch {frame[22]}, which this vehicle does not hold")
    if not any(hmac.compare_digest(mac(k, address, frame[:24]), frame[24:]) for k in candidates):
        raise BadMac("control packet MAC does not match this vehicle's key")
    return decode_control(frame)


def priority_tag(key: bytes, address: int, frame: bytes) -> int:
    """The one-byte tag of a priority packet: a MAC of its bytes but the tag (byte 2) for the vehicle at
    ``address``. It makes a forged twin of a genuine packet fail at once (255 times in 256), so the shore
    never decodes it and the check-point's candidate set per seq is almost always the genuine packet."""
    message = _TAG_DOMAIN + bytes([address & 0xFF]) + bytes(frame[:2]) + bytes(frame[3:])
    return hmac.new(key, message, hashlib.sha256).digest()[0]


def tag_priority(packet: PriorityPacket, key: bytes, address: int) -> bytes:
    """The 32-byte frame of a priority packet, tagged for the vehicle at ``address``."""
    frame = packet.encode()
    return frame[:2] + bytes([priority_tag(key, address, frame)]) + frame[3:]


def tag_matches(frame: bytes, keys: Keys, address: int) -> bool:
    """Whether a priority packet's tag is right under one of the vehicle's keys."""
    return any(
        hmac.compare_digest(bytes([priority_tag(k, address, frame)]), frame[2:3]) for k in keys.values()
    )


def packet_hash(packet: bytes) -> bytes:
    """What a check-point's MAC covers of a priority packet."""
    return hashlib.sha256(bytes(packet)).digest()


def checkpoint_mac(key: bytes, address: int, signed: bytes, covered: Sequence[bytes]) -> bytes:
    """The 32-bit tag of a check-point's first 28 bytes and the hashes of the packets it covers."""
    message = _CP_DOMAIN + bytes([address & 0xFF]) + signed + b"".join(covered)
    return hmac.new(key, message, hashlib.sha256).digest()[:CHECKPOINT_MAC_SIZE]


def sign_checkpoint(
    packet: CheckpointPacket, key: bytes, version: int, address: int, covered: Sequence[bytes]
) -> bytes:
    """The 32-byte frame of a check-point whose ``covered`` map lists the priority packets with the
    given hashes (oldest first), signed with the key of ``version`` by the vehicle at ``address``."""
    packet = replace(packet, key_parity=version & 1, mac=bytes(CHECKPOINT_MAC_SIZE))
    signed = packet.signed_part()
    return signed + checkpoint_mac(key, address, signed, covered)


def verify_checkpoint(
    packet: CheckpointPacket, keys: Keys, address: int, candidates: Sequence[Sequence[bytes]]
) -> tuple[int, tuple[bytes, ...]]:
    """Check a decoded check-point: ``candidates[i]`` are the hashes of the packets the shore holds for
    its i-th covered seq (usually one). Returns (key version, the hashes that matched); raises
    ``BadMac`` if none does, or if more than ``MAX_COMBINATIONS`` sets would have to be tried."""
    versions = [v for v in keys if v % 2 == packet.key_parity]
    if not versions:
        raise BadMac("no key of this parity")
    if any(not c for c in candidates):
        raise Unverifiable("a covered priority packet was never received here")
    combinations = 1
    for c in candidates:
        combinations *= len(c)
    if combinations > MAX_COMBINATIONS:
        raise BadMac(f"{combinations} candidate sets of covered packets (at most {MAX_COMBINATIONS} tried)")
    signed = replace(packet, mac=bytes(CHECKPOINT_MAC_SIZE)).signed_part()
    for version in versions:
        for chosen in itertools.product(*candidates):
            if hmac.compare_digest(checkpoint_mac(keys[version], address, signed, chosen), packet.mac):
                return version, chosen
    raise BadMac("check-point MAC does not match")


@dataclass
class ReplayWindow:
    """Accepts each control sequence number once, and only from a recent time stamp (and none stamped
    before ``floor``: set when the window's memory was lost)."""

    max_age: float = 600.0
    size: int = 64
    highest: int = 0
    seen: int = 0  # bit i set: sequence (highest - i) was accepted
    floor: int = 0

    def check(self, seq: int, stamp: int, now: float) -> None:
        """Raise ``Replayed`` or ``OutOfWindow`` if (seq, stamp) must not be accepted."""
        if abs(now - stamp) > self.max_age:
            raise OutOfWindow(f"control seq {seq} is stamped {stamp - now:+.0f} s from now")
        if stamp < self.floor:
            raise Replayed(f"control seq {seq} is stamped before the replay window was reset")
        if seq > self.highest:
            return
        offset = self.highest - seq
        if offset >= self.size:
            raise Replayed(f"control seq {seq} is older than the window (highest {self.highest})")
        if self.seen >> offset & 1:
            raise Replayed(f"control seq {seq} was already accepted")

    def accept(self, seq: int, stamp: int, now: float) -> None:
        """Check and record (seq, stamp)."""
        self.check(seq, stamp, now)
        if seq > self.highest:
            shift = seq - self.highest
            self.seen = ((self.seen << shift) | 1) & ((1 << self.size) - 1) if shift < self.size else 1
            self.highest = seq
        else:
            self.seen |= 1 << (self.highest - seq)

    def to_dict(self) -> dict[str, int]:
        return {"highest": self.highest, "seen": self.seen, "floor": self.floor}

    @classmethod
    def from_dict(cls, data: dict[str, int], max_age: float = 600.0) -> ReplayWindow:
        return cls(
            max_age=max_age,
            highest=int(data["highest"]),
            seen=int(data["seen"]),
            floor=int(data.get("floor", 0)),
        )


@dataclass
class SyncWindow:
    """Accepts SYNC packets whose counter (``seq``) grows, within ``max_correction`` s of the local clock
    (a scheduled one: within ``SCHEDULED_WINDOW`` of the local clock plus ``offset``, the correction the
    center's SYNCs gave); while unsynced (``counter`` None: the state was lost), only one that echoes a
    challenge."""

    max_correction: float = MAX_CORRECTION
    counter: int | None = 0  # the last accepted SYNC's; None: unsynced
    challenges: deque[bytes] = field(default_factory=lambda: deque(maxlen=CHALLENGES))

    @property
    def unsynced(self) -> bool:
        return self.counter is None

    def challenge(self, checkpoint_mac: bytes) -> None:
        """A check-point signed while unsynced: a SYNC echoing its MAC answers it."""
        self.challenges.append(bytes(checkpoint_mac))

    def accept(self, packet: ControlPacket, local_now: float, offset: float = 0.0) -> bool:
        """Check and record a SYNC; True if it answered a challenge (the vehicle is synced from now)."""
        if self.counter is None:
            if not any(packet.echo) or packet.echo not in self.challenges:
                raise Unsynced(f"SYNC {packet.seq} answers none of this start's check-points")
            self.counter = packet.seq
            self.challenges.clear()
            return True
        if packet.flags & ControlFlag.SCHEDULED and abs(packet.time - local_now - offset) > SCHEDULED_WINDOW:
            raise OutOfWindow(
                f"scheduled SYNC {packet.seq} stamped {packet.time - local_now - offset:+.0f} s from the "
                f"vehicle's clock (at most {SCHEDULED_WINDOW:.0f} s)"
            )
        if abs(packet.time - local_now) > self.max_correction:
            raise OutOfWindow(
                f"SYNC stamped {packet.time - local_now:+.0f} s from the local clock "
                f"(at most {self.max_correction:.0f} s is corrected)"
            )
        if packet.seq <= self.counter:
            raise Replayed(f"SYNC {packet.seq} is not newer than {self.counter}")
        self.counter = packet.seq
        return False


@dataclass
class ControlReceiver:
    """The vehicle's gate for control frames: MAC (under the key epoch it names), then the replay
    window (commands; none while unsynced) or the SYNC window (heartbeats), then the decoded packet.

    ``accept`` takes the local clock and ``offset``, the correction learnt from the shore's SYNC time
    (commands are checked against local + offset; SYNC against the local clock within its limit)."""

    key: bytes | Keys
    address: int
    window: ReplayWindow = field(default_factory=ReplayWindow)
    sync: SyncWindow = field(default_factory=SyncWindow)

    def accept(self, frame: bytes, now: float, offset: float = 0.0) -> ControlPacket:
        packet = verify(frame, self.key, self.address)
        if packet.command is Command.SYNC:
            if self.sync.accept(packet, now, offset):
                self.window.floor = packet.time - FLOOR_SLACK  # nothing recorded before it passes
        elif self.sync.unsynced:
            raise Unsynced(f"control seq {packet.seq}: no SYNC has answered this vehicle's check-points")
        else:
            self.window.accept(packet.seq, packet.time, now + offset)
        return packet
