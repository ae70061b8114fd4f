"""The adaptive models both ends keep per stream, and the contexts that choose among them.

Entropy coding (``tacit.arithmetic``) with adaptive models, so what is regular becomes almost free. The
token is coded with a model per stream and previous token. A sample's "all channels present" symbol has
a model per stream and previous answer; a presence symbol, a model per channel and previous presence;
q, a model per channel and context min(|previous q|, 2). The unary part of a count has a model per
position. On a clean grid a tick costs hundredths of a bit beyond its q's; a 5 % dropout costs about
0.3 bit per missing tick.
"""

from __future__ import annotations

from dataclasses import dataclass

from tacit.arithmetic import AdaptiveModel
from tacit.codec.tokens import END

PRIOR = [1, 1, 1, 2, 4, 8, 24, 8, 4, 2, 1, 1, 1, 1, 1, 1]  # q = -6..6, ESC_NEG, ESC_POS, RAW
TOKEN_PRIOR = [2, 24, 1, 2, 1, 1, 1]  # END, STEP, SAME, JUMP, LOST, START, PHASE
Q_CONTEXTS = 3
Q_INCREMENT = 24
COUNT_MODELS = 24


def _binary() -> AdaptiveModel:
    return AdaptiveModel([1, 8])  # symbol 1 (the usual answer) starts likely


def _q_context(previous: int) -> int:
    """The q model's context: min(|the channel's previous q|, 2). (Adding whether an earlier channel of
    the same sample was a surprise was tried: on the ArduSub IMU its learning cost outweighs it.)"""
    return min(abs(previous), 2)


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

    @classmethod
    def new(cls, channels: int) -> Coder:
        return cls(
            [[AdaptiveModel(list(PRIOR), Q_INCREMENT) for _ in range(Q_CONTEXTS)] for _ in range(channels)],
            [AdaptiveModel(list(TOKEN_PRIOR)) for _ in TOKEN_PRIOR],
            [_binary() for _ in range(2)],
            [[_binary() for _ in range(2)] for _ in range(channels)],
            [AdaptiveModel([1, 1]) for _ in range(COUNT_MODELS)],
            [0] * channels,
            [1] * channels,
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
        )

    def token_model(self) -> AdaptiveModel:
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
        return [models, self.previous_q, self.previous_present, self.previous_all, self.previous_token]

    @classmethod
    def load(cls, data: list) -> Coder:
        """What ``dump`` returned; ValueError if it has the wrong shape."""
        models, previous_q, previous_present, previous_all, previous_token = data
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
        )
