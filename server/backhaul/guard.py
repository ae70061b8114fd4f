"""What the center takes from the broker: every message checked before it reaches the store or the
gateways' table, and a message that fails is a logged, counted refusal, never an exception.

* A frame must decode (``subjects.FrameMessage``), come on its own gateway's subject with an id of that
  gateway (the broker's permissions keep a gateway to its own subject; the id check catches a message
  passed off inside it), on its source address's partition (the process that owns the partition decodes
  the vehicle), and carry a finite time and a statistics object.
* An event must decode and come on its own gateway's subject; a heartbeat's detail must be a
  ``subjects.GatewayState`` (its place, outbox and outage numbers).
* A gateway announcing itself twice: heartbeats under one name from two outbox incarnations (two
  processes sharing a name or a credentials file, or a gateway restarted on a new outbox while the old
  one still runs). The first keeps the name until it has been silent for ``STALE_BEATS`` heartbeats;
  the other's heartbeats are refused and logged. Its frames are not: their ids differ (the incarnation
  is part of them), so they are stored, none lost.
* A stale heartbeat (sent ``STALE_BEATS`` heartbeats ago or more, by its own time: a backlog a center
  consumes after it was away) is passed on but says nothing of now: it neither makes its gateway up nor
  holds its name against another incarnation.
* A frame stamped more than ``FUTURE`` s ahead of the center's clock is refused (``future``): a
  gateway's clock is NTP/GPS-disciplined, and a frame from the future would make a vehicle heard then.
  A late frame is not: after an outage a gateway's backlog is as old as the stream keeps (7 days).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass

from server.backhaul import subjects
from server.backhaul.subjects import EventMessage, FrameMessage, GatewayState, PayloadError

log = logging.getLogger("tacit.backhaul.guard")

STALE_BEATS = 3  # heartbeats missed before another incarnation may take a gateway's name
MAX_ID = 128  # characters: the store's column
FUTURE = 120.0  # s a frame may be stamped ahead of the center's clock (clocks apart, a slow center)


@dataclass
class Announced:
    """A gateway's heartbeats: its outbox's incarnation, since when it beats without a gap, the last."""

    incarnation: str
    since: float
    last: float


class Guard:
    def __init__(self, heartbeat: float = subjects.HEARTBEAT) -> None:
        self.heartbeat = heartbeat
        self.refused: Counter[str] = Counter()  # by reason: malformed, foreign, partition, future, twice
        self.announced: dict[str, Announced] = {}  # by gateway name

    def frame(self, subject: str, data: bytes, now: float) -> FrameMessage | None:
        """The frame in a message from ``subject`` consumed at ``now``, or None (refused, logged)."""
        try:
            frame = FrameMessage.decode(data)
            subjects.gateway_name(frame.gateway)
        except (PayloadError, ValueError) as exc:
            self._refuse("malformed", f"malformed frame message on {subject} dropped: {exc}")
            return None
        if not subject.startswith(subjects.frames(frame.gateway).removesuffix("*")) or not _own(
            frame.gateway, frame.id
        ):
            self._refuse(
                "foreign", f"frame {frame.id[:MAX_ID]!r} of gateway {frame.gateway!r} on {subject} dropped"
            )
            return None
        if subject != subjects.frames(frame.gateway, subjects.partition(frame.src)):
            self._refuse(
                "partition",
                f"frame {frame.id} from address {frame.src} on {subject} dropped: not its partition's subject "
                f"({subjects.PARTITIONS} partitions: a gateway of another wire)",
            )
            return None
        if not math.isfinite(frame.at) or not isinstance(frame.stats, dict | None):
            self._refuse("malformed", f"frame {frame.id} on {subject} dropped: bad time or statistics")
            return None
        if frame.at > now + FUTURE:
            self._refuse(
                "future",
                f"frame {frame.id} from address {frame.src} on {subject} dropped: stamped {frame.at - now:.0f} s "
                f"ahead of the center's clock (more than {FUTURE:.0f} s)",
            )
            return None
        return frame

    def event(self, subject: str, data: bytes, now: float) -> EventMessage | None:
        """The event in a message from ``subject``, or None (refused, logged)."""
        try:
            event = EventMessage.decode(data)
        except PayloadError as exc:
            self._refuse("malformed", f"malformed event on {subject} dropped: {exc}")
            return None
        if subject != subjects.events(event.gateway):
            self._refuse("foreign", f"event of gateway {event.gateway!r} on {subject} dropped")
            return None
        if event.kind != "heartbeat":
            return event
        try:
            GatewayState.of(event.detail)
        except PayloadError as exc:
            self._refuse("malformed", f"heartbeat {event.id!r} on {subject} dropped: {exc}")
            return None
        return event if self.stale(event, now) or self._one_incarnation(event, now) else None

    def stale(self, event: EventMessage, now: float) -> bool:
        """The event was sent ``STALE_BEATS`` heartbeats ago or more (its gateway's clock)."""
        return now - event.at >= STALE_BEATS * self.heartbeat

    def up(self, gateway: str, now: float) -> bool:
        """Its last heartbeat came less than ``STALE_BEATS`` heartbeats ago."""
        held = self.announced.get(gateway)
        return held is not None and now - held.last < STALE_BEATS * self.heartbeat

    def _one_incarnation(self, event: EventMessage, now: float) -> bool:
        incarnation = str(event.detail.get("incarnation", ""))
        held = self.announced.get(event.gateway)
        up = self.up(event.gateway, now)
        if held is not None and up and held.incarnation != incarnation:
            self._refuse(
                "twice",
                f"gateway {event.gateway!r} announced twice (outboxes {held.incarnation!r} and "
                f"{incarnation!r}): two gateways share a name or credentials; {held.incarnation!r} keeps it",
            )
            return False
        since = held.since if held is not None and up else now
        self.announced[event.gateway] = Announced(incarnation, since, now)
        return True

    def _refuse(self, reason: str, message: str) -> None:
        self.refused[reason] += 1
        log.error("backhaul: %s", message)


def _own(gateway: str, message_id: str) -> bool:
    return message_id.startswith(f"{gateway}-") and len(message_id) <= MAX_ID
