"""Bearer tokens: operators (write) and observers (read), each a named ``Actor``. Settings' tokens are
compared in constant time, never logged; the rest live in the operators table (``server.operators``),
whose ``Operators.actor`` is the one rule. The API's dependencies (``server.api.deps``) and the map's
panel both sign in through a ``Throttle`` that asks it."""

from __future__ import annotations

import enum
import hmac
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from server.core.config import Settings
from server.core.errors import TooMany, Unauthorized

MAX_CLIENTS = 4096  # clients with recent failures remembered: beyond it, those with none in the window go


class Role(enum.StrEnum):
    WRITE = "write"  # an operator: commands, missions, vehicles
    READ = "read"  # an observer: watches


@dataclass(frozen=True)
class Actor:
    """Who sends a request: a named operator (write) or observer (read), and when its token expires
    (UNIX s; None: never, as the settings' tokens)."""

    name: str
    role: Role
    expires_at: float | None = None


Lookup = Callable[[str], Actor | None]  # a token's actor; raises ``Unauthorized`` if expired or revoked


def _match(token: str, candidates: list[str]) -> int | None:
    """The index of ``token`` among ``candidates``; no early exit: the time does not depend on which."""
    found = None
    for index, candidate in enumerate(candidates):
        if hmac.compare_digest(token.encode(), candidate.encode()):
            found = index
    return found


def configured(settings: Settings, token: str) -> Actor | None:
    """The settings' tokens, which bootstrap a deployment: "config-operator-N" (write) and
    "config-observer-N" (read), N counted from 1 in the order configured; None for any other token."""
    for candidates, name, kind in (
        (settings.write_tokens, "config-operator", Role.WRITE),
        (settings.read_tokens, "config-observer", Role.READ),
    ):
        index = _match(token, candidates)
        if index is not None:
            return Actor(f"{name}-{index + 1}", kind)
    return None


def open_reads(settings: Settings) -> bool:
    """Reads are open when no tokens are configured at all (a bench setup)."""
    return not settings.write_tokens and not settings.read_tokens


class Throttle:
    """Wrong tokens, counted per client (an address): after ``sign_in_failures`` of them within
    ``sign_in_window`` seconds, that client's further attempts are refused with ``TooMany`` (HTTP 429 with
    Retry-After) until the oldest is that old, a right token's too, so guessing cannot go on. Others
    are not affected. Safe from any thread (routes run in a thread pool, the map in its own)."""

    def __init__(
        self, settings: Settings, lookup: Lookup, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.settings = settings
        self.lookup = lookup
        self.clock = clock
        self._failures: dict[str, deque[float]] = {}
        self._lock = threading.Lock()

    def actor(self, token: str, client: str) -> Actor | None:
        """``lookup`` of ``token``, unless ``client`` failed too often lately (``TooMany``). An unknown,
        expired or revoked token counts as a failure."""
        now = self.clock()
        with self._lock:
            failures = self._recent(client, now)
            if len(failures) >= self.settings.sign_in_failures:
                wait = failures[0] + self.settings.sign_in_window - now
                raise TooMany(f"too many wrong tokens from {client}: try again in {wait:.0f} s", wait)
        try:
            found = self.lookup(token)
        except Unauthorized:
            self._fail(client, now)
            raise
        if found is None:
            self._fail(client, now)
        return found

    def still(self, token: str) -> Actor:
        """Who holds ``token`` now, asked again of a sign-in that lasts (the map's panel at each send, the
        event stream at each event): ``Unauthorized`` saying why once it has expired or been revoked.
        Not counted as a failure: the client signed in with it."""
        found = self.lookup(token)
        if found is None:
            raise Unauthorized("this token is no longer accepted here")
        return found

    def _fail(self, client: str, now: float) -> None:
        with self._lock:
            self._recent(client, now).append(now)
            if len(self._failures) > MAX_CLIENTS:
                self._failures = {c: f for c, f in self._failures.items() if self._recent(c, now)}

    def _recent(self, client: str, now: float) -> deque[float]:
        """The client's failures within the window (older ones forgotten)."""
        failures = self._failures.setdefault(client, deque())
        while failures and failures[0] <= now - self.settings.sign_in_window:
            failures.popleft()
        return failures
