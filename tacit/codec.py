"""The sample codec: what goes in a priority packet's 30 bytes, and how the shore gets it back.

Quantisation. For channel c with error bound eps_c, the vehicle sends q = round((x - p) / s) with
p the dual prediction and s = 2 eps_c (1 - 1e-9); the shore reconstructs p + q s, so
|reconstruction - x| <= eps_c for every present sample (the 1e-9 margin absorbs floating-point
rounding). q = 0 is the paper's "predictable" verdict. Both ends feed the reconstruction, not the raw
value, back into the predictor. p is the channel's predictor (``tacit.predict``) plus a cross-channel
term (``_Dual``): channels are coded in order, and channel c's residual is predicted by a ridge
regression on the residuals of the channels already coded in the same sample and on the previous
sample's residuals, fitted on reconstructions (so both ends hold the same coefficients), used by a
channel only while it has lately cut its squared error by 10 %. A residual of 2^40 steps or more (or a
value beyond what a step count can reach) is sent as the value itself (RAW: an IEEE double, exact);
a single raw value (a glitch) is not given to the predictor, a second one in a row is (a real jump).

Time. Each stream has a tick period T and a grid phase f (in sixteenths of a tick); a sample taken at
time t belongs to tick k = round(t / T - f / 16), and the shore dates it (k + f / 16) T: **every
sample's time is known to within T / 2** (``time_precision``), whatever its jitter, and jitter costs
no bits. The phase keeps the grid's ticks where the sensor samples: on a grid half a tick off, each
jittered sample would land in the tick before or after its own (two samples in one tick, then a tick
without one: bits for nothing). START sends the first sample's phase; the vehicle follows the
sensor's phase (a circular mean over about 8 samples) and, when a grid there would misplace fewer
samples (a jittered first sample, a clock that drifts against T), moves the grid with PHASE (``_Grid``). Nothing is dropped: a tick may hold no sample (a dropped
message, a blank row, a slower sensor), one, or several (a burst, duplicate times: each is coded, in
order, with the same tick). A channel may be absent from a sample (NaN, a blank cell): the shore stores
it as absent (NaN / None), never as a made-up value, and the predictors skip it.

Entropy coding (``tacit.arithmetic``, adaptive models, so what is regular becomes almost free).
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
       nearest to its time (``_regrid``)
START  the stream's first sample (no cursor yet): the grid phase, the tick's     4 + 24 bits, a sample
       low 24 bits
=====  ========================================================================  ==================

The token is coded with a model per stream and previous token. A sample is then: one "all channels
present" symbol (model per stream and previous answer); if not all, a presence symbol per channel
(model per channel and previous presence); then q for each present channel (model per channel and
context min(|previous q|, 2)): symbols -6..6, two escapes (an escaped magnitude as an Exp-Golomb
code) and RAW (64 bits follow). n is an Elias-gamma code whose unary part has an adaptive model per position. On a clean grid a
tick costs hundredths of a bit beyond its q's; a 5 % dropout costs about 0.3 bit per missing tick.

Payload (30 bytes after the priority packet's 2-byte header; version ``FORMAT``)::

    byte 0     bits 7-6  format version (3); a decoder refuses any other with ``CodecError``
               bits 5-0  base: 0 = starts from the initial state (first packet of a vehicle run);
                         1-63 = continues from the state after the packet whose id this is
                         (a packet's own id is base % 63 + 1)
    byte 1-29  arithmetic code (232 bits), zero-padded: one section per stream, in the order of
               the stream list both ends configured (``tacit.streams``)

START's 24 bits are placed by the reception time: the packet must arrive within 2^24 ticks of the
stream's first sample (at 256 Hz, 18 hours). There is no tick count and no first-tick field: the shore knows where each stream stood after the base
packet, END closes a section, and a packet holds as many ticks as its code bytes carry (a quiet stream:
thousands). Several streams share a packet, so a quiet one rides along instead of paying 32 bytes.

Packets chain: each continues from a predictor and model state both ends hold. The vehicle learns from
the modem's ACK which packets arrived and bases the next on the last delivered one, so one lost packet
costs its own samples (declared with LOST, stored as uncertain on the shore), never the ones after.
Decoding raises nothing but ``CodecError``; a packet whose base the shore does not hold raises its
subclass ``UnknownBase``, and the vehicle's ``PacketEncoder.restart()`` makes its next packet start from
the initial state (base 0; the shore then forgets every older state). The shore persists its states
with ``PacketDecoder.to_bytes()`` / ``load()`` / ``from_bytes()``.

A sample too large for an empty packet (many channels far off, raw values) is sent as several samples
of the same tick, each with some of its channels (the others absent): the stream never stalls, and the
shore gets every channel, in parts (a part in a lost packet is declared lost like any sample).
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tacit.arithmetic import AdaptiveModel, Decoder, Encoder, pack_bits
from tacit.packets import PAYLOAD_SIZE, Priority, PriorityPacket, Stream
from tacit.predict import Predictor, make_predictor

FORMAT = 3
HEADER_BYTES = 1
CODE_BYTES = PAYLOAD_SIZE - HEADER_BYTES
CODE_BITS = CODE_BYTES * 8
CHAIN_IDS = 63
SMALL = 6
ESC_NEG, ESC_POS, RAW = 2 * SMALL + 1, 2 * SMALL + 2, 2 * SMALL + 3
PRIOR = [1, 1, 1, 2, 4, 8, 24, 8, 4, 2, 1, 1, 1, 1, 1, 1]
MARGIN = 1 - 1e-9
END, STEP, SAME, JUMP, LOST, START, PHASE = range(7)
TOKEN_PRIOR = [2, 24, 1, 2, 1, 1, 1]
TICK_BITS = 24
PHASE_BITS = 4  # the grid phase in sixteenths of a tick
PHASES = 1 << PHASE_BITS
PHASE_FOLLOW = 1 / 8  # the vehicle follows a sensor's phase and misplacement rates over about 8 samples
PHASE_GAIN = 0.15  # the grid moves to the followed phase when that would misplace 15 % fewer samples ...
PHASE_SURE = 0.4  # ... and the samples agree on it (mean resultant length: 1 for a steady clock, 0.5 for
# +-30 % uniform jitter, ~0.25 for random phases)
RAW_Q = 1 << 40  # a residual of this many steps or more is sent as the value itself (RAW)
FEED_LIMIT = 1e100  # the predictors see values clipped to +-this (both ends), so they stay finite


class CodecError(ValueError):
    """A payload that cannot be decoded (another format, an unknown base state, or malformed)."""


class UnknownBase(CodecError):
    """The packet continues from a state this decoder does not hold (an earlier packet was not received,
    or the shore restarted without its saved state): ask the vehicle to start over (``restart``)."""

    def __init__(self, base: int) -> None:
        super().__init__(f"no state for packet id {base}: an earlier packet was not received")
        self.base = base


class _Raw(int):
    """A channel's value sent as itself (IEEE double), for a residual too large for a step count; as an
    int it is huge, so it counts as a surprise everywhere a q does."""

    value: float

    def __new__(cls, value: float) -> _Raw:
        raw = super().__new__(cls, RAW_Q if value >= 0 else -RAW_Q)
        raw.value = float(value)
        return raw


def _feed(values: np.ndarray) -> np.ndarray:
    """What the predictors are given (both ends): the reconstruction, clipped so they stay finite."""
    return np.clip(values, -FEED_LIMIT, FEED_LIMIT)


CROSS_FORGET = 1 - 1 / 256  # the regression's memory: about 256 samples
CROSS_REFIT = 4  # samples between refits of the coefficients
CROSS_CLIP = 3.0  # residuals (in steps) enter the regression clipped to +-this (a jump must not dominate)
CROSS_RIDGE = 0.05  # ridge, as a fraction of the mean residual power
CROSS_USE = 0.9  # a channel uses the correction while it has cut its squared error by 10 % lately
CROSS_MIN_R2 = 0.1  # a channel whose fit explains less of its residual power is predicted without it


class _Dual:
    """A stream's predictor as both ends run it: the per-channel predictor (``tacit.predict``), and on top
    a cross-channel prediction of the residual. Channels are coded in order; channel c's prediction is
    the predictor's plus sum_j<c beta_cj z_j step_c, z_j = (reconstruction_j - prediction_j) / step_j of
    the channels already coded in the same sample (0 if absent). beta is a ridge regression of each z_c
    on the earlier z, over exponentially forgotten sums, refitted every ``CROSS_REFIT`` samples: from
    reconstructions only, so both ends hold the same coefficients. A value sent raw (a glitch) is not
    given to the predictor unless the channel's previous value was raw too (a real jump is learnt)."""

    def __init__(self, spec: StreamSpec) -> None:
        n = len(spec.channels)
        self.base, self.step, self.cross = spec.predictor(), spec.step, spec.cross and n > 1
        self.sums, self.beta, self.count = np.zeros((2 * n, 2 * n)), np.zeros((n, 2 * n)), 0
        self.raw_before = np.zeros(n, dtype=bool)
        self.previous = np.zeros(n)  # the previous sample's z (across a gap too)
        self.errors = np.zeros((2, n))  # per channel, forgotten squared error: without, with the correction

    def predict(self) -> np.ndarray:
        return self.base.predict()

    def current(self) -> np.ndarray:
        return self.base.current()

    def skip(self, ticks: int = 1) -> None:
        self.base.skip(ticks)  # the previous sample's residuals still predict (zeroing them cost 6 % on gaps)

    def correction(self, c: int, z: np.ndarray) -> float:
        """Channel c's predicted residual, in steps, from the earlier channels' ``z``."""
        if not self.cross:
            return 0.0
        if not self.errors[1, c] < CROSS_USE * self.errors[0, c]:
            return 0.0
        n = len(z)
        return float(self.beta[c, :c] @ z[:c] + self.beta[c, n:] @ self.previous)

    def update(self, values: np.ndarray, z: np.ndarray, raw: np.ndarray) -> None:
        """The sample's reconstruction (NaN: absent), residuals in steps (0: absent or raw), raw channels."""
        present = ~np.isnan(values)
        fed = np.where(raw & ~self.raw_before, np.nan, values)
        self.raw_before = np.where(present, raw, self.raw_before)
        self.base.update(_feed(fed))
        if not self.cross:
            return
        zz = np.concatenate([np.clip(z, -CROSS_CLIP, CROSS_CLIP), self.previous])
        candidate = (
            np.tril(self.beta[:, : len(z)], -1) @ zz[: len(z)] + self.beta[:, len(z) :] @ self.previous
        )
        self.errors = self.errors * CROSS_FORGET + np.where(present, np.array([z, z - candidate]) ** 2, 0.0)
        self.previous = zz[: len(z)]
        self.sums = self.sums * CROSS_FORGET + np.outer(zz, zz)
        self.count += 1
        if self.count % CROSS_REFIT == 0:
            self._refit()

    def _refit(self) -> None:
        n = len(self.step)
        ridge = CROSS_RIDGE * float(np.trace(self.sums)) / (2 * n) + 1e-9
        for c in range(n):
            used = np.r_[0:c, n : 2 * n]
            a = self.sums[np.ix_(used, used)] + ridge * np.eye(len(used))
            b = self.sums[used, c]
            beta = np.linalg.solve(a, b)
            explained = float(beta @ b) / (self.sums[c, c] + 1e-12)  # R^2 of the fit
            self.beta[c, used] = beta if explained >= CROSS_MIN_R2 else 0.0
        self.beta[:, :n] = np.tril(self.beta[:, :n], -1)

    def state(self) -> Any:
        return (self.base.state(), self.sums.copy(), self.beta.copy(), self.count, self.raw_before.copy(),
                self.previous.copy(), self.errors.copy())  # fmt: skip

    def restore(self, state: Any) -> None:
        base, sums, beta, count, raw_before, previous, errors = state
        self.previous, self.errors = np.array(previous, dtype=np.float64), np.array(errors, dtype=np.float64)
        self.base.restore(base)
        self.sums, self.beta = np.array(sums, dtype=np.float64), np.array(beta, dtype=np.float64)
        self.count = int(count)
        self.raw_before = np.array(raw_before, dtype=bool)


@dataclass(frozen=True)
class StreamSpec:
    """What both ends agree on for one stream of samples."""

    name: str
    stream: Stream
    channels: tuple[str, ...]
    eps: tuple[float, ...]
    period: float
    method: str = "kalman"
    initial: tuple[float, ...] | None = None
    cross: bool = True  # predict each channel's residual from the channels coded before it (``_Dual``)

    def __post_init__(self) -> None:
        if len(self.eps) != len(self.channels):
            raise ValueError("one eps per channel")
        if any(not e > 0 for e in self.eps):
            raise ValueError("every eps must be positive")
        if not self.period > 0:
            raise ValueError("period must be positive")

    @property
    def step(self) -> np.ndarray:
        return 2 * np.asarray(self.eps, dtype=np.float64) * MARGIN

    @property
    def time_precision(self) -> float:
        """The shore dates every sample to within this many seconds (half a tick)."""
        return self.period / 2

    def predictor(self) -> Predictor:
        return make_predictor(
            self.method, len(self.channels), None if self.initial is None else np.array(self.initial)
        )

    def tick(self, time: float, phase: int = 0) -> int:
        """The tick a sample taken at ``time`` belongs to, on the grid of ``phase`` (sixteenths)."""
        return round(time / self.period - phase / PHASES)

    def phase_of(self, time: float) -> complex:
        """Where ``time`` falls within a tick, as a unit phasor (so phases average across the wrap)."""
        return complex(np.exp(2j * np.pi * (time / self.period % 1.0)))


def _nearest_phase(phasor: complex) -> int:
    """The grid phase (sixteenths of a tick) nearest a phasor's angle."""
    return round(float(np.angle(phasor)) / (2 * np.pi) % 1.0 * PHASES) % PHASES


def _regrid(cursor: int, phase: int, new: int) -> int:
    """The tick of the grid of phase ``new`` nearest the time of tick ``cursor`` of the grid ``phase``."""
    return cursor + (phase - new + PHASES // 2) // PHASES


# --- the models both ends keep per stream -------------------------------------------------------------


def _binary() -> AdaptiveModel:
    return AdaptiveModel([1, 8])  # symbol 1 (the usual answer) starts likely


@dataclass
class _Coder:
    """A stream's adaptive models and the contexts they are chosen by."""

    q: list[list[AdaptiveModel]]  # per channel, per min(|previous q|, 2)
    tokens: list[AdaptiveModel]  # per previous token
    all_present: list[AdaptiveModel]  # per previous answer
    present: list[list[AdaptiveModel]]  # per channel, per previous presence
    counts: list[AdaptiveModel]  # the unary part of Elias-gamma counts, per position
    previous_q: list[int]
    previous_present: list[int]
    previous_all: int = 1
    previous_token: int = END

    @classmethod
    def new(cls, channels: int) -> _Coder:
        return cls([[AdaptiveModel(list(PRIOR), Q_INCREMENT) for _ in range(Q_CONTEXTS)] for _ in range(channels)],
                   [AdaptiveModel(list(TOKEN_PRIOR)) for _ in TOKEN_PRIOR], [_binary() for _ in range(2)],
                   [[_binary() for _ in range(2)] for _ in range(channels)],
                   [AdaptiveModel([1, 1]) for _ in range(24)], [0] * channels, [1] * channels)  # fmt: skip

    def dump(self) -> list:
        models = [[[m.freqs, m.increment, m.limit] for m in row] for row in (*self.q, self.tokens,
                  self.all_present, *self.present, self.counts)]  # fmt: skip
        return [models, self.previous_q, self.previous_present, self.previous_all, self.previous_token]

    @classmethod
    def load(cls, data: list) -> _Coder:
        models, previous_q, previous_present, previous_all, previous_token = data
        rows = [[AdaptiveModel(list(map(int, f)), int(i), int(lim)) for f, i, lim in row] for row in models]
        channels = len(previous_q)
        q, rest = rows[:channels], rows[channels:]
        tokens, all_present, present, counts = rest[0], rest[1], rest[2 : 2 + channels], rest[2 + channels]
        if len(rows) != 2 * channels + 3 or len(previous_present) != channels:
            raise ValueError("coder shape")
        return cls(q, tokens, all_present, present, counts, [int(v) for v in previous_q],
                   [int(v) for v in previous_present], int(previous_all), int(previous_token))  # fmt: skip

    def copy(self) -> _Coder:
        return _Coder([[m.copy() for m in row] for row in self.q], [m.copy() for m in self.tokens],
                      [m.copy() for m in self.all_present], [[m.copy() for m in row] for row in self.present],
                      [m.copy() for m in self.counts], list(self.previous_q), list(self.previous_present),
                      self.previous_all, self.previous_token)  # fmt: skip

    # tokens and counts

    def encode_token(self, enc: Encoder, token: int) -> None:
        enc.encode_symbol(self.tokens[self.previous_token], token)
        self.previous_token = token

    def decode_token(self, dec: Decoder) -> int:
        token = dec.decode_symbol(self.tokens[self.previous_token])
        self.previous_token = token
        return token

    def encode_count(self, enc: Encoder, n: int) -> None:
        """n >= 0 as Elias-gamma of n + 1, the unary part adaptive."""
        m = n + 1
        width = m.bit_length()
        for i in range(width - 1):
            enc.encode_symbol(self.counts[min(i, len(self.counts) - 1)], 0)
        enc.encode_symbol(self.counts[min(width - 1, len(self.counts) - 1)], 1)
        _encode_bits(enc, m, width - 1)  # below the leading 1

    def decode_count(self, dec: Decoder) -> int:
        width = 1
        while dec.decode_symbol(self.counts[min(width - 1, len(self.counts) - 1)]) == 0:
            width += 1
            if width > 48:
                raise CodecError("count too long")
        return ((1 << (width - 1)) | _decode_bits(dec, width - 1)) - 1

    # samples

    def encode_sample(self, enc: Encoder, q: list[int | None]) -> None:
        present = [v is not None for v in q]
        everything = all(present)
        enc.encode_symbol(self.all_present[self.previous_all], int(everything))
        self.previous_all = int(everything)
        if not everything:
            for c, here in enumerate(present):
                enc.encode_symbol(self.present[c][self.previous_present[c]], int(here))
                self.previous_present[c] = int(here)
        for c, value in enumerate(q):
            if value is None:
                continue
            model = self.q[c][_q_context(self.previous_q[c])]
            if isinstance(value, _Raw):
                enc.encode_symbol(model, RAW)
                _encode_bits(enc, int.from_bytes(struct.pack(">d", value.value), "big"), 64)
            elif -SMALL <= value <= SMALL:
                enc.encode_symbol(model, value + SMALL)
            else:
                enc.encode_symbol(model, ESC_POS if value > 0 else ESC_NEG)
                _encode_exp_golomb(enc, abs(value) - SMALL - 1)
            self.previous_q[c] = value

    def decode_sample(self, dec: Decoder) -> list[int | None]:
        channels = len(self.q)
        everything = dec.decode_symbol(self.all_present[self.previous_all])
        self.previous_all = everything
        present = [True] * channels
        if not everything:
            for c in range(channels):
                here = dec.decode_symbol(self.present[c][self.previous_present[c]])
                self.previous_present[c] = here
                present[c] = bool(here)
        out: list[int | None] = [None] * channels
        for c in range(channels):
            if not present[c]:
                continue
            symbol = dec.decode_symbol(self.q[c][_q_context(self.previous_q[c])])
            if symbol < ESC_NEG:
                value = symbol - SMALL
            elif symbol == RAW:
                raw = struct.unpack(">d", _decode_bits(dec, 64).to_bytes(8, "big"))[0]
                if not np.isfinite(raw):
                    raise CodecError("a raw value that is not a finite number")
                value = _Raw(raw)
            else:
                magnitude = _decode_exp_golomb(dec) + SMALL + 1
                value = magnitude if symbol == ESC_POS else -magnitude
            out[c] = value
            self.previous_q[c] = value
        return out


Q_CONTEXTS = 3
Q_INCREMENT = 24


def _q_context(previous: int) -> int:
    """The q model's context: min(|the channel's previous q|, 2). (Adding whether an earlier channel of
    the same sample was a surprise was tried: on the ArduSub IMU its learning cost outweighs it.)"""
    return min(abs(previous), 2)


def _encode_bits(enc: Encoder, value: int, bits: int) -> None:
    for i in range(bits - 1, -1, -1):
        enc.encode_bit((value >> i) & 1)


def _decode_bits(dec: Decoder, bits: int) -> int:
    value = 0
    for _ in range(bits):
        value = (value << 1) | dec.decode_bit()
    return value


def _encode_exp_golomb(enc: Encoder, n: int) -> None:
    m = n + 1
    width = m.bit_length()
    for _ in range(width - 1):
        enc.encode_bit(0)
    _encode_bits(enc, m, width)


def _decode_exp_golomb(dec: Decoder) -> int:
    zeros = 0
    while dec.decode_bit() == 0:
        zeros += 1
        if zeros > 64:
            raise CodecError("escaped magnitude too long")
    return ((1 << zeros) | _decode_bits(dec, zeros)) - 1


# --- the chain of states both ends hold -------------------------------------------------------------


@dataclass
class _Position:
    """One stream's state after a packet: predictor snapshot, models, cursor (last coded tick)."""

    predictor: object
    coder: _Coder
    cursor: int | None
    phase: int = 0  # the grid phase START set (sixteenths of a tick)


@dataclass
class _Chain:
    id: int  # 0: the initial state; 1..63 the packet that ended here
    streams: list[_Position]


def _next_id(base: int) -> int:
    return base % CHAIN_IDS + 1


def chain_ids(payload: bytes) -> tuple[int, int]:
    """(the base packet id a payload continues from, 0 = the initial state; the id of the state it
    leaves): what a receiver needs to know which earlier packet a packet's decoding depends on."""
    base = payload[0] & 0x3F if payload else 0
    return base, _next_id(base)


@dataclass
class _Sample:
    time: float
    index: int  # tick
    values: np.ndarray  # NaN = absent
    urgent: bool
    serial: int = 0  # the stream's sample number (0, 1, ...), for the caller's bookkeeping
    flagged: bool = False  # urgent because the caller said so (an event), not only by its size
    phase: int = 0  # the phase of the grid ``index`` is on
    q: list[int | None] = field(default_factory=list)
    state_before: object = None  # the predictor before this sample (for a packet that ends before it)


@dataclass
class _Grid:
    """Where the vehicle puts a stream's ticks. The first sample sets the phase; the vehicle follows the
    sensor's phase (a forgetting circular mean) and how often each grid misplaces a sample (puts two
    consecutive samples a different number of ticks apart than their times are periods apart), and
    moves the grid only when the followed phase misplaces ``PHASE_GAIN`` fewer: a steady clock that
    sits near a tick boundary or drifts is followed; a loose one (intervals from half to one and a half
    periods) misplaces as many samples on any grid, and does not pay for PHASE tokens chasing it."""

    followed: complex  # the sensor's phase, as a phasor (``StreamSpec.phase_of``) averaged
    phase: int  # the grid's, sixteenths of a tick
    last: float  # the previous sample's time
    misplaced: tuple[float, float] = (0.0, 0.0)  # forgetting rates: on this grid, on the followed phase's

    @classmethod
    def start(cls, spec: StreamSpec, time: float) -> _Grid:
        """The grid a stream's first sample, taken at ``time``, sets."""
        here = spec.phase_of(time)
        return cls(here, _nearest_phase(here), time)

    def follow(self, spec: StreamSpec, time: float) -> int | None:
        """Take a sample's time into account; the phase the grid should move to (None: stay)."""
        self.followed += PHASE_FOLLOW * (spec.phase_of(time) - self.followed)
        candidate = _nearest_phase(self.followed)
        apart = round((time - self.last) / spec.period)
        rates = [
            rate + PHASE_FOLLOW * ((spec.tick(time, grid) - spec.tick(self.last, grid) != apart) - rate)
            for rate, grid in zip(self.misplaced, (self.phase, candidate), strict=True)
        ]
        self.misplaced, self.last = (rates[0], rates[1]), time
        better = rates[0] - rates[1] >= PHASE_GAIN and abs(self.followed) >= PHASE_SURE
        return candidate if candidate != self.phase and better else None

    def move(self, phase: int) -> None:
        self.phase, self.misplaced = phase, (self.misplaced[1], self.misplaced[1])


@dataclass
class EncodedPacket:
    """A priority packet and what it covers (for logs, latency and the link's bookkeeping)."""

    packet: PriorityPacket
    first_tick: int  # the first sample's tick in the packet's main stream (header's stream)
    ticks: int  # samples in the packet, all streams
    gap: int  # ticks declared lost (LOST) in this packet
    sample_times: list[float]
    surprise_times: list[float]  # the samples the shore could not predict (some q != 0)
    nonzero: int
    samples_by_stream: dict[str, int] = field(default_factory=dict)
    serials: list[list[int]] = field(default_factory=list)  # per stream: the samples' numbers, in order
    code_bits: int = 0  # of the payload's 232 code bits, how many the arithmetic code used
    surprises: dict[str, list[int]] = field(
        default_factory=dict
    )  # per stream and channel: values not predicted


def _code_sample(
    coder: _Coder, enc: Encoder, cursor: int | None, phase: int, sample: _Sample
) -> tuple[int, int]:
    """The token(s) that place ``sample`` after ``cursor`` (on the grid ``phase``), then the sample;
    returns the new cursor and phase."""
    if cursor is None:
        coder.encode_token(enc, START)
        _encode_bits(enc, sample.phase, PHASE_BITS)
        _encode_bits(enc, sample.index & ((1 << TICK_BITS) - 1), TICK_BITS)
        coder.encode_sample(enc, sample.q)
        return sample.index, sample.phase
    if sample.phase != phase:
        coder.encode_token(enc, PHASE)
        _encode_bits(enc, sample.phase, PHASE_BITS)
        cursor = _regrid(cursor, phase, sample.phase)
    if sample.index == cursor:
        coder.encode_token(enc, SAME)
    elif sample.index == cursor + 1:
        coder.encode_token(enc, STEP)
    else:
        coder.encode_token(enc, JUMP)
        coder.encode_count(enc, sample.index - cursor - 2)
    coder.encode_sample(enc, sample.q)
    return sample.index, sample.phase


@dataclass
class _Section:
    """One stream's part of the packet being filled."""

    base: _Position
    lost: int | None = None  # declare LOST(n) at the section's start (None: nothing was lost)
    count: int = 0  # samples of the stream's pending list in this packet
    closed: bool = False  # a sample did not fit: nothing later of this stream goes in this packet
    open_encoder: Encoder | None = None  # after this section's tokens, before its END
    open_coder: _Coder | None = None
    open_cursor: int | None = None
    open_phase: int = 0


class PacketEncoder:
    """The vehicle's side: samples of every stream in, priority packets out, re-based on the last
    delivered packet. Streams are coded in the order given (both ends use the same list)."""

    def __init__(self, specs: list[StreamSpec], max_latency: float = 10.0, urgent_threshold: float | None = None,
                 max_silence: float = 60.0) -> None:  # fmt: skip
        """An unpredictable sample (some q != 0) leaves within ``max_latency`` seconds; a predictable
        one (the paper's silence) only needs confirming within ``max_silence``, so a quiet stream does
        not pay a packet per latency period. ``urgent_threshold``: a sample with any |q| at or above it
        (a surprise of that many 2-eps steps) is time-sensitive and makes its packet leave at once."""
        if not specs:
            raise ValueError("at least one stream")
        self.specs = list(specs)
        self.max_latency = max_latency
        self.max_silence = max(max_silence, max_latency)
        self.urgent_threshold = urgent_threshold
        self.predictors = [_Dual(s) for s in self.specs]
        self.initial = _Chain(0, [_Position(p.state(), _Coder.new(len(s.channels)), None)
                                  for p, s in zip(self.predictors, self.specs, strict=True)])  # fmt: skip
        self.delivered = self.initial
        self._queues: list[list[_Sample]] = [[] for _ in self.specs]
        self.in_flight: tuple[_Chain, list[bool]] | None = None  # its chain; which streams it carried
        self.seq = 0
        self._cursor: list[int | None] = [None] * len(self.specs)  # of the last processed sample
        self._lost: list[int | None] = [None] * len(self.specs)
        self._serial = [0] * len(self.specs)
        self._phase = [0] * len(self.specs)  # the phase of the last processed sample's grid
        self._grids: list[_Grid | None] = [None] * len(self.specs)  # the grids new samples go on
        self.last_q: list[int | None] = []  # the last pushed sample's quantised residuals (None: absent)
        self.split = 0  # samples too large for an empty packet, sent as parts (channels) in one tick
        self.refused = 0  # samples that fit no packet even alone from the initial state (never seen)
        self._oversize: int | None = None  # a stream whose first pending sample fits no empty packet
        self._restart_on_resolve = False
        self._start(self.initial)

    @property
    def pending(self) -> list[_Sample]:
        """Every sample not yet in a packet (all streams)."""
        return [x for queue in self._queues for x in queue]

    # --- samples in -------------------------------------------------------------------------------

    def push(self, stream: int, time: float, values: np.ndarray | list[float], urgent: bool = False) -> bool:
        """Add one sample of stream number ``stream`` (NaN = a channel without a value). Always coded:
        True unless every channel is absent (then there is nothing to send and nothing is queued)."""
        spec = self.specs[stream]
        row = np.array(values, dtype=np.float64).reshape(-1)
        if row.shape != (len(spec.channels),):
            raise ValueError(f"{spec.name}: {len(spec.channels)} values per sample, got {row.shape[0]}")
        row[~np.isfinite(row)] = np.nan
        if np.isnan(row).all():
            return False
        index = self._tick(stream, time)
        sample = _Sample(
            time,
            index,
            row,
            urgent,
            self._serial[stream],
            flagged=urgent,
            phase=self._grids[stream].phase,  # type: ignore[union-attr]
        )
        self._serial[stream] += 1
        self._process(stream, sample)
        self.last_q = sample.q
        self._settle()
        if self.urgent_threshold is not None and any(
            v is not None and abs(v) >= self.urgent_threshold for v in sample.q
        ):
            sample.urgent = True
        return True

    def _tick(self, stream: int, time: float) -> int:
        """The tick of a sample taken at ``time``, on its stream's grid (``_Grid``)."""
        spec, grid = self.specs[stream], self._grids[stream]
        if grid is None:
            grid = self._grids[stream] = _Grid.start(spec, time)
        elif (phase := grid.follow(spec, time)) is not None:
            cursor = self._cursor[stream]
            # not on a sample the new grid would date at a tick after its own (the cursor re-expressed
            # on the new grid may be up to half a tick later than the latest sample)
            if cursor is None or spec.tick(time, phase) >= _regrid(cursor, self._phase[stream], phase):
                grid.move(phase)
        return spec.tick(time, grid.phase)

    def _process(self, stream: int, sample: _Sample, draft: bool = True) -> None:
        spec, predictor = self.specs[stream], self.predictors[stream]
        cursor = self._cursor[stream]
        if cursor is not None and sample.phase != self._phase[stream]:
            cursor = _regrid(cursor, self._phase[stream], sample.phase)
        if cursor is not None and sample.index < cursor:
            sample.index = cursor  # out of order by less than a tick's rounding: dated with the latest tick
        sample.state_before = predictor.state()
        if cursor is None or sample.index > cursor:
            if cursor is not None:
                predictor.skip(sample.index - cursor - 1)
            prediction = predictor.predict()
        else:
            prediction = predictor.current()
        absent = np.isnan(sample.values)
        with np.errstate(over="ignore", invalid="ignore"):
            residual = (sample.values - prediction) / spec.step
        n = len(spec.channels)
        reconstruction, z, raw = np.full(n, np.nan), np.zeros(n), np.zeros(n, dtype=bool)
        sample.q = []
        for c in range(n):
            if absent[c]:
                sample.q.append(None)
                continue
            correction = predictor.correction(c, z)
            r = residual[c] - correction
            if not abs(r) < RAW_Q - 1:  # too far (or beyond floats) for a step count: the value itself
                sample.q.append(_Raw(sample.values[c]))
                reconstruction[c], raw[c] = sample.values[c], True
            else:
                q = int(np.round(r))
                sample.q.append(q)
                reconstruction[c] = prediction[c] + (correction + q) * spec.step[c]
                z[c] = correction + q
        predictor.update(reconstruction, z, raw)
        self._cursor[stream], self._phase[stream] = sample.index, sample.phase
        self._queues[stream].append(sample)
        if draft:
            self._add_to_draft(stream)

    # --- the packet being filled ------------------------------------------------------------------

    def _start(self, base: _Chain) -> None:
        self._base = base
        self._full = False
        self._sections = [_Section(p, lost) for p, lost in zip(base.streams, self._lost, strict=True)]
        self._layout(0)

    def _open(self, section: _Section, enc: Encoder) -> None:
        coder = section.base.coder.copy()
        cursor = section.base.cursor
        if section.lost is not None:
            coder.encode_token(enc, LOST)
            coder.encode_count(enc, section.lost)
            cursor = (cursor or 0) + section.lost
        section.open_encoder, section.open_coder, section.open_cursor = enc, coder, cursor
        section.open_phase = section.base.phase

    def _layout(self, first: int, enc: Encoder | None = None) -> Encoder:
        """Re-code sections ``first``.. (their samples as counted) after ``enc``; the finished encoder."""
        enc = Encoder() if enc is None else enc
        for s in range(first, len(self.specs)):
            section = self._sections[s]
            self._open(section, enc)
            coder, cursor, phase = section.open_coder, section.open_cursor, section.open_phase
            for sample in self._queues[s][: section.count]:
                cursor, phase = _code_sample(coder, enc, cursor, phase, sample)  # type: ignore[arg-type]
            section.open_encoder, section.open_cursor, section.open_phase = enc.copy(), cursor, phase
            section.open_coder = coder.copy()  # type: ignore[union-attr]
            coder.encode_token(enc, END)  # type: ignore[union-attr]
        return enc

    def _add_to_draft(self, stream: int) -> None:
        section = self._sections[stream]
        if self._full or section.closed or section.count != len(self._queues[stream]) - 1:
            return
        enc, coder = section.open_encoder.copy(), section.open_coder.copy()  # type: ignore[union-attr]
        cursor, phase = _code_sample(
            coder, enc, section.open_cursor, section.open_phase, self._queues[stream][-1]
        )
        trial_open = (enc.copy(), coder.copy(), cursor, phase)
        coder.encode_token(enc, END)
        saved = [
            (s.open_encoder, s.open_coder, s.open_cursor, s.open_phase) for s in self._sections[stream + 1 :]
        ]
        finished = self._layout(stream + 1, enc)
        if finished.bits_if_finished > CODE_BITS:
            for s, (e, c, k, f) in zip(self._sections[stream + 1 :], saved, strict=True):
                s.open_encoder, s.open_coder, s.open_cursor, s.open_phase = e, c, k, f
            section.closed = self._full = True
            if not any(sec.count for sec in self._sections):
                self._oversize = stream  # this sample alone overflows an empty packet
            return
        section.count += 1
        section.open_encoder, section.open_coder, section.open_cursor, section.open_phase = trial_open

    def _rebase(self, base: _Chain) -> None:
        """Continue from ``base`` (the last delivered state): recompute every pending sample."""
        samples = [list(p) for p in self._queues]
        self._queues = [[] for _ in self.specs]
        for s, position in enumerate(base.streams):
            self.predictors[s].restore(position.predictor)
            self._cursor[s], self._phase[s] = position.cursor, position.phase
            if position.cursor is not None and self._lost[s]:
                self._cursor[s] = position.cursor + self._lost[s]  # type: ignore[operator]
                self.predictors[s].skip(self._lost[s])  # type: ignore[arg-type]
        self._start(base)
        for s, stream_samples in enumerate(samples):
            for sample in stream_samples:
                self._process(s, sample, draft=False)
        self._refill()

    # --- packets out --------------------------------------------------------------------------------

    def _in_draft(self) -> list[_Sample]:
        return [x for s, sec in enumerate(self._sections) for x in self._queues[s][: sec.count]]

    def deadline(self) -> float | None:
        """When a packet must leave: the oldest unpredictable sample's latency bound, or the oldest
        predictable one's silence bound, whichever comes first (None: nothing pending)."""
        firsts = [p[0].time for p in self._queues if p]
        if not firsts:
            return None
        silence = min(firsts) + self.max_silence
        surprises = [x.time for p in self._queues for x in p if any(x.q)]
        return min(silence, min(surprises) + self.max_latency) if surprises else silence

    def ready(self, now: float) -> bool:
        """A packet should go out now: one is full, a sample is urgent, or latency is due."""
        if self.in_flight is not None:
            return False
        draft = self._in_draft()
        if not draft:
            return False
        return self._full or any(x.urgent for x in draft) or now >= self.deadline()  # type: ignore[operator]

    def take(self) -> EncodedPacket:
        """The next priority packet (call when ``ready``); it stays in flight until ``resolve``."""
        draft = self._in_draft()
        if not draft:
            raise RuntimeError("nothing to send")
        enc = self._layout(0)
        bits = enc.finish()
        payload = bytes([(FORMAT << 6) | self._base.id]) + pack_bits(bits, CODE_BYTES)
        urgent = any(x.urgent for x in draft)
        main = self._main_stream(urgent)  # before the taken samples leave the queues
        main_first = self._first_index(main, draft)
        positions, counts, serials, surprises = [], {}, [], {}
        for s, section in enumerate(self._sections):
            taken, rest = self._queues[s][: section.count], self._queues[s][section.count :]
            predictor = rest[0].state_before if rest else self.predictors[s].state()
            coder = section.open_coder.copy()  # type: ignore[union-attr]
            coder.encode_token(Encoder(), END)  # the model update END made (both ends make it)
            positions.append(_Position(predictor, coder, section.open_cursor, section.open_phase))
            counts[self.specs[s].name] = len(taken)
            surprises[self.specs[s].name] = [
                sum(1 for x in taken if x.q[c]) for c in range(len(self.specs[s].channels))
            ]
            serials.append([x.serial for x in taken])
            self._queues[s] = rest
        chain = _Chain(_next_id(self._base.id), positions)
        packet = PriorityPacket(self.seq % 256, Priority.TIME_SENSITIVE if urgent else Priority.ROUTINE,
                                self.specs[main].stream, payload)  # fmt: skip
        encoded = EncodedPacket(packet, main_first, len(draft), sum(sec.lost or 0 for sec in self._sections),
                                [x.time for x in draft], [x.time for x in draft if any(x.q)],
                                sum(1 for x in draft for v in x.q if v), counts, serials, len(bits),
                                surprises)  # fmt: skip
        carried = [sec.count > 0 or sec.lost is not None for sec in self._sections]
        self.in_flight = (chain, carried)
        self.seq += 1
        self._lost = [None] * len(self.specs)
        self._start(chain)
        self._refill()
        self._settle()
        return encoded

    def _main_stream(self, urgent: bool) -> int:
        """The stream named in the header: the one whose sample the caller flagged urgent (an event),
        else one with a sample urgent by its size, else the one with the oldest surprise."""
        best, key = 0, None
        for s, section in enumerate(self._sections):
            for x in self._queues[s][: section.count]:
                k = (not (urgent and x.flagged), not (urgent and x.urgent), not any(x.q), x.time)
                if key is None or k < key:
                    best, key = s, k
        return best

    def _first_index(self, stream: int, draft: list[_Sample]) -> int:
        section = self._sections[stream]
        samples = self._queues[stream][: section.count]
        return samples[0].index if samples else (section.open_cursor or 0)

    def _refill(self) -> None:
        """Put the samples that are still pending into the fresh draft, oldest first across streams."""
        nxt = [0] * len(self.specs)
        while not self._full:
            heads = [(q[nxt[s]].time, s) for s, q in enumerate(self._queues) if nxt[s] < len(q)]
            if not heads:
                return
            _, s = min(heads)
            if self._sections[s].count == nxt[s]:
                self._add_to_draft_index(s, nxt[s])
            nxt[s] += 1

    def _add_to_draft_index(self, stream: int, i: int) -> None:
        """Like ``_add_to_draft`` for the i-th pending sample (the next one the section lacks)."""
        keep = self._queues[stream][i + 1 :]
        self._queues[stream] = self._queues[stream][: i + 1]
        self._add_to_draft(stream)
        self._queues[stream].extend(keep)

    def resolve(self, delivered: bool) -> None:
        """The in-flight packet was delivered (ACK) or lost for good; re-base if lost."""
        if self.in_flight is None:
            return
        (chain, carried), self.in_flight = self.in_flight, None
        if self._restart_on_resolve:
            self._restart_on_resolve = False
            self.restart()
            return
        if delivered:
            self.delivered = chain
            return
        # the lost packet's samples are gone: the next packet says up to which tick, per stream (a
        # stream that had not started on the shore starts afresh, its lost samples before its START)
        for s, position in enumerate(self.delivered.streams):
            end = chain.streams[s].cursor
            if carried[s] and position.cursor is not None and end is not None:
                # the lost packet's end on the delivered packet's grid (the exact inverse of ``_regrid``:
                # the lost packet may have moved the grid)
                end -= (position.phase - chain.streams[s].phase + PHASES // 2) // PHASES
                self._lost[s] = max(0, end - position.cursor)
            else:
                self._lost[s] = None
        self._rebase(self.delivered)
        self._settle()

    def restart(self) -> None:
        """Start over: the next packet continues from the initial state (base 0), whatever was delivered.
        For a shore that lost its decoder state (``UnknownBase``): the samples still pending are re-coded
        from the initial state (each stream starts again with START); a packet in flight is forgotten
        when it resolves (delivered or not, the shore that asked cannot continue from it)."""
        self.delivered = self.initial
        self._lost = [None] * len(self.specs)
        if self.in_flight is not None:
            self._restart_on_resolve = True
            return
        self._rebase(self.initial)
        self._settle()

    def _settle(self) -> None:
        """A sample too large for an empty packet (hundreds of steps off on many channels, raw values)
        would leave the draft full with nothing to send: split it into two samples of the same tick, each
        with half its channels (the others absent), until it fits; a single channel that still does not
        fit (adaptive models very sure of something else) starts over from the initial state, where one
        channel always fits. Nothing is dropped; the shore gets the parts as samples of one tick."""
        while self._oversize is not None:
            s, self._oversize = self._oversize, None
            sample = self._queues[s][0]
            present = np.flatnonzero(~np.isnan(sample.values))
            if len(present) > 1:
                parts = []
                for channels in (present[: len(present) // 2], present[len(present) // 2 :]):
                    values = np.full_like(sample.values, np.nan)
                    values[channels] = sample.values[channels]
                    parts.append(_Sample(sample.time, sample.index, values, sample.urgent, sample.serial,
                                         sample.flagged, sample.phase))  # fmt: skip
                self._queues[s][0:1] = parts
                self.split += 1
                self._rebase(self._base)
            elif self._base is not self.initial:
                self.delivered = self.initial
                self._lost = [None] * len(self.specs)
                self._rebase(self.initial)
            else:  # cannot happen (one channel from the initial models takes < 200 bits): never stall
                self._queues[s].pop(0)
                self.refused += 1
                self._rebase(self._base)


class StreamEncoder(PacketEncoder):
    """A single stream's encoder (``tacit eval-compression``, tests): ``push(time, values)``."""

    def __init__(self, spec: StreamSpec, max_latency: float = 10.0, urgent_threshold: float | None = None,
                 max_silence: float = 60.0) -> None:  # fmt: skip
        super().__init__([spec], max_latency, urgent_threshold, max_silence)
        self.spec = spec

    def push(self, time: float, values: np.ndarray | list[float], urgent: bool = False) -> bool:  # type: ignore[override]
        return super().push(0, time, values, urgent)


# --- the shore -----------------------------------------------------------------------------------------


@dataclass
class DecodedSpan:
    """One stream's samples from one packet."""

    spec: StreamSpec
    ticks: np.ndarray  # the tick of each sample (its time: ``times``, within period / 2)
    values: np.ndarray  # samples x channels, the shore's reconstruction (within eps); NaN = absent
    lost: tuple[int, int] | None  # [start, end) ticks in a lost packet (the shore cannot vouch for them)
    phases: np.ndarray  # each sample's grid phase, sixteenths of a tick
    lost_phase: int  # the grid the lost ticks are on

    @property
    def first_tick(self) -> int:
        return int(self.ticks[0]) if len(self.ticks) else (self.lost[1] if self.lost else 0)

    @property
    def times(self) -> np.ndarray:
        """Each sample's time as the shore dates it (seconds; within period / 2 of when it was taken)."""
        return (self.ticks + self.phases / PHASES) * self.spec.period

    @property
    def lost_times(self) -> np.ndarray:
        """The times of the ticks in ``lost`` (none if nothing was lost)."""
        ticks = np.arange(*self.lost) if self.lost else np.zeros(0)
        return (ticks + self.lost_phase / PHASES) * self.spec.period


class PacketDecoder:
    """The shore's side: payloads in, each stream's reconstructed samples out, in the vehicle's chain."""

    def __init__(self, specs: list[StreamSpec]) -> None:
        self.specs = list(specs)
        self.predictors = [_Dual(s) for s in self.specs]
        self._initial = _Chain(0, [_Position(p.state(), _Coder.new(len(s.channels)), None)
                                   for p, s in zip(self.predictors, self.specs, strict=True)])  # fmt: skip
        self.snapshots: dict[int, _Chain] = {}

    def decode(self, payload: bytes, received_at: float) -> list[DecodedSpan]:
        """Every stream's samples in a packet (empty streams included); ``CodecError`` if it is not
        this format, its base state is not held here, or it is malformed."""
        try:
            return self._decode(payload, received_at)
        except CodecError:
            raise
        except (ValueError, IndexError, ArithmeticError, TypeError) as exc:  # malformed beyond the checks
            raise CodecError(f"malformed payload ({exc})") from None

    def _decode(self, payload: bytes, received_at: float) -> list[DecodedSpan]:
        if len(payload) != PAYLOAD_SIZE:
            raise CodecError(f"payload is {len(payload)} bytes, not {PAYLOAD_SIZE}")
        version, base_id = payload[0] >> 6, payload[0] & 0x3F
        if version != FORMAT:
            raise CodecError(f"sample format version {version}; this shore decodes version {FORMAT}")
        if base_id == 0:
            base = self._initial
        elif base_id in self.snapshots:
            base = self.snapshots[base_id]
        else:
            raise UnknownBase(base_id)
        decoder = Decoder(payload[HEADER_BYTES:])
        spans, positions = [], []
        for s, spec in enumerate(self.specs):
            span, position = self._section(decoder, s, spec, base.streams[s], received_at)
            spans.append(span)
            positions.append(position)
        if base_id == 0:  # the vehicle started over: nothing before this packet will be a base again
            self.snapshots.clear()
        self.snapshots.pop(_next_id(base_id), None)  # the dict's order: least recently decoded first
        self.snapshots[_next_id(base_id)] = _Chain(_next_id(base_id), positions)
        return spans

    def mark(self) -> dict[int, _Chain]:
        """The states held now, for ``undo`` (cheap: a state is never changed once decoded)."""
        return dict(self.snapshots)

    def undo(self, mark: dict[int, _Chain]) -> None:
        """Forget what was decoded since ``mark`` (a caller's transaction that did not commit)."""
        self.snapshots = dict(mark)

    # --- persistence: the shore keeps its chain across restarts -------------------------------------

    def _fingerprint(self) -> list:
        return [[s.name, int(s.stream), list(s.channels), list(s.eps), s.period, s.method,
                 None if s.initial is None else list(s.initial), s.cross] for s in self.specs]  # fmt: skip

    def to_bytes(self, keep: int | None = None) -> bytes:
        """The decoder's state (the states packets may continue from), to store and give to
        ``from_bytes`` after a restart. ``keep``: only the ``keep`` most recently decoded (the vehicle
        continues from the last packet it knows was delivered, almost always the newest; a packet based
        on one not kept raises ``UnknownBase``, and the vehicle is asked to ``restart``). zlib-compressed
        JSON; floats round-trip exactly."""
        chains = list(self.snapshots.values())
        if keep is not None:
            chains = chains[len(chains) - keep :] if keep > 0 else []
        doc = {"format": FORMAT, "specs": self._fingerprint(),
               "chains": [[c.id, [[_dump(p.predictor), p.coder.dump(), p.cursor, p.phase] for p in c.streams]]
                          for c in chains]}  # fmt: skip
        return zlib.compress(json.dumps(doc, separators=(",", ":")).encode(), 6)

    def load(self, data: bytes) -> None:
        """Take the state ``to_bytes`` saved (replacing what this decoder holds); ``CodecError`` if
        ``data`` is not such a state or was saved for other streams (the decoder is then unchanged: start
        empty, and the vehicle will be asked to restart)."""
        try:
            doc = json.loads(zlib.decompress(data))
            if doc["format"] != FORMAT or doc["specs"] != self._fingerprint():
                raise CodecError("saved decoder state is for another format or other streams")
            snapshots = {}
            for chain_id, streams in doc["chains"]:
                ok = (
                    isinstance(chain_id, int)
                    and 1 <= chain_id <= CHAIN_IDS
                    and len(streams) == len(self.specs)
                )
                if not ok:
                    raise CodecError("saved decoder state is malformed")
                positions = [
                    _Position(_load(p), _Coder.load(c), _cursor(k), _phase(f)) for p, c, k, f in streams
                ]
                snapshots[chain_id] = _Chain(chain_id, positions)
        except CodecError:
            raise
        except (
            ValueError,
            KeyError,
            IndexError,
            TypeError,
            OverflowError,
            RecursionError,
            zlib.error,
        ) as exc:
            raise CodecError(f"saved decoder state is malformed ({exc})") from None
        self.snapshots = snapshots

    @classmethod
    def from_bytes(cls, specs: list[StreamSpec], data: bytes) -> PacketDecoder:
        """``PacketDecoder(specs)`` holding the state ``to_bytes`` saved (see ``load``)."""
        decoder = PacketDecoder(specs)
        decoder.load(data)
        return decoder

    def _section(self, decoder: Decoder, s: int, spec: StreamSpec, base: _Position,
                 received_at: float) -> tuple[DecodedSpan, _Position]:  # fmt: skip
        predictor = self.predictors[s]
        predictor.restore(base.predictor)
        coder, cursor, phase = base.coder.copy(), base.cursor, base.phase
        ticks: list[int] = []
        phases: list[int] = []
        rows: list[np.ndarray] = []
        lost = None
        step = spec.step
        while True:
            token = coder.decode_token(decoder)
            if token == END:
                break
            if token == LOST:
                if cursor is None or ticks or phase != base.phase:
                    raise CodecError(f"{spec.name}: LOST where it cannot be")
                n = coder.decode_count(decoder)
                lost = (cursor + 1, cursor + 1 + n) if n else (cursor, cursor + 1)
                cursor += n
                predictor.skip(n)
                continue
            if token == PHASE:
                if cursor is None:
                    raise CodecError(f"{spec.name}: PHASE before the stream's start")
                new = _decode_bits(decoder, PHASE_BITS)
                cursor, phase = _regrid(cursor, phase, new), new
                continue
            if token == START:
                if cursor is not None:
                    raise CodecError(f"{spec.name}: START after the stream started")
                phase = _decode_bits(decoder, PHASE_BITS)
                low = _decode_bits(decoder, TICK_BITS)
                now = spec.tick(received_at, phase) + 1
                index = now - ((now - low) % (1 << TICK_BITS))
                prediction = predictor.predict()
            elif cursor is None:
                raise CodecError(f"{spec.name}: a sample before the stream's start")
            elif token == SAME:
                index = cursor
                prediction = predictor.current()
            else:
                index = cursor + 1 if token == STEP else cursor + 2 + coder.decode_count(decoder)
                predictor.skip(index - cursor - 1)
                prediction = predictor.predict()
            q = coder.decode_sample(decoder)
            n = len(q)
            values, z, raw = np.full(n, np.nan), np.zeros(n), np.zeros(n, dtype=bool)
            for c, v in enumerate(q):
                if v is None:
                    continue
                if isinstance(v, _Raw):
                    values[c], raw[c] = v.value, True
                else:
                    correction = predictor.correction(c, z)
                    values[c] = prediction[c] + (correction + v) * step[c]
                    z[c] = correction + v
            predictor.update(values, z, raw)
            ticks.append(index)
            phases.append(phase)
            rows.append(values)
            cursor = index
            if len(rows) > CODE_BITS * 64:
                raise CodecError("more samples than a packet can hold")
        values = np.array(rows) if rows else np.zeros((0, len(spec.channels)))
        span = DecodedSpan(
            spec, np.array(ticks, dtype=np.int64), values, lost, np.array(phases, dtype=np.int64), base.phase
        )
        return span, _Position(predictor.state(), coder, cursor, phase)


class StreamDecoder(PacketDecoder):
    """A single stream's decoder: ``decode`` returns its one span."""

    def __init__(self, spec: StreamSpec) -> None:
        super().__init__([spec])
        self.spec = spec

    def decode(self, payload: bytes, received_at: float) -> DecodedSpan:  # type: ignore[override]
        return super().decode(payload, received_at)[0]


def _cursor(value: object) -> int | None:
    if value is None or (isinstance(value, int) and not isinstance(value, bool)):
        return value
    raise ValueError(f"cursor {value!r}")


def _phase(value: object) -> int:
    if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < PHASES:
        return value
    raise ValueError(f"phase {value!r}")


def _dump(state: object) -> object:
    """A predictor snapshot (tuples, lists, arrays, numbers) as JSON-able data."""
    if isinstance(state, np.ndarray):
        return {"a": state.tolist(), "d": str(state.dtype)}
    if isinstance(state, tuple):
        return {"t": [_dump(x) for x in state]}
    if isinstance(state, list):
        return [_dump(x) for x in state]
    if isinstance(state, np.generic):
        return state.item()
    return state


def _load(data: object) -> object:
    if isinstance(data, dict):
        if "a" in data:
            return np.array(data["a"], dtype=np.dtype(data["d"]))
        return tuple(_load(x) for x in data["t"])
    if isinstance(data, list):
        return [_load(x) for x in data]
    return data
