"""Authentication of control packets: a truncated HMAC and a replay window.

An acoustic command must not be spoofable: anyone with a Micro-Modem in the water can transmit.
Each control packet carries a 64-bit truncated HMAC-SHA256 under a per-vehicle key. 64 bits is
longer than MAVLink 2 signing's 48: at 80 bit/s an attacker gets well under one guess per second,
so forging by brute force would take ~10^11 years; the cost is 8 of 32 bytes, affordable because a
control packet has few fields. The MAC also covers the destination address (not transmitted), so a
packet signed for one vehicle cannot be replayed to another sharing the key.

Replays are stopped by the sequence number (a sliding window remembers which of the last 64 were
seen, as IPsec does, so a retransmission that arrives late still counts once) and by the time stamp
(a packet older or newer than ``max_age`` seconds against the vehicle's clock is rejected, so a
recording played back after the window's state is lost still fails).
"""

from __future__ import annotations

import hashlib
import hmac
import os
from dataclasses import dataclass, field

from tacit.packets import MAC_SIZE, ControlPacket, PacketError, PacketType, decode_control, packet_type

KEY_SIZE = 32
MAX_KEY_SIZE = 64
_DOMAIN = b"tacit-control-v1"


class AuthError(PacketError):
    """A control packet that failed authentication."""


class BadMac(AuthError):
    pass


class Replayed(AuthError):
    pass


class OutOfWindow(AuthError):
    pass


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


def sign(packet: ControlPacket, key: bytes, address: int) -> bytes:
    """The 32-byte frame of a control packet, signed for the vehicle at ``address``."""
    signed = packet.signed_part()
    return signed + mac(key, address, signed)


def verify(frame: bytes, key: bytes, address: int) -> ControlPacket:
    """Decode a control frame whose MAC is valid; raises ``BadMac`` or ``PacketError`` otherwise."""
    if packet_type(frame) is not PacketType.CONTROL:
        raise PacketError("not a control packet")
    frame = bytes(frame)
    if not hmac.compare_digest(mac(key, address, frame[:24]), frame[24:]):
        raise BadMac("control packet MAC does not match this vehicle's key")
    return decode_control(frame)


@dataclass
class ReplayWindow:
    """Accepts each control sequence number once, and only from a recent time stamp."""

    max_age: float = 600.0
    size: int = 64
    highest: int = 0
    seen: int = 0  # bit i set: sequence (highest - i) was accepted

    def check(self, seq: int, stamp: int, now: float) -> None:
        """Raise ``Replayed`` or ``OutOfWindow`` if (seq, stamp) must not be accepted."""
        if abs(now - stamp) > self.max_age:
            raise OutOfWindow(f"control seq {seq} is stamped {stamp - now:+.0f} s from now")
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
        return {"highest": self.highest, "seen": self.seen}

    @classmethod
    def from_dict(cls, data: dict[str, int], max_age: float = 600.0) -> ReplayWindow:
        return cls(max_age=max_age, highest=int(data["highest"]), seen=int(data["seen"]))


@dataclass
class ControlReceiver:
    """The vehicle's gate for control frames: MAC, then replay window, then decoded packet."""

    key: bytes
    address: int
    window: ReplayWindow = field(default_factory=ReplayWindow)

    def accept(self, frame: bytes, now: float) -> ControlPacket:
        packet = verify(frame, self.key, self.address)
        self.window.accept(packet.seq, packet.time, now)
        return packet
