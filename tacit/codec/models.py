"""The adaptive models both ends keep per stream, and the contexts that choose among them.

Entropy coding (``tacit.arithmetic``) with adaptive models, so what is regular becomes almost free. The
token is coded with a model per stream and previous token. A sample's "all channels present" symbol has
a model per stream and previous answer; a presence symbol, a model per channel and previous presence;
q, a model per channel and context min(|previous q|, 2). The unary part of a count has a model per
position. On a clean grid a tick costs hundredths of a bit beyond its q's; a 5 % dropout costs about
0.3 bit per missing tick.

Payload version 4 (``Timing``) chooses the token model after a sample also by how long a run of samples
came the same tick delta apart (a periodic pattern's runs against the run before), and codes JUMP's count
as the last one, the one before, or a new one: an irregular sampler whose interval is piecewise regular
(a glider's depth-binned schedule, gaps between dives, a CTD reporting every second cycle and now and
then the next) then costs about what a regular one does.
"""

from __future__ import annotations

from dataclasses import dataclass

from tacit.arithmetic import AdaptiveModel
from tacit.codec.tokens import END, JUMP, SAME, STEP
from tacit.codec.versions import Coding

PRIOR = [1, 1, 1, 2, 4, 8, 24, 8, 4, 2, 1, 1, 1, 1, 1, 1]  # q = -6..6, ESC_NEG, ESC_POS, RAW
TOKEN_PRIOR = [2, 24, 1, 2, 1, 1, 1]  # END, STEP, SAME, JUMP, LOST, START, PHASE
Q_CONTEXTS = 3
Q_INCREMENT = 24
COUNT_MODELS = 24
RUNS = 6  # version 4's token contexts after a sample: runs of 1, 2-3, 4-7, .., 32 and more (``_runs``)
NAMED = 2  # ... JUMP's count: the last (0), the one before (1), or named (2: an Elias-gamma count follows)
JUMP_PRIOR = [8, 2, 2]


def _binary() -> AdaptiveModel:
    return AdaptiveModel([1, 8])  # symbol 1 (the usual answer) starts likely


def _q_context(previous: int) -> int:
    """The q model's context: min(|the channel's previous q|, 2). (Adding whether an earlier channel of
    the same sample was a surprise was tried: on the ArduSub IMU its learning cost outweighs it.)"""
    return min(abs(previous), 2)


def _again(previous: int) -> list[int]:
    """Version 4's token prior after ``previous``: a sample placed as the one before was, likely."""
    if previous not in (SAME, STEP, JUMP):
        return list(TOKEN_PRIOR)
    prior = [1 if f == TOKEN_PRIOR[STEP] else f for f in TOKEN_PRIOR]
    prior[previous] = TOKEN_PRIOR[STEP]
    return prior


def _runs(run: int, last_run: int) -> int:
    """A run's context: near the length of the same delta's run before (one shorter, as long, longer:
    a periodic pattern's runs), else its length's octave (1, 2-3, 4-7, .., up to ``RUNS``)."""
    if last_run and run >= last_run - 1:
        return RUNS + min(run - last_run + 1, 2)
    return min(run.bit_length(), RUNS) - 1


@dataclass
class Timing:
    """Version 4's models of where samples go: the token model per previous token and, after a sample,
    per context of its run (``_runs``); JUMP's count against the last two (``NAMED``). State: the
    last tick delta, how many samples in a row had it (``run``), its run before (``last_run``, 0 if
    another delta was not between), the run of the delta before it (``other``, ``other_run``), the
    last two JUMP counts and the class the last one was coded as."""

    tokens: list[AdaptiveModel]
    counts: list[AdaptiveModel]
    last: int = 1
    run: int = 1
    last_run: int = 0
    other: int = 1
    other_run: int = 0
    jumps: tuple[int, int] = (0, 1)
    jumped: int = NAMED

    @classmethod
    def new(cls) -> Timing:
        tokens = [
            AdaptiveModel(_again(previous)) for previous in range(len(TOKEN_PRIOR)) for _ in range(RUNS + 3)
        ]
        return cls(tokens, [AdaptiveModel(list(JUMP_PRIOR)) for _ in range(NAMED + 1)])

    def copy(self) -> Timing:
        return Timing(
            [m.copy() for m in self.tokens],
            [m.copy() for m in self.counts],
            self.last,
            self.run,
            self.last_run,
            self.other,
            self.other_run,
            self.jumps,
            self.jumped,
        )

    def token_model(self, previous: int) -> AdaptiveModel:
        placed = previous in (SAME, STEP, JUMP)
        return self.tokens[previous * (RUNS + 3) + (_runs(self.run, self.last_run) if placed else 0)]

    def count_model(self) -> AdaptiveModel:
        return self.counts[self.jumped]

    def placed(self, delta: int) -> None:
        """After a sample placed ``delta`` ticks on."""
        if delta == self.last:
            self.run += 1
            return
        last_run = self.other_run if delta == self.other else 0
        self.other, self.other_run, self.last, self.run, self.last_run = (
            self.last,
            self.run,
            delta,
            1,
            last_run,
        )

    def jumped_by(self, n: int) -> int:
        """JUMP's count n as its class: the last count (0), the one before (1), or NAMED (n follows)."""
        return self.jumps.index(n) if n in self.jumps else NAMED

    def jump(self, kind: int, n: int) -> None:
        self.jumped = kind
        if n != self.jumps[0]:
            self.jumps = (n, self.jumps[0])

    def dump(self) -> list:
        models = [[m.freqs, m.increment, m.limit] for m in (*self.tokens, *self.counts)]
        state = [self.last, self.run, self.last_run, self.other, self.other_run, *self.jumps, self.jumped]
        return [models, state]

    @classmethod
    def load(cls, data: list) -> Timing:
        models, state = data
        loaded = [AdaptiveModel(list(map(int, f)), int(i), int(lim)) for f, i, lim in models]
        tokens, counts = loaded[: -NAMED - 1], loaded[-NAMED - 1 :]
        last, run, last_run, other, other_run, jump, jump_before, jumped = (int(x) for x in state)
        if len(tokens) != len(TOKEN_PRIOR) * (RUNS + 3) or any(
            len(m.freqs) != len(TOKEN_PRIOR) for m in tokens
        ):
            raise ValueError("timing shape")
        if any(len(m.freqs) != len(JUMP_PRIOR) for m in counts) or not 0 <= jumped <= NAMED or run < 1:
            raise ValueError("timing state")
        return cls(tokens, counts, last, run, last_run, other, other_run, (jump, jump_before), jumped)


@dataclass
class Coder:
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
    timing: Timing | None = None  # version 4: tick deltas coded against the last ones

    @classmethod
    def new(cls, channels: int, coding: Coding) -> Coder:
        return cls(
            [[AdaptiveModel(list(PRIOR), Q_INCREMENT) for _ in range(Q_CONTEXTS)] for _ in range(channels)],
            [AdaptiveModel(list(TOKEN_PRIOR)) for _ in TOKEN_PRIOR],
            [_binary() for _ in range(2)],
            [[_binary() for _ in range(2)] for _ in range(channels)],
            [AdaptiveModel([1, 1]) for _ in range(COUNT_MODELS)],
            [0] * channels,
            [1] * channels,
            timing=Timing.new() if coding.timing else None,
        )

    def copy(self) -> Coder:
        return Coder(
            [[m.copy() for m in row] for row in self.q],
            [m.copy() for m in self.tokens],
            [m.copy() for m in self.all_present],
            [[m.copy() for m in row] for row in self.present],
            [m.copy() for m in self.counts],
            list(self.previous_q),
            list(self.previous_present),
            self.previous_all,
            self.previous_token,
            None if self.timing is None else self.timing.copy(),
        )

    def token_model(self) -> AdaptiveModel:
        if self.timing is not None:
            return self.timing.token_model(self.previous_token)
        return self.tokens[self.previous_token]

    def count_model(self, position: int) -> AdaptiveModel:
        return self.counts[min(position, len(self.counts) - 1)]

    def all_model(self) -> AdaptiveModel:
        return self.all_present[self.previous_all]

    def present_model(self, channel: int) -> AdaptiveModel:
        return self.present[channel][self.previous_present[channel]]

    def q_model(self, channel: int) -> AdaptiveModel:
        return self.q[channel][_q_context(self.previous_q[channel])]

    def dump(self) -> list:
        """As JSON-able data (``tacit.codec.state``)."""
        models = [
            [[m.freqs, m.increment, m.limit] for m in row]
            for row in (*self.q, self.tokens, self.all_present, *self.present, self.counts)
        ]
        dumped = [models, self.previous_q, self.previous_present, self.previous_all, self.previous_token]
        return dumped if self.timing is None else [*dumped, self.timing.dump()]

    @classmethod
    def load(cls, data: list) -> Coder:
        """What ``dump`` returned; ValueError if it has the wrong shape."""
        models, previous_q, previous_present, previous_all, previous_token, *timing = data
        if len(timing) > 1:
            raise ValueError("coder shape")
        rows = [[AdaptiveModel(list(map(int, f)), int(i), int(lim)) for f, i, lim in row] for row in models]
        channels = len(previous_q)
        q, rest = rows[:channels], rows[channels:]
        tokens, all_present, present, counts = rest[0], rest[1], rest[2 : 2 + channels], rest[2 + channels]
        if len(rows) != 2 * channels + 3 or len(previous_present) != channels:
            raise ValueError("coder shape")
        return cls(
            q,
            tokens,
            all_present,
            present,
            counts,
            [int(v) for v in previous_q],
            [int(v) for v in previous_present],
            int(previous_all),
            int(previous_token),
            Timing.load(timing[0]) if timing else None,
        )
