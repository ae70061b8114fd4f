"""The shore's side: payloads in, each stream's reconstructed samples out, in the vehicle's chain.

The decoder runs the vehicle's predictors and models on what it reads (``tacit.codec.grammar``): each
present value is reconstructed within its eps, each sample dated within half a tick
(``tacit.codec.grid``), absent channels stay absent (NaN), and the ticks of a lost packet are declared
(``DecodedSpan.lost``), never filled in. It keeps the state each decoded packet left, so the next packet
can continue from it (``tacit.codec.state``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tacit.arithmetic import Decoder
from tacit.codec.format import (
    CODE_BITS,
    MAX_BACK,
    MAX_WINDOW,
    SEQS,
    CodecError,
    UnknownBase,
    chain_ids,
    unpack,
)
from tacit.codec.grammar import (
    RawValue,
    continues,
    placed,
    presence_before,
    read_sample,
    read_token,
    started,
)
from tacit.codec.grid import PHASES, regrid
from tacit.codec.prediction import Dual
from tacit.codec.spec import StreamSpec
from tacit.codec.state import Chain, Position, restore, save
from tacit.codec.tokens import END, LOST, PHASE, SAME, START
from tacit.codec.versions import coding


@dataclass
class DecodedSpan:
    """One stream's samples from one packet."""

    spec: StreamSpec
    ticks: np.ndarray  # the tick of each sample (its time: ``times``, within period / 2)
    values: np.ndarray  # samples x channels, the shore's reconstruction (within eps); NaN = absent
    lost: tuple[int, int] | None  # [start, end) ticks in a lost packet (the shore cannot vouch for them)
    phases: np.ndarray  # each sample's grid phase, sixteenths of a tick
    lost_phase: int  # the grid the lost ticks are on
    # the first row is the rest of the stream's last row in the packet before (a sample sent in parts:
    # the same tick, the channels that row lacks); parts within one packet are merged into one row
    continues: bool = False

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

    def __init__(self, specs: list[StreamSpec], protocol: int = 3) -> None:
        """``protocol``: the version the vehicle speaks, which says what its payloads code
        (``tacit.codec.versions``)."""
        self.specs = list(specs)
        self.coding = coding(protocol)
        self.predictors = [Dual(s, self.coding) for s in self.specs]
        self._initial = Chain.initial(self.specs, self.predictors, self.coding)
        self.snapshots: dict[int, Chain] = {}

    def decode(self, payload: bytes, received_at: float, seq: int | None = None) -> list[DecodedSpan]:
        """Every stream's samples in a packet (empty streams included); ``CodecError`` if it is not
        this format, its base state is not held here, or it is malformed. ``seq``: the priority packet's
        (version 4 names states by it: required)."""
        if seq is None and self.coding.window:
            raise ValueError(f"protocol {self.coding.version} decodes a payload with its packet's seq")
        seq = seq or 0
        try:
            return self._decode(payload, received_at, seq)
        except CodecError:
            raise
        except (ValueError, IndexError, ArithmeticError, TypeError) as exc:  # malformed beyond the checks
            raise CodecError(f"malformed payload ({exc})") from None

    @property
    def keep(self) -> int:
        """How many states are worth saving (``to_bytes``): the vehicle continues from its last delivered
        packet (version 3), or from one of the packets of its window (version 4)."""
        return MAX_WINDOW + 2 if self.coding.window else 4

    def ahead(self, base: int, seq: int) -> bool:
        """Version 4: whether the state ``base`` (not held), on which the packet with ``seq`` continues,
        may still come: newer than every state held, the packet with ``seq`` no further than
        ``MAX_WINDOW`` seqs after the one that follows the newest held (the vehicle numbers no packet
        further than that from the oldest whose fate it has not heard): a packet of its window that
        was lost or comes later (if lost, the vehicle codes again from a state held). False when no
        state is held, or ``base`` is older than one held, or ``seq`` further on: the vehicle heard a
        packet delivered that this shore never had, so it must start over."""
        if not self.coding.window or not base:
            return False
        behind = [(seq - (k - 1)) % SEQS for k in self.snapshots]
        held = [b for b in behind if b <= MAX_BACK]  # not those of packets after it (come first)
        return bool(held) and (seq - (base - 1)) % SEQS < min(held) <= MAX_WINDOW + 1

    def _decode(self, payload: bytes, received_at: float, seq: int) -> list[DecodedSpan]:
        _, code = unpack(payload, self.coding.window)
        base_id, own = chain_ids(payload, seq)
        if base_id == 0:
            base = self._initial
        elif base_id in self.snapshots:
            base = self.snapshots[base_id]
        else:
            raise UnknownBase(base_id)
        decoder = Decoder(code)
        spans, positions = [], []
        for s, spec in enumerate(self.specs):
            span, position = self._section(decoder, s, spec, base.streams[s], received_at)
            spans.append(span)
            positions.append(position)
        if base_id == 0:  # the vehicle started over: nothing before this packet will be a base again
            self.snapshots.clear()
        self.snapshots.pop(own, None)  # the dict's order: least recently decoded first
        self.snapshots[own] = Chain(own, positions)
        if self.coding.window:  # states named by a seq that has come round again are another packet's
            for stale in [k for k in self.snapshots if MAX_BACK < (seq - (k - 1)) % SEQS <= SEQS - MAX_BACK]:
                del self.snapshots[stale]
        return spans

    def mark(self) -> dict[int, Chain]:
        """The states held now, for ``undo`` (cheap: a state is never changed once decoded)."""
        return dict(self.snapshots)

    def undo(self, mark: dict[int, Chain]) -> None:
        """Forget what was decoded since ``mark`` (a caller's transaction that did not commit)."""
        self.snapshots = dict(mark)

    # --- persistence: the shore keeps its chain across restarts (``tacit.codec.state``) -------------

    def to_bytes(self, keep: int | None = None) -> bytes:
        """The decoder's state (the states packets may continue from), to store and give to
        ``from_bytes`` after a restart. ``keep``: only the ``keep`` most recently decoded (the vehicle
        continues from the last packet it knows was delivered, almost always the newest; a packet based
        on one not kept raises ``UnknownBase``, and the vehicle is asked to ``restart``)."""
        chains = list(self.snapshots.values())
        if keep is not None:
            chains = chains[len(chains) - keep :] if keep > 0 else []
        return save(self.specs, chains)

    def load(self, data: bytes) -> None:
        """Take the state ``to_bytes`` saved (replacing what this decoder holds); ``CodecError`` if
        ``data`` is not such a state or was saved for other streams (the decoder is then unchanged: start
        empty, and the vehicle will be asked to restart)."""
        self.snapshots = restore(self.specs, data, self.coding)

    @classmethod
    def from_bytes(cls, specs: list[StreamSpec], data: bytes, protocol: int = 3) -> PacketDecoder:
        """``PacketDecoder(specs, protocol)`` holding the state ``to_bytes`` saved (see ``load``)."""
        decoder = PacketDecoder(specs, protocol)
        decoder.load(data)
        return decoder

    def _section(
        self, decoder: Decoder, s: int, spec: StreamSpec, base: Position, received_at: float
    ) -> tuple[DecodedSpan, Position]:
        predictor = self.predictors[s]
        predictor.restore(base.predictor)
        coder, cursor, phase = base.coder.copy(), base.cursor, base.phase
        ticks: list[int] = []
        phases: list[int] = []
        rows: list[np.ndarray] = []
        lost, first_continues, last_phase = None, False, base.phase
        held: list[bool] = []  # the channels the last row holds
        while True:
            token = read_token(coder, decoder)
            if token.kind == END:
                break
            if token.kind == LOST:
                if cursor is None or ticks or phase != base.phase:
                    raise CodecError(f"{spec.name}: LOST where it cannot be")
                n = token.n
                lost = (cursor + 1, cursor + 1 + n) if n else (cursor, cursor + 1)
                cursor += n
                predictor.skip(n)
                continue
            if token.kind == PHASE:
                if cursor is None:
                    raise CodecError(f"{spec.name}: PHASE before the stream's start")
                cursor, phase = regrid(cursor, phase, token.phase), token.phase
                continue
            if token.kind == START:
                if cursor is not None:
                    raise CodecError(f"{spec.name}: START after the stream started")
                phase = token.phase
                index = started(token.low, spec.tick(received_at, phase) + 1)
                prediction = predictor.predict()
            elif cursor is None:
                raise CodecError(f"{spec.name}: a sample before the stream's start")
            elif token.kind == SAME:
                index = cursor
                prediction = predictor.current()
            else:
                index = placed(cursor, token)
                predictor.skip(index - cursor - 1)
                prediction = predictor.predict()
            # a part joins the row so far when it has none of that row's channels (not only the last part's)
            before = held if rows else presence_before(coder)
            same_tick = token.kind == SAME and phase == last_phase
            row = _reconstruct(predictor, prediction, read_sample(coder, decoder))
            present = presence_before(coder)  # the channels the sample just read has
            if continues(before, present, same_tick) and (rows or lost is None):
                if rows:  # a part of the row before: one row
                    rows[-1] = np.where(np.isnan(rows[-1]), row, rows[-1])
                    held = [b or p for b, p in zip(held, present, strict=True)]
                    continue
                first_continues = True  # the rest of the last packet's last row: it holds that part's too
                held = [b or p for b, p in zip(before, present, strict=True)]
            else:
                held = present
            ticks.append(index)
            phases.append(phase)
            rows.append(row)
            cursor, last_phase = index, phase
            if len(rows) > CODE_BITS * 64:
                raise CodecError("more samples than a packet can hold")
        values = np.array(rows) if rows else np.zeros((0, len(spec.channels)))
        span = DecodedSpan(
            spec,
            np.array(ticks, dtype=np.int64),
            values,
            lost,
            np.array(phases, dtype=np.int64),
            base.phase,
            first_continues,
        )
        return span, Position(predictor.state(), coder, cursor, phase)


def _reconstruct(predictor: Dual, prediction: np.ndarray, q: list[int | None]) -> np.ndarray:
    """A sample's values from its q's (NaN: absent), fed back into the predictor as the vehicle did.
    The arithmetic is on Python floats, the same IEEE operations as on numpy's scalars, without them."""
    n = len(q)
    predicted, fine, step = prediction.tolist(), predictor.fine().tolist(), predictor.step.tolist()
    values, z, raw = np.full(n, np.nan), np.zeros(n), np.zeros(n, dtype=bool)
    for c, v in enumerate(q):
        if v is None:
            continue
        if isinstance(v, RawValue):
            values[c], raw[c] = v.value, True
        else:
            correction = predictor.correction(c, z)
            values[c] = predicted[c] + (correction + v * fine[c]) * step[c]
            z[c] = correction + v * fine[c]
    predictor.update(values, z, raw)
    return values


class StreamDecoder(PacketDecoder):
    """A single stream's decoder: ``decode`` returns its one span."""

    def __init__(self, spec: StreamSpec, protocol: int = 3) -> None:
        super().__init__([spec], protocol)
        self.spec = spec

    def decode(self, payload: bytes, received_at: float, seq: int | None = None) -> DecodedSpan:  # type: ignore[override]
        return super().decode(payload, received_at, seq)[0]
