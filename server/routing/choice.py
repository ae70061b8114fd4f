"""The assignment rule, pure: which gateway a vehicle should be on, from how well each gateway heard it.

A gateway's score for a vehicle (dB) is the mean SNR of the vehicle's frames it heard in the window plus
``10 log10`` of the share of the vehicle's frames it heard (half of them heard costs 3 dB): a gateway
that hears loudly but seldom is not preferred to one that hears every frame a little less loudly.
Hysteresis: the vehicle moves only to a gateway better by ``margin`` dB, and not before it has been
``dwell`` s on its gateway (also when its gateway heard none of its frames in the window: a few lost
frames must not move it); it moves at once if its gateway is silent (no heartbeat) or faulty
(``Routing.audit``). A pin is kept whatever the scores.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Quality:
    """How one gateway heard one vehicle in the window."""

    heard: int  # frames
    snr: float  # mean SNR in (dB) of those frames
    share: float  # of the vehicle's frames (any gateway's) in the window

    @property
    def score(self) -> float:
        return self.snr + 10.0 * math.log10(self.share) if self.share > 0 else -math.inf


@dataclass(frozen=True)
class Current:
    gateway: str
    since: float
    pinned: bool = False


@dataclass(frozen=True)
class Decision:
    gateway: str | None
    reason: str
    moved: bool = False


def choose(
    current: Current | None,
    heard: dict[str, Quality],
    alive: set[str],
    now: float,
    margin: float,
    dwell: float,
) -> Decision:
    """The vehicle's gateway now (``heard``: by gateway, the ones that heard it in the window)."""
    if current is not None and current.pinned:
        return Decision(current.gateway, "pinned by an operator")
    scores = {g: q.score for g, q in heard.items() if g in alive and q.heard}
    if not scores:
        return Decision(current.gateway if current else None, "no live gateway heard it in the window")
    best = max(scores, key=lambda g: (scores[g], g))
    if current is None:
        return Decision(best, f"{best} heard it best ({scores[best]:.1f} dB)", moved=True)
    if current.gateway not in alive:
        return Decision(best, f"{current.gateway} is silent or faulty; {best} heard it best", moved=True)
    if best == current.gateway:
        return Decision(best, f"{best} hears it best ({scores[best]:.1f} dB)")
    if current.gateway not in scores:  # lost frames or out of its reach: the dwell tells them apart
        if now - current.since < dwell:
            return Decision(current.gateway, f"{current.gateway} heard none of its frames; {best} did: "
                            f"moving after the {dwell:.0f} s dwell")  # fmt: skip
        return Decision(best, f"{current.gateway} heard none of its frames; {best} did", moved=True)
    gain = scores[best] - scores[current.gateway]
    if gain < margin:
        return Decision(current.gateway, f"{best} is {gain:.1f} dB better, under the {margin:.1f} dB margin")
    if now - current.since < dwell:
        return Decision(
            current.gateway, f"{best} is {gain:.1f} dB better; moving after the {dwell:.0f} s dwell"
        )
    return Decision(best, f"{best} heard it {gain:.1f} dB better than {current.gateway}", moved=True)
