"""The vehicle's side: samples of every stream in, priority packets out, each based on the last delivered one.

Each sample is quantised against the dual prediction (``tacit.codec.spec``, ``tacit.codec.prediction``)
and placed on its stream's grid (``tacit.codec.grid``) when it is pushed; the packet being filled (the
draft) holds every stream's pending samples, oldest first, as far as its 224 code bits reach
(``tacit.codec.grammar``). When it leaves is the send policy's to say (``tacit.codec.policy``). A packet
stays in flight until the modem says whether it arrived; if it was lost, the pending samples are coded
again from the last delivered state, after a LOST that declares the lost ticks.

Version 4 keeps a window of packets in flight (``window``, at most ``MAX_WINDOW``): each is coded on the
state the one before it leaves. When one is lost, its samples and those of every packet after it go back
to the pending samples and are coded again from the state before it (the shore has it, or will): nothing
the vehicle holds is lost, and no LOST is declared; ``resolve`` returns the seqs of the packets after it,
which the caller withdraws from its send queue.

A sample too large for an empty packet (many channels far off, raw values) is sent as several samples of
the same tick, each with some of its channels (the others absent): the stream never stalls, and the
shore gets every channel, in parts (a part in a lost packet is declared lost like any sample).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tacit.arithmetic import Encoder
from tacit.codec.format import CODE_BITS, MAX_WINDOW, base_field, next_id, pack, seq_id
from tacit.codec.grammar import (
    RAW_Q,
    RawValue,
    Token,
    continues,
    placing,
    presence_before,
    write_sample,
    write_token,
)
from tacit.codec.grid import PHASES, Grid, regrid, unregrid
from tacit.codec.models import Coder
from tacit.codec.policy import SendPolicy
from tacit.codec.prediction import Dual
from tacit.codec.spec import MARGIN, StreamSpec
from tacit.codec.state import Chain, Position
from tacit.codec.tokens import END, LOST
from tacit.codec.versions import coding
from tacit.packets import Priority, PriorityPacket


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
    fine: np.ndarray | None = None  # per channel, the fraction of a step q counts (``Dual.fine``)
    state_before: object = None  # the predictor before this sample (for a packet that ends before it)


@dataclass
class _Flight:
    """A packet in flight: its seq, the state it leaves, which streams it carried, and its samples per
    stream (version 4 codes them again if a packet before it is lost)."""

    seq: int
    chain: Chain
    carried: list[bool]
    taken: list[list[_Sample]]
    delivered: bool = False


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
    code_bits: int = 0  # of the payload's 224 code bits, how many the arithmetic code used
    surprises: dict[str, list[int]] = field(
        default_factory=dict
    )  # per stream and channel: values not predicted
    # per stream and sample: its row in the shore's span (a part of the sample before it shares its row)
    rows: list[list[int]] = field(default_factory=list)


def _code_sample(
    coder: Coder, enc: Encoder, cursor: int | None, phase: int, sample: _Sample
) -> tuple[int, int]:
    """The token(s) that place ``sample`` after ``cursor`` (on the grid ``phase``), then the sample;
    returns the new cursor and phase."""
    for token in placing(cursor, phase, sample.index, sample.phase):
        write_token(coder, enc, token)
    write_sample(coder, enc, sample.q)
    return sample.index, sample.phase


def _in_steps(sample: _Sample) -> list[int | None]:
    """A sample's residuals in whole steps (a first value's q counts finer steps), for the policy."""
    fine = np.ones(len(sample.q)) if sample.fine is None else sample.fine
    return [None if v is None else int(v * f) for v, f in zip(sample.q, fine, strict=True)]


def _quantise(
    predictor: Dual, prediction: np.ndarray, values: np.ndarray, step: np.ndarray
) -> list[int | None]:
    """A sample's q's (None: absent), its reconstruction fed back into the predictor as the shore will."""
    with np.errstate(over="ignore", invalid="ignore"):
        residual = (values - prediction) / step
    n, absent, fine = len(values), np.isnan(values), predictor.fine()
    reconstruction, z, raw = np.full(n, np.nan), np.zeros(n), np.zeros(n, dtype=bool)
    out: list[int | None] = []
    for c in range(n):
        if absent[c]:
            out.append(None)
            continue
        correction = predictor.correction(c, z)
        r = (residual[c] - correction) / fine[c]
        q = int(np.round(r)) if abs(r) < RAW_Q - 1 else None
        value = prediction[c] + (correction + q * fine[c]) * step[c] if q is not None else np.nan
        # too far (or beyond floats) for a step count, or a prediction so large that rounding at its
        # magnitude would put the reconstruction off by more than eps: the value itself
        if q is None or not abs(value - values[c]) <= step[c] / (2 * MARGIN):
            out.append(RawValue(values[c]))
            reconstruction[c], raw[c] = values[c], True
        else:
            out.append(q)
            reconstruction[c] = value
            z[c] = correction + q * fine[c]
    predictor.update(reconstruction, z, raw)
    return out


def _rows(section: _Section, taken: list[_Sample]) -> list[int]:
    """For each of ``taken`` (a section's samples), the row of the shore's span it is decoded into: a
    sample that is a part of the one before it in the same packet (``tacit.codec.grammar.continues``:
    the same tick, none of the channels that row holds so far) is merged into that one's row."""
    base, rows = section.base, list[int]()
    before = presence_before(section.base.coder)
    tick, phase = (base.cursor, base.phase) if section.lost is None else (None, base.phase)
    for x in taken:
        present = [v is not None for v in x.q]
        joins = continues(before, present, x.index == tick and x.phase == phase)
        merged = bool(rows) and joins  # the first joins the last packet's last row: a row of its own here
        rows.append(rows[-1] if merged else len(rows) and rows[-1] + 1)
        before = [b or p for b, p in zip(before, present, strict=True)] if joins else present  # the row's
        tick, phase = x.index, x.phase
    return rows


@dataclass
class _Section:
    """One stream's part of the packet being filled."""

    base: Position
    lost: int | None = None  # declare LOST(n) at the section's start (None: nothing was lost)
    count: int = 0  # samples of the stream's pending list in this packet
    closed: bool = False  # a sample did not fit: nothing later of this stream goes in this packet
    open_encoder: Encoder | None = None  # after this section's tokens, before its END
    open_coder: Coder | None = None
    open_cursor: int | None = None
    open_phase: int = 0


class PacketEncoder:
    """The vehicle's side: samples of every stream in, priority packets out, re-based on the last
    delivered packet. Streams are coded in the order given (both ends use the same list)."""

    def __init__(
        self,
        specs: list[StreamSpec],
        max_latency: float = 10.0,
        urgent_threshold: float | None = None,
        max_silence: float | None = 60.0,
        protocol: int = 3,
    ) -> None:
        """When packets leave: ``SendPolicy(max_latency, max_silence, urgent_threshold)`` (``max_silence``
        None: no packet leaves only to confirm predictable samples). ``protocol``: the version the vehicle
        speaks, which says what its payloads code (``tacit.codec.versions``)."""
        if not specs:
            raise ValueError("at least one stream")
        self.specs = list(specs)
        self.coding = coding(protocol)
        self.policy = SendPolicy(max_latency, max_silence, urgent_threshold)
        self.predictors = [Dual(s, self.coding) for s in self.specs]
        self.initial = Chain.initial(self.specs, self.predictors, self.coding)
        self.delivered = self.initial
        self._queues: list[list[_Sample]] = [[] for _ in self.specs]
        self.in_flight: list[_Flight] = []  # oldest first
        self.window = 1  # packets in flight at most (``set_window``)
        self.seq = 0
        self._cursor: list[int | None] = [None] * len(self.specs)  # of the last processed sample
        self._lost: list[int | None] = [None] * len(self.specs)
        self._serial = [0] * len(self.specs)
        self._phase = [0] * len(self.specs)  # the phase of the last processed sample's grid
        # version 4: per stream the last tick delta, the last different one, how many in a row had the last
        self._deltas = [(1, 2, 1)] * len(self.specs)
        self._grids: list[Grid | None] = [None] * len(self.specs)  # the grids new samples go on
        self.last_q: list[int | None] = []  # the last pushed sample's quantised residuals (None: absent)
        self.split = 0  # samples too large for an empty packet, sent as parts (channels) in one tick
        self.refused = 0  # samples that fit no packet even alone from the initial state (never seen)
        self._oversize: int | None = None  # a stream whose first pending sample fits no empty packet
        self._restart_on_resolve = False
        self._start(self.initial)

    def set_window(self, packets: int) -> None:
        """Keep up to ``packets`` in flight (version 4; at least 1, at most ``MAX_WINDOW``): as many as
        the rate the shore polls at carries."""
        if packets > 1 and not self.coding.window:
            raise ValueError(f"protocol {self.coding.version} keeps one packet in flight")
        self.window = min(max(1, packets), MAX_WINDOW)

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
        if self.policy.urgent(_in_steps(sample)):
            sample.urgent = True
        return True

    def _tick(self, stream: int, time: float) -> int:
        """The tick of a sample taken at ``time``, on its stream's grid (``Grid``)."""
        spec, grid = self.specs[stream], self._grids[stream]
        if grid is None:
            grid = self._grids[stream] = Grid.start(spec.period, time)
        elif (phase := grid.follow(spec.period, time)) is not None:
            cursor = self._cursor[stream]
            # not on a sample the new grid would date at a tick after its own (the cursor re-expressed
            # on the new grid may be up to half a tick later than the latest sample)
            if cursor is None or spec.tick(time, phase) >= regrid(cursor, self._phase[stream], phase):
                grid.move(phase)
        index = spec.tick(time, grid.phase)
        return self._stepped(stream, time, index, grid.phase) if self.coding.tolerance else index

    def _stepped(self, stream: int, time: float, index: int, phase: int) -> int:
        """Version 4: the tick the stream's last tick delta, or the last different one, leads to
        (``tacit.codec.models.Timing``: coded for almost nothing; the one before first after a lone
        delta) if it dates ``time`` within the stream's
        time tolerance (``StreamSpec.time_precision``): a sampler whose intervals wander about its period
        (or about a multiple of the tick) then costs an AGAIN, not a new delta each time; else ``index``,
        the nearest tick. A gap longer than the tolerance stays a gap, exact."""
        spec, cursor = self.specs[stream], self._cursor[stream]
        if cursor is None:
            return index
        if phase != self._phase[stream]:
            cursor = regrid(cursor, self._phase[stream], phase)
        last, other, run = self._deltas[stream]
        for delta in (last, other) if run > 1 else (other, last):  # a lone delta: back to the one before
            if abs((cursor + delta + phase / PHASES) * spec.period - time) <= spec.time_precision:
                return cursor + delta
        return index

    def _process(self, stream: int, sample: _Sample, draft: bool = True) -> None:
        spec, predictor = self.specs[stream], self.predictors[stream]
        cursor = self._cursor[stream]
        if cursor is not None and sample.phase != self._phase[stream]:
            cursor = regrid(cursor, self._phase[stream], sample.phase)
        if cursor is not None and sample.index < cursor:
            sample.index = cursor  # out of order by less than a tick's rounding: dated with the latest tick
        if cursor is not None:
            last, other, run = self._deltas[stream]
            delta = sample.index - cursor
            self._deltas[stream] = (last, other, run + 1) if delta == last else (delta, last, 1)
        sample.state_before = predictor.state()
        if cursor is None or sample.index > cursor:
            if cursor is not None:
                predictor.skip(sample.index - cursor - 1)
            prediction = predictor.predict()
        else:
            prediction = predictor.current()
        sample.fine = predictor.fine()
        sample.q = _quantise(predictor, prediction, sample.values, spec.step)
        self._cursor[stream], self._phase[stream] = sample.index, sample.phase
        self._queues[stream].append(sample)
        if draft:
            self._add_to_draft(stream)

    # --- the packet being filled ------------------------------------------------------------------

    def _start(self, base: Chain) -> None:
        self._base = base
        self._full = False
        self._sections = [_Section(p, lost) for p, lost in zip(base.streams, self._lost, strict=True)]
        self._layout(0)

    def _open(self, section: _Section, enc: Encoder) -> None:
        coder = section.base.coder.copy()
        cursor = section.base.cursor
        if section.lost is not None:
            write_token(coder, enc, Token(LOST, n=section.lost))
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
            write_token(coder, enc, Token(END))  # type: ignore[arg-type]
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
        write_token(coder, enc, Token(END))
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

    def _rebase(self, base: Chain) -> None:
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

    def predictable_until(self, now: float) -> float:
        """Up to when every stream was predictable within its eps, as a version-4 check-point tells the
        shore: the time of the oldest sample the shore could not predict and does not hold yet (waiting,
        or in a packet in flight), else ``now``. What is older is delivered, or predictable (from the
        state the shore holds, the initial one included) and waiting for a packet."""
        waiting = [x for queue in self._queues for x in queue]
        waiting += [x for f in self.in_flight for taken in f.taken for x in taken]
        return min((x.time for x in waiting if any(x.q)), default=now)

    def deadline(self) -> float | None:
        """When a packet must leave, by the send policy (None: nothing pending that must leave)."""
        return self.policy.deadline(self._queues)

    def ready(self, now: float) -> bool:
        """A packet should go out now: the window has room, and the send policy says the draft is due."""
        if len(self.in_flight) >= self.window:
            return False
        draft = self._in_draft()
        return bool(draft) and self.policy.due(now, draft, self._full, self._queues)

    def take(self, seq: int | None = None) -> EncodedPacket:
        """The next priority packet (call when ``ready``), numbered ``seq`` (the caller's packet counter;
        by default this encoder's own); it stays in flight until ``resolve``."""
        seq = self.seq if seq is None else seq
        if not self._in_draft():
            raise RuntimeError("nothing to send")
        if base_field(self.coding.window, self._base.id, seq) is None:  # too far back to name
            self._lost = [None] * len(self.specs)
            self._rebase(self.initial)
        draft = self._in_draft()
        enc = self._layout(0)
        bits = enc.finish()
        payload = pack(base_field(self.coding.window, self._base.id, seq) or 0, bits, self.coding.window)
        urgent = any(x.urgent for x in draft)
        main = self._main_stream(urgent)  # before the taken samples leave the queues
        main_first = self._first_index(main)
        positions, counts, serials, rows, surprises, carried_samples = [], {}, [], [], {}, []
        for s, section in enumerate(self._sections):
            taken, rest = self._queues[s][: section.count], self._queues[s][section.count :]
            predictor = rest[0].state_before if rest else self.predictors[s].state()
            coder = section.open_coder.copy()  # type: ignore[union-attr]
            write_token(coder, Encoder(), Token(END))  # the model update END made (both ends make it)
            positions.append(Position(predictor, coder, section.open_cursor, section.open_phase))
            counts[self.specs[s].name] = len(taken)
            surprises[self.specs[s].name] = [
                sum(1 for x in taken if x.q[c]) for c in range(len(self.specs[s].channels))
            ]
            serials.append([x.serial for x in taken])
            rows.append(_rows(section, taken))
            carried_samples.append(taken)
            self._queues[s] = rest
        chain = Chain(seq_id(seq) if self.coding.window else next_id(self._base.id), positions)
        packet = PriorityPacket(
            seq % 256,
            Priority.TIME_SENSITIVE if urgent else Priority.ROUTINE,
            self.specs[main].stream,
            payload,
            version=self.coding.version,
        )
        encoded = EncodedPacket(
            packet,
            main_first,
            len(draft),
            sum(sec.lost or 0 for sec in self._sections),
            [x.time for x in draft],
            [x.time for x in draft if any(x.q)],
            sum(1 for x in draft for v in x.q if v),
            counts,
            serials,
            len(bits),
            surprises,
            rows,
        )
        carried = [sec.count > 0 or sec.lost is not None for sec in self._sections]
        self.in_flight.append(_Flight(seq % 256, chain, carried, carried_samples))
        self.seq = seq + 1
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

    def _first_index(self, stream: int) -> int:
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

    def resolve(self, delivered: bool, seq: int | None = None) -> list[int]:
        """The packet in flight numbered ``seq`` (by default the oldest) was delivered (ACK) or lost for
        good; re-base if lost. Returns the seqs of the packets after it that version 4 codes again (the
        caller withdraws them); a seq not in flight (withdrawn, or forgotten by ``restart``) is ignored."""
        at = 0 if seq is None else next((i for i, f in enumerate(self.in_flight) if f.seq == seq % 256), -1)
        if not self.in_flight or at < 0:
            return []
        if self._restart_on_resolve:
            self.in_flight.clear()
            self._restart_on_resolve = False
            self.restart()
            return []
        flight = self.in_flight[at]
        if delivered:
            flight.delivered = True
            while self.in_flight and self.in_flight[0].delivered:
                self.delivered = self.in_flight.pop(0).chain
            return []
        base = self.in_flight[at - 1].chain if at else self.delivered
        dropped, self.in_flight = self.in_flight[at:], self.in_flight[:at]
        if self.coding.window:  # every sample of the lost packet and those after it is coded again
            for s in range(len(self.specs)):
                self._queues[s] = [x for f in dropped for x in f.taken[s]] + self._queues[s]
        else:  # the lost packet's samples are gone: the next packet says up to which tick, per stream (a
            # stream that had not started on the shore starts afresh, its lost samples before its START)
            self._declare_lost(base, flight)
        self._rebase(base)
        self._settle()
        return [f.seq for f in dropped[1:]]

    def _declare_lost(self, base: Chain, flight: _Flight) -> None:
        for s, position in enumerate(base.streams):
            end = flight.chain.streams[s].cursor
            if flight.carried[s] and position.cursor is not None and end is not None:
                # the lost packet's end on the delivered packet's grid (it may have moved the grid)
                end = unregrid(end, position.phase, flight.chain.streams[s].phase)
                self._lost[s] = max(0, end - position.cursor)
            else:
                self._lost[s] = None

    def restart(self) -> None:
        """Start over: the next packet continues from the initial state (base 0), whatever was delivered.
        For a shore that lost its decoder state (``UnknownBase``): the samples still pending are re-coded
        from the initial state (each stream starts again with START). Version 3: a packet in flight is
        forgotten when it resolves (delivered or not, the shore that asked cannot continue from it).
        Version 4: the packets in flight are forgotten now and their samples coded again."""
        self.delivered = self.initial
        self._lost = [None] * len(self.specs)
        if self.in_flight and not self.coding.window:
            self._restart_on_resolve = True
            return
        for s in range(len(self.specs)):
            self._queues[s] = [x for f in self.in_flight for x in f.taken[s]] + self._queues[s]
        self.in_flight = []
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
                    parts.append(
                        _Sample(
                            sample.time,
                            sample.index,
                            values,
                            sample.urgent,
                            sample.serial,
                            sample.flagged,
                            sample.phase,
                        )
                    )
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

    def __init__(
        self,
        spec: StreamSpec,
        max_latency: float = 10.0,
        urgent_threshold: float | None = None,
        max_silence: float | None = 60.0,
        protocol: int = 3,
    ) -> None:
        super().__init__([spec], max_latency, urgent_threshold, max_silence, protocol)
        self.spec = spec

    def push(self, time: float, values: np.ndarray | list[float], urgent: bool = False) -> bool:  # type: ignore[override]
        return super().push(0, time, values, urgent)
