"""Where a profiled run's time goes: cProfile's figures summed by what the time was spent on (decoding,
prediction, SQL, JSON, HMAC, ...), per frame, then the functions with the most own time.

A function of the project or of a library named in ``CATEGORIES`` counts for its category. Anything else
(numpy, the standard library, built-ins) counts for whoever called it, in proportion to the time each
caller spent in it: numpy's time under the predictors is prediction, ``sum`` under the arithmetic coder is
decoding. cProfile slows what it measures (Python-level calls the most), so a bench prints its figure
from a run without it.
"""

from __future__ import annotations

import cProfile
import io
import pstats
from collections import defaultdict
from typing import Any

# (category, substrings of "file:function"), the first that matches wins
CATEGORIES: list[tuple[str, tuple[str, ...]]] = [
    ("Kalman filter (filterpy)", ("/filterpy/",)),
    ("SQL (SQLAlchemy, driver)", ("/sqlalchemy/", "/sqlmodel/", "sqlite3", "/psycopg", "/server/core/db.py",
                                  "/repository.py")),
    ("JSON, zlib, base64", ("/json/", "_json", "zlib", "base64", "binascii")),
    ("HMAC, SHA-256", ("/hmac.py", "hashlib", "/tacit/auth.py")),
    ("pydantic", ("/pydantic",)),
    ("events (publish)", ("/server/core/events.py", "/queue.py")),
    ("arithmetic decoding (tacit/arithmetic, codec grammar and models)",
     ("/tacit/arithmetic.py", "/tacit/codec/grammar.py", "/tacit/codec/models.py")),
    ("prediction (codec/prediction, tacit/predict)", ("/tacit/codec/prediction.py", "/tacit/predict.py")),
    ("codec, other (decoder, states, grid)", ("/tacit/codec/",)),
    ("packets, link (tacit/)", ("/tacit/",)),
    ("ingest pipeline (server/link)", ("/server/link/",)),
    ("server, other", ("/server/",)),
]  # fmt: skip
OTHER = "other (the bench, logging, the interpreter)"

Func = tuple[str, int, str]


def _category(func: Func) -> str | None:
    where = f"{func[0]}:{func[2]}"
    return next((name for name, marks in CATEGORIES if any(m in where for m in marks)), None)


def _shares(
    stats: dict[Func, Any], func: Func, memo: dict[Func, dict[str, float]], active: set[Func]
) -> dict[str, float]:
    """The categories ``func``'s own time counts for, as fractions (its callers' for an unnamed one)."""
    if func in memo:
        return memo[func]
    named = _category(func)
    callers = {c: t for c, t in stats[func][4].items() if c in stats}
    total = sum(t[3] for t in callers.values())
    if named is not None or func in active or total <= 0:
        return {named or OTHER: 1.0}
    active.add(func)
    out: dict[str, float] = defaultdict(float)
    for caller, figures in callers.items():
        for category, share in _shares(stats, caller, memo, active).items():
            out[category] += share * figures[3] / total
    active.discard(func)
    memo[func] = dict(out)
    return memo[func]


def by_category(profile: cProfile.Profile) -> dict[str, float]:
    """Seconds of own time per category, largest first."""
    stats: dict[Func, Any] = pstats.Stats(profile).stats  # type: ignore[attr-defined]
    seconds: dict[str, float] = defaultdict(float)
    memo: dict[Func, dict[str, float]] = {}
    for func, figures in stats.items():
        for category, share in _shares(stats, func, memo, set()).items():
            seconds[category] += share * figures[2]
    return dict(sorted(seconds.items(), key=lambda item: -item[1]))


def summary(profile: cProfile.Profile, frames: int, top: int = 15) -> str:
    """The categories' time per frame and share, then the ``top`` functions by own time."""
    seconds = by_category(profile)
    total = sum(seconds.values())
    lines = [f"{'where the time goes (cProfile)':<66} {'s':>7} {'us/frame':>9} {'share':>6}"]
    lines += [
        f"{name:<66} {s:>7.2f} {s / frames * 1e6:>9.0f} {s / total:>6.1%}" for name, s in seconds.items()
    ]
    lines.append(f"{'total':<66} {total:>7.2f} {total / frames * 1e6:>9.0f}")
    out = io.StringIO()
    pstats.Stats(profile, stream=out).sort_stats("tottime").print_stats(top)
    body = out.getvalue()
    return "\n".join(lines) + "\n\n" + body[body.find("   ncalls") :]
