"""When a packet leaves: the send policy, kept apart from what the packet says (as goby3 keeps its queue's
priority and time-to-live apart from DCCL's encoding).

An unpredictable sample (some q != 0) leaves within ``max_latency`` seconds; a predictable one (the
paper's silence) only needs confirming within ``max_silence``, so a quiet stream does not pay a packet
per latency period. A sample the caller flags (an event), or with a surprise of ``urgent_threshold``
steps or more, is time-sensitive and makes its packet leave at once. A full packet leaves at once too.

``max_silence=None`` confirms nothing on its own: predictable samples ride in the next packet that leaves
for a surprise, an urgent sample or a full draft. That is send-on-delta's guarantee (its shore is never
told that a quiet value is still quiet), the one to compare the two at: every packet a silence bound
sends is a confirmation send-on-delta never makes.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Protocol


class Pending(Protocol):
    """A sample waiting for a packet, as the policy sees it."""

    time: float
    urgent: bool
    q: list[int | None]  # its quantised residuals (None: absent; any non-zero: a surprise)


class SendPolicy:
    """The encoder's "when": how long a sample may wait, and which samples cannot."""

    def __init__(
        self,
        max_latency: float = 10.0,
        max_silence: float | None = 60.0,
        urgent_threshold: float | None = None,
    ) -> None:
        self.max_latency = max_latency
        self.max_silence = None if max_silence is None else max(max_silence, max_latency)
        self.urgent_threshold = urgent_threshold

    def urgent(self, q: list[int | None]) -> bool:
        """A sample with these residuals is time-sensitive by its size."""
        threshold = self.urgent_threshold
        return threshold is not None and any(v is not None and abs(v) >= threshold for v in q)

    def deadline(self, queues: Sequence[Sequence[Pending]]) -> float | None:
        """When a packet must leave: the oldest unpredictable sample's latency bound, or the oldest
        predictable one's silence bound, whichever comes first (None: nothing pending that has a bound).
        ``queues``: each stream's pending samples, oldest first."""
        bounds = [x.time + self.max_latency for p in queues for x in p if any(x.q)]
        if self.max_silence is not None:
            bounds += [p[0].time + self.max_silence for p in queues if p]
        return min(bounds, default=None)

    def due(
        self, now: float, draft: Iterable[Pending], full: bool, queues: Sequence[Sequence[Pending]]
    ) -> bool:
        """The packet being filled with ``draft`` (not empty) should leave now: it is full, holds an urgent
        sample, or the deadline of what is pending has come."""
        deadline = self.deadline(queues)
        return full or any(x.urgent for x in draft) or (deadline is not None and now >= deadline)
