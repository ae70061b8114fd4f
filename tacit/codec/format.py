"""The payload: what a priority packet's 29 bytes hold, and the errors of a payload that cannot be decoded.

Payload (29 bytes after the priority packet's header, seq and tag), protocol version 3 (``FORMAT``)::

    byte 0     bits 7-6  format version (3); a decoder refuses any other with ``CodecError``
               bits 5-0  base: 0 = starts from the initial state (first packet of a vehicle run);
                         1-63 = continues from the state after the packet whose id this is
                         (a packet's own id is base % 63 + 1)
    byte 1-28  arithmetic code (224 bits), zero-padded: one section per stream (``tacit.codec.grammar``),
               in the order of the stream list both ends configured (``tacit.streams``)

Protocol version 4 (``tacit.codec.versions``: ``Coding.window``) names states by packet seq instead::

    byte 0     bits 7-6  zero (format version 0)
               bits 5-0  back: 0 = starts from the initial state; 1-63 = continues from the state the
                         packet ``back`` seqs before this one left (seqs are the priority packet's, u8)
    byte 1-28  as in version 3

A state is the packet's that left it, so two branches never share a name: a packet coded again after a
loss has a seq of its own, and the shore never decodes a packet on a state another branch left. The
vehicle may then keep up to ``MAX_WINDOW`` packets in flight, each continuing from the one before it;
the shore decodes one whose base has not come yet when that base comes (``UnknownBase`` until then). A
base further back than 63 seqs (an hour of check-points and nothing else) cannot be named: the vehicle
starts that packet from the initial state.

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
from tacit.packets import COVER_BITS, PAYLOAD_SIZE

FORMAT = 3
FORMAT_SEQS = 0  # version 4's format: states named by packet seq
HEADER_BYTES = 1
CODE_BYTES = PAYLOAD_SIZE - HEADER_BYTES
CODE_BITS = CODE_BYTES * 8
CHAIN_IDS = 63
SEQS = 256  # version 4 names a state 1 + the seq of the packet that left it: 1..256
MAX_BACK = 63  # the furthest back (in seqs) a version 4 payload can name its base
# packets in flight at most, and how far (in seqs) the vehicle numbers a packet past the oldest whose fate
# it has not heard: a check-point numbered after them still reaches them all (COVER_BITS back)
MAX_WINDOW = COVER_BITS - 2


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


def seq_id(seq: int) -> int:
    """Version 4: the name of the state the packet with ``seq`` leaves."""
    return seq % SEQS + 1


def chain_ids(payload: bytes, seq: int = 0) -> tuple[int, int]:
    """(the base state a payload continues from, 0 = the initial state; the state it leaves), for the
    packet with ``seq``: what a receiver needs to know which earlier packet a packet's decoding depends
    on. Version 3 names states by chain id, version 4 by packet seq (``seq_id``)."""
    byte = payload[0] if payload else FORMAT << 6
    if byte >> 6 == FORMAT:
        return byte & 0x3F, next_id(byte & 0x3F)
    back = byte & 0x3F
    return (seq_id(seq - back) if back else 0), seq_id(seq)


def base_field(seqs: bool, base: int, seq: int) -> int | None:
    """What byte 0 says of ``base`` (a state's name) for the packet with ``seq``: version 3 its chain id;
    version 4 (``seqs``) how far back its packet is, or None when that is further than ``MAX_BACK``."""
    if not seqs or not base:
        return base
    back = (seq - (base - 1)) % SEQS
    return back if 0 < back <= MAX_BACK else None


def pack(base: int, bits: list[int], seqs: bool = False) -> bytes:
    """The payload of a packet whose byte 0 says ``base`` (``base_field``) and whose arithmetic code is
    ``bits``, in version 3's format or version 4's (``seqs``)."""
    return bytes([((FORMAT_SEQS if seqs else FORMAT) << 6) | base]) + pack_bits(bits, CODE_BYTES)


def unpack(payload: bytes, seqs: bool = False) -> tuple[int, bytes]:
    """(byte 0's base field, the code bytes); ``CodecError`` for another size or format (version 4's
    when ``seqs``)."""
    if len(payload) != PAYLOAD_SIZE:
        raise CodecError(f"payload is {len(payload)} bytes, not {PAYLOAD_SIZE}")
    version, base = payload[0] >> 6, payload[0] & 0x3F
    wanted = FORMAT_SEQS if seqs else FORMAT
    if version != wanted:
        raise CodecError(f"sample format version {version}; this shore decodes version {wanted} for it")
    return base, payload[HEADER_BYTES:]
