"""The gateway's local store first: every frame its modem hears, and every event it reports, is
committed to a local SQLite file before anything else happens to it, then published in order.

Each message gets its id from the store: ``<gateway>-<incarnation>-<counter>``, the counter SQLite's
AUTOINCREMENT row id (never reused, even after rows are pruned), the incarnation a random token the file
was created with (a gateway whose outbox file is lost and recreated does not reuse old ids, which the
center would take for duplicates). The ``Publisher`` sends unpublished messages one at a time, oldest
first, each with its id as ``Nats-Msg-Id``, and marks it published when JetStream acknowledges it; after
an outage or a restart it resumes from the first unpublished message. A message published whose ack was
lost is published again: JetStream drops it within its ``duplicate_window``, the center's store after.

Commands from the center are kept in the same file (``inbox``), de-duplicated by their id, and so are
the SYNCs it pre-signed for each vehicle the gateway serves (``budget``, ``budget_sync``), so that a
gateway restarted during a backhaul outage still has them.

Standard library (and nats-py for the publisher): the gateway imports it.
"""

from __future__ import annotations

import asyncio
import json
import logging
import secrets
import sqlite3
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from server.backhaul import broker, subjects
from server.backhaul.subjects import CommandMessage, EventMessage, FrameMessage, SyncBudgetMessage

if TYPE_CHECKING:
    from nats.js import JetStreamContext

log = logging.getLogger("tacit.backhaul.outbox")

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS outbox (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    id TEXT UNIQUE,
    subject TEXT NOT NULL,
    payload BLOB NOT NULL,
    published INTEGER NOT NULL DEFAULT 0,
    at REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS outbox_unpublished ON outbox (published, seq);
CREATE TABLE IF NOT EXISTS inbox (
    id TEXT PRIMARY KEY,
    payload BLOB NOT NULL,
    received_at REAL NOT NULL,
    state TEXT NOT NULL DEFAULT 'stored'
);
CREATE TABLE IF NOT EXISTS budget (
    address INTEGER PRIMARY KEY,
    id TEXT NOT NULL,
    interval REAL NOT NULL,
    step REAL NOT NULL,
    ack_timeout REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS budget_sync (
    address INTEGER NOT NULL,
    at INTEGER NOT NULL,
    frame BLOB NOT NULL,
    PRIMARY KEY (address, at)
);
"""


@dataclass(frozen=True)
class Budget:
    """How the gateway uses a vehicle's pre-signed SYNCs (``subjects.SyncBudgetMessage``)."""

    address: int
    interval: float
    step: float
    ack_timeout: float


@dataclass(frozen=True)
class Unpublished:
    """A stored message not yet acknowledged by JetStream."""

    seq: int
    id: str
    subject: str
    payload: bytes


class Outbox:
    """The SQLite file: messages up (``outbox``) and commands down (``inbox``). Every write is committed
    (WAL, ``synchronous=FULL``: a frame is on disk before the call returns)."""

    def __init__(self, path: str | Path, gateway: str, keep: int = 10_000) -> None:
        self.gateway = subjects.gateway_name(gateway)
        self.keep = keep  # published messages kept (newest), for inspection; older ones are pruned
        self.on_add: Callable[[], None] | None = None  # called after each message is stored
        self._lock = threading.Lock()
        self._db = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.executescript(SCHEMA)
        with self._tx():
            row = self._db.execute("SELECT value FROM meta WHERE key = 'incarnation'").fetchone()
            if row is None:
                row = (secrets.token_hex(4),)
                self._db.execute("INSERT INTO meta VALUES ('incarnation', ?)", row)
            self._partition_frames()
        self.incarnation: str = row[0]

    def _partition_frames(self) -> None:
        """Frames a gateway of the previous wire stored on its gateway's subject and did not publish go on
        their partition's subject (``subjects.frames``): the center consumes no other."""
        legacy = self._db.execute(
            "SELECT seq, payload FROM outbox WHERE published = 0 AND subject = ?",
            (subjects.frames(self.gateway).rsplit(".", 1)[0],),  # without the partition
        ).fetchall()
        for seq, payload in legacy:
            src = FrameMessage.decode(bytes(payload)).src
            self._db.execute(
                "UPDATE outbox SET subject = ? WHERE seq = ?",
                (subjects.frames(self.gateway, subjects.partition(src)), seq),
            )
        if legacy:
            log.warning("outbox: %d unpublished frames moved to their partitions' subjects", len(legacy))

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def _tx(self) -> sqlite3.Connection:
        """``with self._tx():`` one IMMEDIATE transaction, committed at the end (rolled back on error)."""
        self._db.execute("BEGIN IMMEDIATE")
        return self._db

    def _id(self, seq: int) -> str:
        return f"{self.gateway}-{self.incarnation}-{seq}"

    def _add(self, subject: str, build: Callable[[str], bytes], at: float) -> str:
        with self._lock, self._tx():
            seq = self._db.execute(
                "INSERT INTO outbox (subject, payload, at) VALUES (?, x'', ?)", (subject, at)
            ).lastrowid
            assert seq is not None
            message_id = self._id(seq)
            self._db.execute(
                "UPDATE outbox SET id = ?, payload = ? WHERE seq = ?", (message_id, build(message_id), seq)
            )
        if self.on_add is not None:
            self.on_add()
        return message_id

    def add_frame(
        self,
        src: int,
        dest: int,
        data: bytes,
        rate: int = 0,
        snr_in: float | None = None,
        snr_out: float | None = None,
        stats: dict[str, Any] | None = None,
        at: float | None = None,
    ) -> str:
        """Store a received frame (committed when this returns); its id."""
        at = time.time() if at is None else at
        stats = json.loads(json.dumps(stats, default=str)) if stats else None  # plain JSON, as it will travel

        def build(message_id: str) -> bytes:
            return FrameMessage(
                message_id, self.gateway, src, dest, data, rate, snr_in, snr_out, stats, at
            ).encode()

        return self._add(subjects.frames(self.gateway, subjects.partition(src)), build, at)

    def add_event(self, kind: str, detail: dict[str, Any], at: float | None = None) -> str:
        """Store an event to report upward (an attempt's outcome, a modem state); its id."""
        at = time.time() if at is None else at
        return self._add(
            subjects.events(self.gateway),
            lambda message_id: EventMessage(message_id, self.gateway, kind, at, detail).encode(),
            at,
        )

    def pending(self, limit: int = 100) -> list[Unpublished]:
        """The oldest unpublished messages, in the order they were stored."""
        with self._lock:
            rows = self._db.execute(
                "SELECT seq, id, subject, payload FROM outbox WHERE published = 0 ORDER BY seq LIMIT ?",
                (limit,),
            ).fetchall()
        return [
            Unpublished(seq, message_id, subject, bytes(payload))
            for seq, message_id, subject, payload in rows
        ]

    def mark_published(self, seq: int) -> None:
        with self._lock, self._tx():
            self._db.execute("UPDATE outbox SET published = 1 WHERE seq = ?", (seq,))

    def depth(self) -> int:
        """Messages not yet acknowledged by JetStream."""
        with self._lock:
            return int(self._db.execute("SELECT count(*) FROM outbox WHERE published = 0").fetchone()[0])

    def stored(self) -> int:
        with self._lock:
            return int(self._db.execute("SELECT count(*) FROM outbox").fetchone()[0])

    def prune(self) -> int:
        """Delete published messages but the newest ``keep``; how many were deleted."""
        with self._lock, self._tx():
            cursor = self._db.execute(
                "DELETE FROM outbox WHERE published = 1 AND seq NOT IN "
                "(SELECT seq FROM outbox WHERE published = 1 ORDER BY seq DESC LIMIT ?)",
                (self.keep,),
            )
            return cursor.rowcount

    # --- commands down ---------------------------------------------------------------------------

    def add_command(self, command: CommandMessage, raw: bytes) -> bool:
        """Keep a command from the center; False if it was stored already (a redelivery)."""
        with self._lock, self._tx():
            cursor = self._db.execute(
                "INSERT OR IGNORE INTO inbox (id, payload, received_at) VALUES (?, ?, ?)",
                (command.id, raw, time.time()),
            )
            return cursor.rowcount == 1

    def set_command(self, command_id: str, state: str) -> None:
        with self._lock, self._tx():
            self._db.execute("UPDATE inbox SET state = ? WHERE id = ?", (state, command_id))

    def commands(self, state: str = "stored") -> list[CommandMessage]:
        with self._lock:
            rows = self._db.execute(
                "SELECT payload FROM inbox WHERE state = ? ORDER BY received_at", (state,)
            ).fetchall()
        return [CommandMessage.decode(bytes(row[0])) for row in rows]

    # --- SYNC budgets down ----------------------------------------------------------------------

    def keep_budget(self, message: SyncBudgetMessage, stamps: list[int]) -> bool:
        """Replace the vehicle's pre-signed SYNCs by the message's (``stamps``: each frame's time; none:
        withdrawn); False if this message was kept already (a redelivery)."""
        with self._lock, self._tx():
            row = self._db.execute("SELECT id FROM budget WHERE address = ?", (message.address,)).fetchone()
            if row is not None and row[0] == message.id:
                return False
            self._db.execute("DELETE FROM budget_sync WHERE address = ?", (message.address,))
            self._db.execute("DELETE FROM budget WHERE address = ?", (message.address,))
            if message.syncs:
                self._db.execute(
                    "INSERT INTO budget VALUES (?, ?, ?, ?, ?)",
                    (message.address, message.id, message.interval, message.step, message.ack_timeout),
                )
                self._db.executemany(
                    "INSERT OR REPLACE INTO budget_sync VALUES (?, ?, ?)",
                    [(message.address, at, frame) for at, frame in zip(stamps, message.syncs, strict=True)],
                )
            return True

    def budgets(self) -> list[Budget]:
        """The vehicles this gateway holds pre-signed SYNCs for."""
        with self._lock:
            rows = self._db.execute("SELECT address, interval, step, ack_timeout FROM budget").fetchall()
        return [Budget(int(a), float(i), float(s), float(t)) for a, i, s, t in rows]

    def budget_left(self, address: int) -> tuple[int, int | None]:
        """How many pre-signed SYNCs are kept for the vehicle, and the time of the last."""
        with self._lock:
            n, last = self._db.execute(
                "SELECT count(*), max(at) FROM budget_sync WHERE address = ?", (address,)
            ).fetchone()
        return int(n), None if last is None else int(last)

    def take_sync(self, budget: Budget, now: float) -> tuple[int, bytes] | None:
        """The vehicle's newest pre-signed SYNC whose time has come, if it is less than a step old (its
        time and frame); it and every older one are dropped: none goes out twice, or late."""
        with self._lock, self._tx():
            row = self._db.execute(
                "SELECT at, frame FROM budget_sync WHERE address = ? AND at <= ? ORDER BY at DESC LIMIT 1",
                (budget.address, now),
            ).fetchone()
            if row is None:
                return None
            self._db.execute(
                "DELETE FROM budget_sync WHERE address = ? AND at <= ?", (budget.address, row[0])
            )
        at, frame = int(row[0]), bytes(row[1])
        return (at, frame) if now - at < budget.step else None


PUBLISH_TIMEOUT = 2.0  # s: a publish JetStream has not acknowledged by then failed


class Publisher:
    """Sends the outbox's unpublished messages in order, each acknowledged by JetStream before the next;
    on a failure (broker down, no stream, timeout) waits and tries the same message again."""

    def __init__(
        self,
        outbox: Outbox,
        js: JetStreamContext,
        deployment: subjects.Deployment = subjects.UNNAMED,
        timeout: float = PUBLISH_TIMEOUT,
        retry: float = 0.5,
    ) -> None:
        """``deployment``: the outbox keeps the wire's subjects, published on the deployment's."""
        self.outbox = outbox
        self.js = js
        self.deployment = deployment
        self.timeout = timeout
        self.retry = retry
        self.wake = asyncio.Event()
        self.healthy = False  # the last publish was acknowledged
        self.failing_since: float | None = None  # the first failure since the last acknowledged publish
        self.counters = {"published": 0, "duplicates": 0, "failures": 0}
        loop = asyncio.get_running_loop()

        def added() -> None:  # from any thread: the modem's listener, a test
            loop.call_soon_threadsafe(self.wake.set)

        outbox.on_add = added

    async def run(self) -> None:
        while True:
            broker.stop_if_cancelled()  # a wait_for that ended as it was cancelled swallows the cancellation
            self.wake.clear()
            batch = self.outbox.pending()
            if not batch:
                try:
                    await asyncio.wait_for(self.wake.wait(), timeout=1.0)
                except TimeoutError:
                    pass
                continue
            if not await self.publish(batch):
                await asyncio.sleep(self.retry)
            elif self.outbox.keep >= 0:
                self.outbox.prune()

    async def publish(self, batch: list[Unpublished]) -> bool:
        """Publish ``batch`` in order; False at the first message JetStream did not acknowledge."""
        from nats.errors import Error as NatsError

        for item in batch:
            tried = time.time()
            try:
                ack = await self.js.publish(
                    self.deployment.subject(item.subject),
                    item.payload,
                    timeout=self.timeout,
                    headers={subjects.MSG_ID: item.id},
                )
            except (NatsError, TimeoutError, OSError) as exc:
                if self.healthy:
                    log.warning(
                        "backhaul: publishing %s failed (%s); %d waiting in the outbox",
                        item.id,
                        type(exc).__name__,
                        self.outbox.depth(),
                    )
                self.healthy = False
                self.failing_since = self.failing_since or tried
                self.counters["failures"] += 1
                return False
            self.outbox.mark_published(item.seq)
            self.counters["published"] += 1
            self.counters["duplicates"] += int(bool(ack.duplicate))
            if not self.healthy:
                log.info("backhaul: publishing (from %s)", item.id)
            self.healthy, self.failing_since = True, None
        return True
