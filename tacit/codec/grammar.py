"""The token grammar: what a stream's section of the arithmetic code says, each token's writing and
reading side by side.

Per stream the packet holds a *section*, a sequence of tokens, each followed by what it announces:

=====  ========================================================================  ==================
token  meaning (the cursor is the tick of the stream's last coded sample)          followed by
=====  ========================================================================  ==================
END    the stream's section ends                                                 -
STEP   the next sample is at cursor + 1                                          a sample
SAME   the next sample is at the cursor's tick (several samples in one tick)     a sample
JUMP   the next sample is at cursor + 2 + n (n + 1 ticks without a sample)       n, a sample
LOST   ticks cursor + 1 .. cursor + 1 + n were in a packet that was lost         n
PHASE  the grid's phase becomes f; the cursor becomes the new grid's tick          4 bits (f)
       nearest to its time (``tacit.codec.grid.regrid``)
START  the stream's first sample (no cursor yet): the grid phase, the tick's     4 + 24 bits, a sample
       low 24 bits
=====  ========================================================================  ==================

Version 4 (``Coder.timing``) codes JUMP's n as the stream's last JUMP count, the one before, or a new
one (an Elias-gamma count follows), and chooses the token model after a sample by its run too.

A sample is then: one "all channels present" symbol; if not all, a presence symbol per channel; then q
for each present channel: symbols -6..6, two escapes (an escaped magnitude as an Exp-Golomb code) and
RAW (64 bits follow: the value itself, an IEEE double, exact). A residual of 2^40 steps or more (or a
value beyond what a step count can reach) is sent RAW. n is an Elias-gamma code whose unary part has an
adaptive model per position. Which adaptive model codes each symbol: ``tacit.codec.models``.

START's 24 bits are placed by the reception time: the packet must arrive within 2^24 ticks of the
stream's first sample (at 256 Hz, 18 hours).
"""

from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np

from tacit.arithmetic import Decoder, Encoder
from tacit.codec.format import CodecError
from tacit.codec.grid import PHASE_BITS, regrid
from tacit.codec.models import NAMED, Coder
from tacit.codec.tokens import JUMP, LOST, PHASE, SAME, START, STEP

TICK_BITS = 24
SMALL = 6
ESC_NEG, ESC_POS, RAW = 2 * SMALL + 1, 2 * SMALL + 2, 2 * SMALL + 3
RAW_Q = 1 << 40  # a residual of this many steps or more is sent as the value itself (RAW)


class RawValue(int):
    """A channel's value sent as itself (IEEE double), for a residual too large for a step count; as an
    int it is huge, so it counts as a surprise everywhere a q does."""

    value: float

    def __new__(cls, value: float) -> RawValue:
        raw = super().__new__(cls, RAW_Q if value >= 0 else -RAW_Q)
        raw.value = float(value)
        return raw


class Token(NamedTuple):
    """A token with what follows it (before a sample, if it announces one)."""

    kind: int  # END .. PHASE
    n: int = 0  # JUMP, LOST: the count
    phase: int = 0  # PHASE, START: the grid phase f
    low: int = 0  # START: the tick's low ``TICK_BITS`` bits


def write_token(coder: Coder, enc: Encoder, token: Token) -> None:
    enc.encode_symbol(coder.token_model(), token.kind)
    coder.previous_token = token.kind
    timing = coder.timing
    if timing is not None and token.kind == JUMP:
        kind = timing.jumped_by(token.n)
        enc.encode_symbol(timing.count_model(), kind)
        if kind == NAMED:
            write_count(coder, enc, token.n)
        timing.jump(kind, token.n)
    elif token.kind in (JUMP, LOST):
        write_count(coder, enc, token.n)
    elif token.kind in (PHASE, START):
        write_bits(enc, token.phase, PHASE_BITS)
    if token.kind == START:
        write_bits(enc, token.low, TICK_BITS)
    if timing is not None and token.kind in (SAME, STEP, JUMP):
        timing.placed(token.n + 2 if token.kind == JUMP else int(token.kind == STEP))


def read_token(coder: Coder, dec: Decoder) -> Token:
    token = _read_token(coder, dec)
    if coder.timing is not None and token.kind in (SAME, STEP, JUMP):
        coder.timing.placed(token.n + 2 if token.kind == JUMP else int(token.kind == STEP))
    return token


def _read_token(coder: Coder, dec: Decoder) -> Token:
    kind = dec.decode_symbol(coder.token_model())
    coder.previous_token = kind
    timing = coder.timing
    if timing is not None and kind == JUMP:
        named = dec.decode_symbol(timing.count_model())
        n = read_count(coder, dec) if named == NAMED else timing.jumps[named]
        timing.jump(named, n)
        return Token(kind, n=n)
    if kind in (JUMP, LOST):
        return Token(kind, n=read_count(coder, dec))
    if kind == PHASE:
        return Token(kind, phase=read_bits(dec, PHASE_BITS))
    if kind == START:
        phase = read_bits(dec, PHASE_BITS)
        return Token(kind, phase=phase, low=read_bits(dec, TICK_BITS))
    return Token(kind)


def placing(cursor: int | None, phase: int, index: int, new_phase: int) -> list[Token]:
    """The tokens that place a sample of tick ``index`` on the grid ``new_phase`` after ``cursor`` (a tick
    on the grid ``phase``; None: the stream has not started)."""
    if cursor is None:
        return [Token(START, phase=new_phase, low=index & ((1 << TICK_BITS) - 1))]
    tokens = []
    if new_phase != phase:
        tokens.append(Token(PHASE, phase=new_phase))
        cursor = regrid(cursor, phase, new_phase)
    if index == cursor:
        tokens.append(Token(SAME))
    elif index == cursor + 1:
        tokens.append(Token(STEP))
    else:
        tokens.append(Token(JUMP, n=index - cursor - 2))
    return tokens


def placed(cursor: int, token: Token) -> int:
    """The tick of the sample a SAME, STEP or JUMP token places after ``cursor`` (``placing``'s inverse)."""
    if token.kind == SAME:
        return cursor
    return cursor + 1 if token.kind == STEP else cursor + 2 + token.n


def started(low: int, now: int) -> int:
    """The tick of a stream's first sample, from START's low bits and the tick after the reception's."""
    return now - ((now - low) % (1 << TICK_BITS))


def presence_before(coder: Coder) -> list[bool]:
    """Which channels the last sample coded with ``coder`` had (all, when it had every one)."""
    return [True] * len(coder.q) if coder.previous_all else [bool(p) for p in coder.previous_present]


def continues(before: list[bool], present: list[bool], same_tick: bool) -> bool:
    """A sample is a part of the one before it (a sample too large for a packet, sent as parts with
    some of its channels each): same tick and grid, none of the channels the one before had."""
    return same_tick and not any(b and p for b, p in zip(before, present, strict=True))


def write_sample(coder: Coder, enc: Encoder, q: list[int | None]) -> None:
    present = [v is not None for v in q]
    everything = all(present)
    enc.encode_symbol(coder.all_model(), int(everything))
    coder.previous_all = int(everything)
    if not everything:
        for c, here in enumerate(present):
            enc.encode_symbol(coder.present_model(c), int(here))
            coder.previous_present[c] = int(here)
    for c, value in enumerate(q):
        if value is None:
            continue
        model = coder.q_model(c)
        if isinstance(value, RawValue):
            enc.encode_symbol(model, RAW)
            write_bits(enc, int.from_bytes(struct.pack(">d", value.value), "big"), 64)
        elif -SMALL <= value <= SMALL:
            enc.encode_symbol(model, value + SMALL)
        else:
            enc.encode_symbol(model, ESC_POS if value > 0 else ESC_NEG)
            _write_exp_golomb(enc, abs(value) - SMALL - 1)
        coder.previous_q[c] = value


def read_sample(coder: Coder, dec: Decoder) -> list[int | None]:
    channels = len(coder.q)
    everything = dec.decode_symbol(coder.all_model())
    coder.previous_all = everything
    present = [True] * channels
    if not everything:
        for c in range(channels):
            here = dec.decode_symbol(coder.present_model(c))
            coder.previous_present[c] = here
            present[c] = bool(here)
    out: list[int | None] = [None] * channels
    for c in range(channels):
        if not present[c]:
            continue
        symbol = dec.decode_symbol(coder.q_model(c))
        if symbol < ESC_NEG:
            value = symbol - SMALL
        elif symbol == RAW:
            raw = struct.unpack(">d", read_bits(dec, 64).to_bytes(8, "big"))[0]
            if not np.isfinite(raw):
                raise CodecError("a raw value that is not a finite number")
            value = RawValue(raw)
        else:
            magnitude = _read_exp_golomb(dec) + SMALL + 1
            value = magnitude if symbol == ESC_POS else -magnitude
        out[c] = value
        coder.previous_q[c] = value
    return out


def write_count(coder: Coder, enc: Encoder, n: int) -> None:
    """n >= 0 as Elias-gamma of n + 1, the unary part adaptive."""
    m = n + 1
    width = m.bit_length()
    for i in range(width - 1):
        enc.encode_symbol(coder.count_model(i), 0)
    enc.encode_symbol(coder.count_model(width - 1), 1)
    write_bits(enc, m, width - 1)  # below the leading 1


def read_count(coder: Coder, dec: Decoder) -> int:
    width = 1
    while dec.decode_symbol(coder.count_model(width - 1)) == 0:
        width += 1
        if width > 48:
            raise CodecError("count too long")
    return ((1 << (width - 1)) | read_bits(dec, width - 1)) - 1


def write_bits(enc: Encoder, value: int, bits: int) -> None:
    for i in range(bits - 1, -1, -1):
        enc.encode_bit((value >> i) & 1)


def read_bits(dec: Decoder, bits: int) -> int:
    value = 0
    for _ in range(bits):
        value = (value << 1) | dec.decode_bit()
    return value


def _write_exp_golomb(enc: Encoder, n: int) -> None:
    m = n + 1
    width = m.bit_length()
    for _ in range(width - 1):
        enc.encode_bit(0)
    write_bits(enc, m, width)


def _read_exp_golomb(dec: Decoder) -> int:
    zeros = 0
    while dec.decode_bit() == 0:
        zeros += 1
        if zeros > 64:
            raise CodecError("escaped magnitude too long")
    return ((1 << zeros) | read_bits(dec, zeros)) - 1
