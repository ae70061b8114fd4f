"""The payload: what a priority packet's 29 bytes hold, and the errors of a payload that cannot be decoded.

Payload (29 bytes after the priority packet's header, seq and tag; version ``FORMAT``)::

    byte 0     bits 7-6  format version (3); a decoder refuses any other with ``CodecError``
               bits 5-0  base: 0 = starts from the initial state (first packet of a vehicle run);
                         1-63 = continues from the state after the packet whose id this is
                         (a packet's own id is base % 63 + 1)
    byte 1-28  arithmetic code (224 bits), zero-padded: one section per stream (``tacit.codec.grammar``),
               in the order of the stream list both ends configured (``tacit.streams``)

There is no tick count and no first-tick field: the shore knows where each stream stood after the base
packet, END closes a section, and a packet holds as many ticks as its code bytes carry (a quiet stream:
thousands). Several streams share a packet, so a quiet one rides along instead of paying 32 bytes.

Packets chain: each continues from a predictor and model state both ends hold (``tacit.codec.state``).
The vehicle learns from the modem's ACK which packets arrived and bases the next on the last delivered
one, so one lost packet costs its own samples (declared with LOST, stored as uncertain on the shore),
never the ones after. Decoding raises nothing but ``CodecError``; a packet whose base the shore does not
hold raises its subclass ``UnknownBase``, and the vehicle's ``PacketEncoder.restart()`` makes its next
packet start from the initial state (base 0; the shore then forgets every older state).
"""

from __future__ import annotations

from tacit.arithmetic import pack_bits
from tacit.packets import PAYLOAD_SIZE

FORMAT = 3
HEADER_BYTES = 1
CODE_BYTES = PAYLOAD_SIZE - HEADER_BYTES
CODE_BITS = CODE_BYTES * 8
CHAIN_IDS = 63


class CodecError(ValueError):
    """A payload that cannot be decoded (another format, an unknown base state, or malformed)."""


class UnknownBase(CodecError):
    """The packet continues from a state this decoder does not hold (an earlier packet was not received,
    or the shore restarted without its saved state): ask the vehicle to start over (``restart``)."""

    def __init__(self, base: int) -> None:
        super().__init__(f"no state for packet id {base}: an earlier packet was not received")
        self.base = base


def next_id(base: int) -> int:
    """The id of the state a packet based on ``base`` leaves."""
    return base % CHAIN_IDS + 1


def chain_ids(payload: bytes) -> tuple[int, int]:
    """(the base packet id a payload continues from, 0 = the initial state; the id of the state it
    leaves): what a receiver needs to know which earlier packet a packet's decoding depends on."""
    base = payload[0] & 0x3F if payload else 0
    return base, next_id(base)


def pack(base: int, bits: list[int]) -> bytes:
    """The payload of a packet based on ``base`` whose arithmetic code is ``bits``."""
    return bytes([(FORMAT << 6) | base]) + pack_bits(bits, CODE_BYTES)


def unpack(payload: bytes) -> tuple[int, bytes]:
    """(the base a payload continues from, its code bytes); ``CodecError`` for another size or format."""
    if len(payload) != PAYLOAD_SIZE:
        raise CodecError(f"payload is {len(payload)} bytes, not {PAYLOAD_SIZE}")
    version, base = payload[0] >> 6, payload[0] & 0x3F
    if version != FORMAT:
        raise CodecError(f"sample format version {version}; this shore decodes version {FORMAT}")
    return base, payload[HEADER_BYTES:]
