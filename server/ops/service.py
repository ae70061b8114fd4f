"""The center's operations: its metrics, read from the backhaul's consumer, its guard and the ingest
pipeline (nothing is counted twice: each part keeps its own counters, this reads them), and the
retention of the relayed frames' records."""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import Counter
from collections.abc import Callable, Mapping
from typing import Any, Protocol

from sqlalchemy import Engine

from server.backhaul.guard import Guard
from server.core.db import writing
from server.ops import repository
from server.ops.exposition import Family, render
from tacit.modem import LinkState

log = logging.getLogger("tacit.ops")

DAY = 86400.0


class Retention:
    """Relayed frames' records (``relayedframe``: which gateway heard a frame, its SNR, its message id)
    older than ``days`` are deleted; the frames, packets and samples they point at are the campaign's
    record and stay. ``days`` 0: kept for ever."""

    def __init__(self, db: Engine, days: float) -> None:
        self.db = db
        self.days = days
        self.pruned = 0  # records deleted since start

    def prune(self, now: float | None = None) -> int:
        """Delete the records older than ``days``; how many."""
        if not self.days:
            return 0
        before = (time.time() if now is None else now) - self.days * DAY
        with writing(self.db) as s:
            count = repository.prune_relayed(s, before)
            s.commit()
        self.pruned += count
        if count:
            log.info("retention: %d relayed frames' records older than %g days deleted", count, self.days)
        return count

    async def run(self, every: float = 3600.0, active: Callable[[], bool] = lambda: True) -> None:
        """Prune every ``every`` s while ``active`` (one center process of several coordinates)."""
        while True:
            if active():
                await asyncio.to_thread(self.prune)
            await asyncio.sleep(every)


class Stats(Protocol):
    stats: dict[str, int]


class Consumer(Protocol):
    """What the metrics read of the center's consumer (``server.backhaul.center.Center``)."""

    up: bool
    since: float
    coordinator: bool
    pending: int
    frames: Counter[str]
    counters: dict[str, int]
    gateways: dict[str, dict[str, Any]]
    guard: Guard

    @property
    def ingest(self) -> Stats: ...

    @property
    def subs(self) -> Mapping[int, object]: ...  # the frames partitions this process consumes


class Metrics:
    """What ``/metrics`` shows, in Prometheus' text format."""

    def __init__(self, center: Consumer, retention: Retention) -> None:
        self.center = center
        self.retention = retention

    def text(self, now: float | None = None) -> str:
        now = time.time() if now is None else now
        return render([*self._backhaul(), *self._gateways(now), *self._ingest()])

    def _backhaul(self) -> list[Family]:
        c = self.center
        refused = Family("tacit_backhaul_refused_total", "Messages refused, by reason", "counter")
        for reason, count in sorted(c.guard.refused.items()):
            refused.add(count, reason=reason)
        stored_refused = c.counters["malformed"] - sum(c.guard.refused.values())
        return [
            Family("tacit_backhaul_up", "The center's broker connection: 1 up, 0 down").add(int(c.up)),
            Family(
                "tacit_backhaul_state_since_timestamp_seconds",
                "When the connection last came up or went down",
            ).add(c.since),
            Family("tacit_backhaul_pending_frames", "Frame messages in the stream not yet consumed").add(
                c.pending
            ),
            Family("tacit_center_partitions", "Frames partitions this center process consumes").add(
                len(c.subs)
            ),
            Family("tacit_center_coordinator", "1 if this center process runs the singletons").add(
                int(c.coordinator)
            ),
            refused.add(stored_refused, reason="store"),
            Family("tacit_backhaul_store_retries_total", "Batches retried: the database away", "counter").add(
                c.counters["retries"]
            ),
            Family(
                "tacit_retention_pruned_total", "Relayed frames' records deleted by retention", "counter"
            ).add(self.retention.pruned),
        ]

    def _gateways(self, now: float) -> list[Family]:
        c = self.center
        frames = Family("tacit_gateway_frames_total", "Frame messages consumed, by gateway", "counter")
        up = Family("tacit_gateway_up", "1 while the gateway's heartbeats come, else 0")
        since = Family(
            "tacit_gateway_state_since_timestamp_seconds", "Heartbeats since (up), or the last (down)"
        )
        waiting = Family("tacit_gateway_outbox_waiting", "Messages in the gateway's outbox not yet published")
        for name in sorted(set(c.frames) | set(c.guard.announced)):
            frames.add(c.frames[name], gateway=name)
            announced = c.guard.announced.get(name)
            if announced is None:
                continue
            alive = c.guard.up(name, now)
            up.add(int(alive), gateway=name)
            since.add(announced.since if alive else announced.last, gateway=name)
            waiting.add(_number(c.gateways.get(name, {}).get("outbox")), gateway=name)
        return [frames, up, since, waiting]

    def _ingest(self) -> list[Family]:
        return ingest_families(self.center.ingest.stats)


def ingest_families(stats: Mapping[str, int]) -> list[Family]:
    """The ingest pipeline's counters (every shore process has one)."""
    counters = Family("tacit_ingest_total", "The ingest pipeline's counters, by what they count", "counter")
    for what, count in sorted(stats.items()):
        counters.add(count, counter=what)
    errors = Family("tacit_decode_errors_total", "Packets that did not decode or verify", "counter")
    for what in ("rejected", "forged", "unverifiable"):
        errors.add(stats.get(what, 0), kind=what)
    return [counters, errors]


class Link(Protocol):
    """What the metrics read of a shore's link engine (``server.link.engine.LinkEngine``)."""

    def status(self) -> dict[str, Any]: ...


class ShoreMetrics:
    """What ``/metrics`` shows for a shore with its own modem (``tacit serve``, the demo): the modem,
    the link's counters, each vehicle's frames and packets, the ingest pipeline's counters."""

    def __init__(self, link: Link) -> None:
        self.link = link

    def text(self) -> str:
        status = self.link.status()
        return render([*self._link(status), *self._vehicles(status), *ingest_families(status["ingest"])])

    def _link(self, status: dict[str, Any]) -> list[Family]:
        counters = Family("tacit_link_total", "The link engine's counters, by what they count", "counter")
        for what, count in sorted(status["counters"].items()):
            counters.add(count, counter=what)
        ready = Family("tacit_modem_ready", "The shore modem: 1 configured and answering, else 0")
        return [ready.add(int(status["modem"] == LinkState.READY.value)), counters]

    def _vehicles(self, status: dict[str, Any]) -> list[Family]:
        frames = Family("tacit_vehicle_frames_total", "Frames heard from each vehicle", "counter")
        packets = Family("tacit_vehicle_packets_total", "Packets stored from each vehicle", "counter")
        heard = Family("tacit_vehicle_last_heard_timestamp_seconds", "When each vehicle was last heard")
        for name, v in sorted(status["vehicles"].items()):
            frames.add(v["frames"], vehicle=name)
            packets.add(v["packets"], vehicle=name)
            heard.add(_number(v["last_heard"]), vehicle=name)
        return [frames, packets, heard]


def _number(value: object) -> float:
    """A heartbeat's field as a sample (NaN if the gateway sent none, or not a number)."""
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else math.nan
