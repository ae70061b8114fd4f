"""The sample codec: what goes in a priority packet's 30 bytes, and how the shore gets it back.

Quantisation. For channel c with error bound eps_c, the vehicle sends q = round((x - p) / s) with
p the dual prediction (``tacit.predict``) and s = 2 eps_c (1 - 1e-9); the shore reconstructs
p + q s, so |reconstruction - x| <= eps_c for every sample (the 1e-9 margin absorbs floating-point
rounding). q = 0 is the paper's "predictable" verdict: the shore's prediction is already within eps.
Both ends feed the reconstruction, not the raw value, back into the predictor.

Entropy coding. Every tick's q for every channel is arithmetic-coded (``tacit.arithmetic``) with an
adaptive model per channel and context (whether that channel's previous q was 0): symbols -6..6 and
two escapes, an escaped magnitude as an Exp-Golomb code. A run of predictable ticks costs a few
hundredths of a bit per sample; a surprise costs what its size needs.

Payload (30 bytes, after the priority packet's 2-byte header)::

    byte 0-1   first tick index k0 (u16, wraps; tick = round(time / period))
    byte 2     number of ticks n (1-255)
    byte 3-29  arithmetic code (216 bits), zero-padded, starting with the gap: one bit 0 = continues
               from the state at the end of tick k0-1 (almost always); one bit 1 and eight bits g:
               g in 1-254 = continues from the state at the end of tick k0-g-1 (the ticks between were
               lost: the shore marks them unbounded and the predictors skip them); g = 255 = starts
               from the initial state (first packet, or after a long loss)

Packets chain: each continues from a predictor and model state both ends hold. The vehicle learns
from the modem's ACK which packets arrived and bases the next packet on the last delivered one, so
one lost packet costs its own span, never the ones after it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tacit.arithmetic import AdaptiveModel, Decoder, Encoder, pack_bits
from tacit.packets import PAYLOAD_SIZE, Priority, PriorityPacket, Stream
from tacit.predict import Predictor, make_predictor

HEADER_BYTES = 3
CODE_BYTES = PAYLOAD_SIZE - HEADER_BYTES
CODE_BITS = CODE_BYTES * 8
MAX_TICKS = 255
RESET = 255
SMALL = 6
ESC_NEG, ESC_POS = 2 * SMALL + 1, 2 * SMALL + 2
PRIOR = [1, 1, 1, 2, 4, 8, 24, 8, 4, 2, 1, 1, 1, 1, 1]
MARGIN = 1 - 1e-9


class CodecError(ValueError):
    """A payload that cannot be decoded (its base state is unknown, or it is malformed)."""


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

    def __post_init__(self) -> None:
        if len(self.eps) != len(self.channels):
            raise ValueError("one eps per channel")
        if any(not e > 0 for e in self.eps):
            raise ValueError("every eps must be positive")
        if not self.period > 0:
            raise ValueError("period must be positive")

    @property
    def step(self) -> np.ndarray:
        return 2 * np.asarray(self.eps, dtype=float) * MARGIN

    def predictor(self) -> Predictor:
        return make_predictor(
            self.method, len(self.channels), None if self.initial is None else np.array(self.initial)
        )

    def tick(self, time: float) -> int:
        return round(time / self.period)


@dataclass
class _Coder:
    """Adaptive models per channel and context, and each channel's previous symbol."""

    models: list[list[AdaptiveModel]]
    previous: list[int]

    @classmethod
    def new(cls, channels: int) -> _Coder:
        return cls([[AdaptiveModel(list(PRIOR)) for _ in range(2)] for _ in range(channels)], [0] * channels)

    def copy(self) -> _Coder:
        return _Coder([[m.copy() for m in pair] for pair in self.models], list(self.previous))

    def encode(self, enc: Encoder, q: np.ndarray) -> None:
        for c, value in enumerate(int(v) for v in q):
            model = self.models[c][self.previous[c] != 0]
            if -SMALL <= value <= SMALL:
                enc.encode_symbol(model, value + SMALL)
            else:
                enc.encode_symbol(model, ESC_POS if value > 0 else ESC_NEG)
                _encode_exp_golomb(enc, abs(value) - SMALL - 1)
            self.previous[c] = value

    def decode(self, dec: Decoder) -> np.ndarray:
        out = np.zeros(len(self.models), dtype=np.int64)
        for c in range(len(self.models)):
            symbol = dec.decode_symbol(self.models[c][self.previous[c] != 0])
            if symbol < ESC_NEG:
                value = symbol - SMALL
            else:
                magnitude = _decode_exp_golomb(dec) + SMALL + 1
                value = magnitude if symbol == ESC_POS else -magnitude
            out[c] = value
            self.previous[c] = value
        return out


def _encode_gap(enc: Encoder, gap: int) -> None:
    enc.encode_bit(1 if gap else 0)
    if gap:
        for i in range(7, -1, -1):
            enc.encode_bit((gap >> i) & 1)


def _decode_gap(dec: Decoder) -> int:
    if not dec.decode_bit():
        return 0
    gap = 0
    for _ in range(8):
        gap = (gap << 1) | dec.decode_bit()
    return gap


def _encode_exp_golomb(enc: Encoder, n: int) -> None:
    m = n + 1
    width = m.bit_length()
    for _ in range(width - 1):
        enc.encode_bit(0)
    for i in range(width - 1, -1, -1):
        enc.encode_bit((m >> i) & 1)


def _decode_exp_golomb(dec: Decoder) -> int:
    zeros = 0
    while dec.decode_bit() == 0:
        zeros += 1
        if zeros > 64:
            raise CodecError("escaped magnitude too long")
    m = 1
    for _ in range(zeros):
        m = (m << 1) | dec.decode_bit()
    return m - 1


@dataclass
class _Chain:
    """The state both ends hold after a tick: predictor and coder; ``end`` is that tick's index + 1,
    or None for the initial state (a packet based on it says RESET and needs no skipping)."""

    end: int | None
    predictor: object
    coder: _Coder


@dataclass
class _Tick:
    index: int
    time: float
    values: np.ndarray
    q: np.ndarray
    state_after_previous: object  # the predictor right after the previous tick, before any skip
    urgent: bool = False


@dataclass
class EncodedPacket:
    """A priority packet and what it covers (for logs, latency and the link's bookkeeping)."""

    packet: PriorityPacket
    first_tick: int
    ticks: int
    gap: int
    sample_times: list[float]
    surprise_times: list[float]  # the samples the shore could not predict (q != 0)
    nonzero: int


@dataclass
class _Draft:
    """The packet being filled: ticks ``pending[:count]`` are in ``encoder``."""

    base: _Chain
    coder: _Coder
    gap: int = RESET
    encoder: Encoder = field(default_factory=Encoder)
    count: int = 0
    full: bool = False


class StreamEncoder:
    """The vehicle's side: ticks in, priority packets out, re-based on the last delivered packet."""

    def __init__(
        self,
        spec: StreamSpec,
        max_latency: float = 10.0,
        urgent_threshold: float | None = None,
        max_silence: float = 60.0,
    ) -> None:
        """An unpredictable sample (q != 0) leaves within ``max_latency`` seconds; a predictable one
        (the paper's silence) only needs confirming within ``max_silence``, so a quiet stream does not
        pay a packet per latency period. ``urgent_threshold``: a tick with any |q| at or above it (a
        surprise of that many 2-eps steps) is time-sensitive and makes its packet leave at once."""
        self.spec = spec
        self.max_latency = max_latency
        self.max_silence = max(max_silence, max_latency)
        self.urgent_threshold = urgent_threshold
        self.predictor = spec.predictor()
        self.initial = _Chain(None, self.predictor.state(), _Coder.new(len(spec.channels)))
        self.delivered = self.initial
        self.pending: list[_Tick] = []
        self.in_flight: _Chain | None = None
        self.seq = 0
        self._draft = _Draft(self.initial, self.initial.coder.copy())
        self._last_index: int | None = None  # the last tick accepted (duplicates are dropped)
        self._carry_urgent = False
        self._predicted_to: int | None = None  # the last tick the predictor has processed

    # --- ticks in -------------------------------------------------------------------------------

    def push(self, time: float, values: np.ndarray | list[float], urgent: bool = False) -> bool:
        """Add one sample per channel taken at ``time``; False if it was a duplicate tick (dropped)."""
        index = self.spec.tick(time)
        if self._last_index is not None and index <= self._last_index:
            if urgent:  # the sample is dropped, its urgency is not: it rides on this tick's sample
                if self.pending and self.pending[-1].index == self._last_index:
                    self.pending[-1].urgent = True
                else:
                    self._carry_urgent = True
            return False
        state = self.predictor.state()
        tick = _Tick(index, time, np.asarray(values, dtype=float), np.zeros(0, np.int64), state,
                     urgent or self._carry_urgent)  # fmt: skip
        self._carry_urgent = False
        self._process(tick)
        if self.urgent_threshold is not None and np.any(np.abs(tick.q) >= self.urgent_threshold):
            tick.urgent = True
        self._last_index = index
        return True

    def _process(self, tick: _Tick) -> None:
        """Skip the ticks the predictor has not seen, quantise, update, add to the draft."""
        tick.state_after_previous = self.predictor.state()
        for _ in range(0 if self._predicted_to is None else tick.index - self._predicted_to - 1):
            self.predictor.skip()
        self._predicted_to = tick.index
        prediction = self.predictor.predict()
        tick.q = np.round((tick.values - prediction) / self.spec.step).astype(np.int64)
        self.predictor.update(prediction + tick.q * self.spec.step)
        self.pending.append(tick)
        self._add_to_draft(tick)

    def _add_to_draft(self, tick: _Tick) -> None:
        draft = self._draft
        if draft.full:
            return
        if draft.count == 0:
            if draft.base.end is not None:
                draft.gap = tick.index - draft.base.end
                if draft.gap >= RESET:  # too long to say: both ends start again from the initial state
                    self._rebase(self.initial)
                    return
            draft.encoder = Encoder()
            _encode_gap(draft.encoder, draft.gap)
        elif draft.count and tick.index != self.pending[draft.count - 1].index + 1:
            draft.full = True  # ticks inside a packet are contiguous; a sensor gap ends it
            return
        trial_encoder, trial_coder = draft.encoder.copy(), draft.coder.copy()
        trial_coder.encode(trial_encoder, tick.q)
        if draft.count >= MAX_TICKS or trial_encoder.bits_if_finished > CODE_BITS:
            draft.full = True
            return
        draft.encoder, draft.coder, draft.count = trial_encoder, trial_coder, draft.count + 1

    def _rebase(self, base: _Chain) -> None:
        """Continue from ``base`` (the last delivered state, or the initial one): recompute pending."""
        self.predictor.restore(base.predictor)
        ticks, self.pending = self.pending, []
        self._draft = _Draft(base, base.coder.copy())
        self._predicted_to = None if base.end is None else base.end - 1
        for tick in ticks:
            self._process(tick)

    # --- packets out ----------------------------------------------------------------------------

    def deadline(self) -> float | None:
        """When a packet must leave: the oldest unpredictable sample's latency bound, or the oldest
        predictable one's silence bound, whichever comes first (None: nothing pending)."""
        if not self.pending:
            return None
        silence = self.pending[0].time + self.max_silence
        surprise = next((t.time + self.max_latency for t in self.pending if t.q.any()), silence)
        return min(silence, surprise)

    def ready(self, now: float) -> bool:
        """A packet should go out now: one is full, a sample is urgent, or latency is due."""
        if not self.pending or self.in_flight is not None or self._draft.count == 0:
            return False
        urgent = any(t.urgent for t in self.pending[: self._draft.count])
        return self._draft.full or urgent or now >= self.deadline()  # type: ignore[operator]

    def take(self) -> EncodedPacket:
        """The next priority packet (call when ``ready``); it stays in flight until ``resolve``."""
        draft = self._draft
        if draft.count == 0:
            raise RuntimeError("nothing to send")
        ticks, rest = self.pending[: draft.count], self.pending[draft.count :]
        end_state = rest[0].state_after_previous if rest else self.predictor.state()
        chain = _Chain(ticks[-1].index + 1, end_state, draft.coder)
        k0 = ticks[0].index & 0xFFFF
        payload = bytes([k0 >> 8, k0 & 0xFF, len(ticks)]) + pack_bits(draft.encoder.finish(), CODE_BYTES)
        urgent = any(t.urgent for t in ticks)
        packet = PriorityPacket(self.seq % 256, Priority.TIME_SENSITIVE if urgent else Priority.ROUTINE,
                                self.spec.stream, payload)  # fmt: skip
        encoded = EncodedPacket(packet, ticks[0].index, len(ticks), draft.gap, [t.time for t in ticks],
                                [t.time for t in ticks if t.q.any()],
                                int(sum(np.count_nonzero(t.q) for t in ticks)))  # fmt: skip
        self.in_flight = chain
        self.seq += 1
        self.pending = rest
        self._draft = _Draft(chain, chain.coder.copy())
        for tick in rest:
            self._add_to_draft(tick)
        return encoded

    def resolve(self, delivered: bool) -> None:
        """The in-flight packet was delivered (ACK) or lost for good; re-base if lost."""
        if self.in_flight is None:
            return
        chain, self.in_flight = self.in_flight, None
        if delivered:
            self.delivered = chain
        else:
            self._rebase(self.delivered)


@dataclass
class DecodedSpan:
    first_tick: int
    values: np.ndarray  # ticks x channels, the shore's reconstruction (within eps of the truth)
    lost: tuple[int, int] | None  # [start, end) ticks this packet says were lost before it


class StreamDecoder:
    """The shore's side: payloads in, reconstructed samples out, in the vehicle's own chain."""

    def __init__(self, spec: StreamSpec, keep: int = 64) -> None:
        self.spec = spec
        self.predictor = spec.predictor()
        self._initial = _Chain(None, self.predictor.state(), _Coder.new(len(spec.channels)))
        self.snapshots: dict[int, _Chain] = {}
        self.keep = keep

    def _unwrap(self, k0_low: int, received_at: float) -> int:
        """The full tick index: the one with these low 16 bits at or just before reception."""
        now = self.spec.tick(received_at) + 1
        return now - ((now - k0_low) % 65536)

    def decode(self, payload: bytes, received_at: float) -> DecodedSpan:
        """Reconstruct a packet's samples; ``CodecError`` if its base state is not held here."""
        if len(payload) != PAYLOAD_SIZE:
            raise CodecError(f"payload is {len(payload)} bytes, not {PAYLOAD_SIZE}")
        k0_low, n = (payload[0] << 8) | payload[1], payload[2]
        if n == 0:
            raise CodecError("a packet holds at least one tick")
        k0 = self._unwrap(k0_low, received_at)
        decoder = Decoder(payload[HEADER_BYTES:])
        gap = _decode_gap(decoder)
        if gap == RESET:
            base, lost = self._initial, None
        else:
            base_end = k0 - gap
            base = self.snapshots.get(base_end)
            if base is None:
                raise CodecError(f"no state for tick {base_end}: an earlier packet was not received")
            lost = (base_end, k0) if gap else None
        self.predictor.restore(base.predictor)
        coder = base.coder.copy()
        for _ in range(gap if gap != RESET else 0):
            self.predictor.skip()
        values = np.zeros((n, len(self.spec.channels)))
        for i in range(n):
            prediction = self.predictor.predict()
            q = coder.decode(decoder)
            values[i] = prediction + q * self.spec.step
            self.predictor.update(values[i])
        self._remember(_Chain(k0 + n, self.predictor.state(), coder))
        return DecodedSpan(k0, values, lost)

    def _remember(self, chain: _Chain) -> None:
        self.snapshots[chain.end] = chain  # type: ignore[index]
        while len(self.snapshots) > self.keep:
            del self.snapshots[min(self.snapshots)]
