"""The center's end of the backhaul: durable pull consumers on the frames stream, one per partition
(``subjects.partition``: a vehicle's frames are all in one), feeding the shore's ingest
(``RelayIngest``), and the commands it sends down.

A frame must come on its own gateway's subject with an id of that gateway (with per-gateway publish
permissions on the broker, a gateway cannot pass its frames off as another's), on its partition. For
each fetched batch of a partition, in stream order: the frames are handed to ingest in one transaction
(the store de-duplicates by message id and across gateways), then every message is acked. A failing
transaction is retried (the messages kept in progress) before anything later of that partition is
fetched, so a vehicle's frames are stored in the order the stream holds them. A process that dies
between its commit and its acks leaves the messages to the partition's next holder (the store drops
them); when a process takes a partition whose messages were left unacked, the consumer is set back to
just after its ack floor, so they come again at once and in order instead of after ``ack_wait`` behind
newer ones.

Several center processes share one broker and database: each holds the partitions it has a lease on
(``server.backhaul.leases``; their vehicles' states loaded and replayed when it takes one, saved and
forgotten when it lets go), and the one holding the coordinator's lease runs the singletons: the
gateways' events, the routing, the TDMA schedules, the SYNC budgets and retention. Each process sends
the SYNCs and commands of the vehicles it decodes; every one serves the REST API and the dashboard from
the database.

The gateways' events (attempt outcomes, heartbeats) come through another durable consumer
(``tacit-center-events``) to ``on_event`` (the command dispatcher, ``server.backhaul.dispatch``), acked
after it returns; its reports are idempotent, so a redelivery does no harm. A restarted center resumes
from its ack floor; a fresh one (no such consumer yet) starts ``events_since`` s back (a command's
``max_age``: an attempt's outcome matters while the command may still be sent), not at the day the
stream keeps. A heartbeat older than a few heartbeats (a backlog) does not make its gateway up.

``tacit center``: the consumers into ingest and the dispatcher (PostgreSQL or SQLite), with the REST
API, the dashboard and the map of ``tacit serve`` (no shore modem of its own); ``--instance`` names a
process among several.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import re
import socket
import sys
import time
from collections import Counter
from collections.abc import Awaitable, Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import nats
from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.errors import Error as NatsError
from nats.js import JetStreamContext
from nats.js.api import AckPolicy, ConsumerConfig, DeliverPolicy
from nats.js.errors import NotFoundError
from sqlalchemy.engine import make_url
from sqlalchemy.exc import InterfaceError, OperationalError

from server.backhaul import access, broker, subjects
from server.backhaul.access import BrokerAuth
from server.backhaul.guard import Guard
from server.backhaul.leases import COORDINATOR, Leases, partition_key
from server.backhaul.live import Live
from server.backhaul.relay import RelayedIncoming, RelayIngest
from server.backhaul.subjects import (
    UNNAMED,
    CommandMessage,
    Deployment,
    EventMessage,
    PayloadError,
    ScheduleMessage,
    WithdrawMessage,
)

if TYPE_CHECKING:
    from server.shore import Shore

log = logging.getLogger("tacit.backhaul.center")

DURABLE = "tacit-center"  # partition p's durable is "<durable>-<p>", its events' "<durable>-events"


class Center:
    """One center process's consumers. ``instance`` None: the only one, consuming every partition and
    running the singletons, without leases (the tests and the benchmark drive it by ``step``); with an
    ``instance`` name, ``run`` shares the partitions and the singletons with the other processes through
    leases (``server.backhaul.leases``)."""

    def __init__(
        self,
        ingest: RelayIngest,
        url: str,
        deployment: Deployment = UNNAMED,
        batch: int = 64,
        ack_wait: float = 30.0,
        duplicate_window: float = subjects.DUPLICATE_WINDOW,
        auth: BrokerAuth | None = None,
        events_since: float = subjects.COMMAND_MAX_AGE,
        instance: str | None = None,
        lease: float = 5.0,
        database: str = "",
    ) -> None:
        """``database``: which database it stores into (``database_identity``), said to the others."""
        self.ingest = ingest
        self.database = database
        self.events_since = events_since
        self.auth = auth
        self.url = url
        self.deployment = deployment
        self.durable = deployment.named(DURABLE)  # its consumers' names' prefix, and its leases' bucket
        self.batch = batch
        self.ack_wait = ack_wait
        self.duplicate_window = duplicate_window
        self.instance = instance
        self.lease = lease
        self.nc: Client | None = None
        self.js: JetStreamContext | None = None
        self.leases: Leases | None = None
        self.live = None if instance is None else Live(ingest.bus, instance, deployment)  # the others' events
        self.subs: dict[int, JetStreamContext.PullSubscription] = {}  # the partitions consumed here
        self.coordinator = instance is None  # runs the singletons (the events, routing, slots, retention)
        self.gateways: dict[str, dict[str, Any]] = {}  # each gateway's last heartbeat
        self.on_event: Callable[[EventMessage], Awaitable[None]] | None = None
        self.events: JetStreamContext.PullSubscription | None = None
        self.counters = {"messages": 0, "batches": 0, "malformed": 0, "retries": 0}
        self.guard = Guard()
        self.frames: Counter[str] = Counter()  # frame messages consumed, by gateway
        self.pending = 0  # frame messages in the stream not yet delivered to this center's partitions
        self.up, self.since = False, time.time()  # the broker connection, and since when
        self._pending: dict[int, int] = {}  # by partition
        self._loops: dict[int, asyncio.Task[None]] = {}
        self._ingesting = asyncio.Lock()  # one batch in the ingest's thread at a time
        self._reloaded = 0.0  # when the vehicles were last read again for an unknown address (monotonic)

    def _state(self, up: bool) -> None:
        self.up, self.since = up, time.time()

    async def connect(self) -> None:
        """The broker, the streams and the events' consumer; without an instance, every partition."""
        self.nc = await broker.connect(self.url, self.instance or "tacit-center", self._state, auth=self.auth)
        self.js = self.nc.jetstream()
        await broker.ensure_streams(self.js, self.duplicate_window, self.deployment)
        if self.instance is None:
            self.events = await self._subscribe_events(self.js)
            for part in range(subjects.PARTITIONS):
                self.subs[part] = await self._partition(self.js, part)
        else:
            self.leases = Leases(self.js, self.durable, self.instance, self.lease, self.database)
            await self.leases.open()
            await self.leases.renew()  # announced among the members
            await asyncio.to_thread(self.ingest.own, self.mine)  # none until it holds a partition
        if self.live is not None:
            await self.live.start(self.nc)

    async def close(self) -> None:
        if self.nc is not None:
            with contextlib.suppress(NatsError, OSError):  # the backhaul may be down: closed all the same
                await self.nc.close()
        self.nc = self.js = self.events = self.leases = None
        if self.live is not None:
            self.live.nc = None
        self.subs = {}
        self._state(False)

    async def run(self, *also: Awaitable[None]) -> None:
        """Connect, take this process's share of the partitions, then consume its frames and, while it
        coordinates, the events, for ever, with ``also`` (the dispatcher); at the end its partitions'
        states saved and its leases released, for another process to take at once."""
        await self.connect()
        try:
            await self.rebalance()
            if self.leases is None:
                self._start(list(self.subs))
            await asyncio.gather(
                self._renewing(), self._rebalancing(), self._forever(self._coordinated_events), *also
            )
        finally:
            await self._leave()
            await self.close()

    @staticmethod
    async def _forever(step: Callable[[], Awaitable[int]]) -> None:
        task = asyncio.current_task()
        while task is None or not task.cancelling():  # a fetch may swallow the cancellation: not this
            await step()
        raise asyncio.CancelledError

    async def publish(self, subject: str, payload: bytes, message_id: str) -> None:
        """Publish to a stream with ``message_id`` as its ``Nats-Msg-Id`` (the dispatcher's way down)."""
        assert self.js is not None, "connect() first"
        await self.js.publish(
            self.deployment.subject(subject), payload, headers={subjects.MSG_ID: message_id}
        )

    async def kept_schedules(self) -> list[ScheduleMessage]:
        """The last schedule the stream keeps for each gateway (what gateways may still follow)."""
        assert self.js is not None, "connect() first"
        stream = self.deployment.named(subjects.SCHEDULE_STREAM)
        info = await self.js.stream_info(
            stream, subjects_filter=self.deployment.subject(subjects.schedule(">"))
        )
        kept = []
        for subject in sorted(info.state.subjects or {}):
            msg = await self.js.get_last_msg(stream, subject)
            try:
                kept.append(ScheduleMessage.decode(msg.data or b""))
            except PayloadError as exc:
                log.error("backhaul: the schedule kept on %s is unreadable (%s): ignored", subject, exc)
        return kept

    # --- the partitions: which this process consumes -----------------------------------------------

    def mine(self, address: int) -> bool:
        """This process decodes the vehicle at ``address``: it consumes its partition."""
        return subjects.partition(address) in self.subs

    def decoding(self, address: int) -> bool:
        """This process decodes the vehicle at ``address`` and no other can have taken it: its partition's
        lease was renewed less than a lease ago. Only then are its SYNCs and commands sent from here (two
        processes would sign SYNCs with the same counter, or dispatch one command twice)."""
        part = subjects.partition(address)
        return part in self.subs and (self.leases is None or self.leases.fresh(partition_key(part)))

    async def _renewing(self) -> None:
        while self.leases is not None:
            await asyncio.sleep(self.lease / 3)
            try:
                await self.leases.renew()
            except (NatsError, TimeoutError) as exc:  # the broker away: leases expire if it lasts
                log.warning("center %s: leases not renewed: %s", self.instance, exc)

    async def _rebalancing(self) -> None:
        while self.leases is not None:
            await asyncio.sleep(self.lease / 3)
            try:
                await self.rebalance()
            except (NatsError, TimeoutError) as exc:
                log.warning("center %s: partitions not rebalanced: %s", self.instance, exc)

    async def rebalance(self) -> None:
        """Let go of the partitions whose leases were lost or that another live process wants, take those
        this one wants that are free, and the coordinator's role if free (``server.backhaul.leases``)."""
        leases, js = self.leases, self.js
        if leases is None or js is None:
            return
        if not leases.holds(COORDINATOR):
            await self._coordinate(js, False)
        gone = {p for p in self.subs if not leases.holds(partition_key(p))}
        if gone:  # lost: another process may hold them already, and save their vehicles' states: not saved
            await self._stop(gone)
            await asyncio.to_thread(self.ingest.own, self.mine)
        members = await leases.members()
        wanted = leases.wanted(members, leases.instance)
        if self.live is not None:
            self.live.peers = len(members) > 1
        leaving = set(self.subs) - wanted
        if leaving:
            await self._stop(leaving)
            parts = frozenset(leaving)
            await asyncio.to_thread(self.ingest.save_states, lambda a: subjects.partition(a) in parts)
            await asyncio.to_thread(self.ingest.own, self.mine)
            for part in sorted(leaving):
                await leases.release(partition_key(part))
        taken = [p for p in sorted(wanted - set(self.subs)) if await leases.take(partition_key(p))]
        if taken:
            for part in taken:
                self.subs[part] = await self._partition(js, part)
            fresh = frozenset(taken)  # their vehicles read from the store before their frames are consumed
            await asyncio.to_thread(self.ingest.own, self.mine, lambda a: subjects.partition(a) in fresh)
            self._start(taken)
            log.info(
                "center %s: consuming partitions %s (%d center processes)",
                leases.instance,
                sorted(self.subs),
                len(members),
            )
        await self._coordinate(js, await leases.take(COORDINATOR))

    async def _coordinate(self, js: JetStreamContext, coordinator: bool) -> None:
        """Take up the singletons (the events' consumer first), or let go of them."""
        if coordinator and self.events is None:
            self.events = await self._subscribe_events(js)
            log.info("center %s: coordinating (events, routing, slots, budgets, retention)", self.instance)
        elif not coordinator and self.events is not None:
            events, self.events = self.events, None
            with contextlib.suppress(NatsError, TimeoutError):
                await events.unsubscribe()
        self.coordinator = coordinator

    def _start(self, parts: list[int]) -> None:
        for part in parts:
            self._loops[part] = asyncio.create_task(self._consume(part, self.subs[part]))

    async def _consume(self, part: int, sub: JetStreamContext.PullSubscription) -> None:
        while self.subs.get(part) is sub:
            if self.leases is not None and not self.leases.fresh(partition_key(part)):
                await asyncio.sleep(0.2)  # not renewed for a lease (the broker away): wait for the renewal
                continue
            try:
                await self._step(part, sub)
            except (NatsError, TimeoutError) as exc:  # an ack lost with the connection: it comes again
                log.warning("backhaul: partition %d: %s", part, exc)
                await asyncio.sleep(0.5)

    async def _stop(self, parts: set[int]) -> None:
        """Stop consuming ``parts``: each loop ends after its batch is stored and acked."""
        subs = {part: self.subs.pop(part) for part in parts if part in self.subs}
        await asyncio.gather(*(self._loops.pop(part) for part in parts if part in self._loops))
        for sub in subs.values():
            with contextlib.suppress(NatsError, TimeoutError):
                await sub.unsubscribe()
        for part in parts:
            self._pending.pop(part, None)

    async def _leave(self) -> None:
        """Stopping: the partitions' loops ended, their vehicles' states saved, the leases released."""
        leases = self.leases
        if leases is None:
            await self._stop(set(self.subs))
            return
        renewing = asyncio.create_task(self._renewing())  # held until the states are saved
        try:
            await self._stop(set(self.subs))
            await asyncio.to_thread(self.ingest.save_states)
        finally:
            renewing.cancel()
        with contextlib.suppress(NatsError, TimeoutError):
            for key in list(leases.held):
                await leases.release(key)
            await leases.leave()
        self.coordinator = False

    def _partition(self, js: JetStreamContext, part: int) -> Awaitable[JetStreamContext.PullSubscription]:
        return self._durable(
            js,
            self.deployment.named(subjects.FRAMES_STREAM),
            f"{self.durable}-{part}",
            self.deployment.subject(subjects.frames("*", part)),
            10 * self.batch,
        )

    async def _durable(
        self,
        js: JetStreamContext,
        stream: str,
        durable: str,
        subject: str,
        max_ack_pending: int | None = None,
        since: float | None = None,
    ) -> JetStreamContext.PullSubscription:
        """A durable consumer this process takes over (a partition's, the events'). If messages were left
        unacked (its last holder died between commit and acks), it is set back to just after its ack
        floor: they come again at once and in order. A fresh one (no such consumer yet) starts ``since``
        s back if given, else at the stream's first message."""
        config = ConsumerConfig(
            durable_name=durable,
            ack_policy=AckPolicy.EXPLICIT,
            ack_wait=self.ack_wait,
            max_ack_pending=max_ack_pending,
            filter_subject=subject,
        )
        try:
            info = await js.consumer_info(stream, durable)
        except NotFoundError:
            info = None
            if since is not None:
                start = datetime.fromtimestamp(time.time() - since, UTC)
                config.deliver_policy, config.opt_start_time = DeliverPolicy.BY_START_TIME, start
                log.info("backhaul: a fresh consumer %s, from %s on", durable, start.isoformat())
        if info is not None and info.num_ack_pending:
            floor = info.ack_floor.stream_seq if info.ack_floor else 0
            log.warning(
                "backhaul: %s: %d messages were left unacked; consumer set back to after %d",
                durable,
                info.num_ack_pending,
                floor,
            )
            await js.delete_consumer(stream, durable)
            config.deliver_policy, config.opt_start_seq = DeliverPolicy.BY_START_SEQUENCE, floor + 1
        return await js.pull_subscribe(subject, durable=durable, stream=stream, config=config)

    async def _subscribe_events(self, js: JetStreamContext) -> JetStreamContext.PullSubscription:
        """The events' durable consumer (the coordinator's): resumed where it is (set back to after its ack
        floor if its last holder left messages unacked), or made to start ``events_since`` s back."""
        return await self._durable(
            js,
            self.deployment.named(subjects.EVENTS_STREAM),
            f"{self.durable}-events",
            self.deployment.subject(subjects.events(">")),
            since=self.events_since,
        )

    # --- frames ----------------------------------------------------------------------------------

    async def step(self, timeout: float = 1.0) -> int:
        """Fetch one batch of every partition consumed here with frames waiting (of every one, waiting up to
        ``timeout`` for them, if none has), store each, ack it; how many messages. ``run`` consumes each
        partition in a loop of its own instead."""
        subs = list(self.subs.items())
        try:
            infos = await asyncio.gather(*(sub.consumer_info() for _, sub in subs))
        except (TimeoutError, NatsError) as exc:
            await _pause(exc)
            return 0
        waiting = [(p, sub) for (p, sub), info in zip(subs, infos, strict=True) if info.num_pending]
        fetched = await asyncio.gather(*(self._step(p, sub, timeout) for p, sub in waiting or subs))
        return sum(fetched)

    async def _step(self, part: int, sub: JetStreamContext.PullSubscription, timeout: float = 1.0) -> int:
        """Fetch one batch of partition ``part``, store it, ack it; how many messages it held."""
        try:
            msgs = await sub.fetch(self.batch, timeout=timeout)
        except (TimeoutError, NatsError) as exc:
            await _pause(exc)
            return 0
        batch: list[tuple[RelayedIncoming, Msg]] = []
        now = time.time()
        for msg in msgs:
            frame = self.guard.frame(self.deployment.local(msg.subject), msg.data, now)
            if frame is None:
                self.counters["malformed"] += 1
                await msg.term()
            else:
                batch.append((RelayedIncoming.of(frame), msg))
                self.frames[frame.gateway] += 1
        self._pending[part] = msgs[-1].metadata.num_pending if msgs else 0
        self.pending = sum(self._pending.values())
        if any(frame.src not in self.ingest.vehicles for frame, _ in batch):
            await self._reload()
        for msg in await self._store(batch) if batch else []:
            await msg.ack()
        self.counters["messages"] += len(msgs)
        self.counters["batches"] += 1
        return len(msgs)

    async def _reload(self) -> None:
        """A frame from an address this process holds no vehicle for: one registered through another
        process's API since it loaded them, or a stranger. The vehicles read again before the batch is
        stored (at most once a lease, for the strangers' sake)."""
        if time.monotonic() - self._reloaded < self.lease:
            return
        self._reloaded = time.monotonic()
        async with self._ingesting:
            await asyncio.to_thread(self.ingest.load_vehicles)

    async def _store(self, batch: list[tuple[RelayedIncoming, Msg]]) -> list[Msg]:
        """Ingest the batch in one transaction; the messages stored. Retried while the database is away
        (the messages kept in progress, nothing later fetched). A batch the pipeline fails on for what it
        holds is taken frame by frame, and a frame it fails on alone is stored undecoded, logged with its
        stream sequence: one bad frame must not stop every gateway's, nor be lost."""
        wait = 0.2
        while True:
            try:
                async with self._ingesting:
                    await asyncio.to_thread(self.ingest.handle_batch, [frame for frame, _ in batch])
                return [msg for _, msg in batch]
            except (OperationalError, InterfaceError):  # the database away, or locked
                self.counters["retries"] += 1
                log.exception("backhaul: storing %d frames failed; retrying in %.1f s", len(batch), wait)
                for _, msg in batch:
                    await msg.in_progress()
                await asyncio.sleep(wait)
                wait = min(wait * 2, 5.0)
            except Exception:
                if len(batch) > 1:
                    return [msg for one in batch for msg in await self._store([one])]
                return await self._undecoded(*batch[0])

    async def _undecoded(self, frame: RelayedIncoming, msg: Msg) -> list[Msg]:
        log.exception(
            "backhaul: frame %s (stream seq %d) failed in the pipeline; stored undecoded",
            frame.id,
            msg.metadata.sequence.stream,
        )
        try:
            await asyncio.to_thread(self.ingest.keep_undecoded, frame)
        except (OperationalError, InterfaceError):
            return []  # the database went away meanwhile: not acked, it comes again
        except Exception:  # not even its bytes can be stored: refused, left in the stream to look at
            self.counters["malformed"] += 1
            log.exception("backhaul: frame %s refused by the store", frame.id)
            await msg.term()
            return []
        return [msg]

    # --- events ----------------------------------------------------------------------------------

    async def _coordinated_events(self) -> int:
        """The gateways' events, while this process coordinates (one process handles them)."""
        if self.events is not None:
            return await self.step_events()
        await asyncio.sleep(self.lease / 3)
        return 0

    async def step_events(self, timeout: float = 1.0) -> int:
        """Fetch the gateways' events, hand each to ``on_event``, ack it; how many were fetched. An
        event ``on_event`` failed on (the database away) is left for redelivery."""
        assert self.events is not None, "connect() first"
        try:
            msgs = await self.events.fetch(self.batch, timeout=timeout)
        except (TimeoutError, NatsError) as exc:
            await _pause(exc)
            return 0
        for msg in msgs:
            await self._event(msg)
        return len(msgs)

    async def _event(self, msg: Msg) -> None:
        now = time.time()
        event = self.guard.event(self.deployment.local(msg.subject), msg.data, now)
        if event is None:
            await msg.term()
            return
        if event.kind == "heartbeat":
            if not self.guard.stale(event, now):  # a backlog's says nothing of now
                self.gateways[event.gateway] = {**event.detail, "at": event.at, "seen": now}
                await self._gateway_consumers(event)
        elif event.kind != "attempt":
            log.info("gateway %s: %s %s", event.gateway, event.kind, event.detail)
        try:
            if self.on_event is not None:
                await self.on_event(event)
        except Exception:
            log.exception("backhaul: event %s not handled; it comes again", event.id)
            await msg.nak(delay=1.0)
            return
        await msg.ack()

    async def _gateway_consumers(self, heartbeat: EventMessage) -> None:
        """A gateway heard: its consumers made if missing (the center makes them, not the gateway), those
        of the last messages made anew for a new outbox."""
        assert self.js is not None, "connect() first"
        try:
            await broker.ensure_gateway_consumers(
                self.js, heartbeat.gateway, str(heartbeat.detail["incarnation"]), self.deployment
            )
        except (NatsError, TimeoutError) as exc:  # its next heartbeat tries again
            log.warning("backhaul: gateway %s's consumers not made: %s", heartbeat.gateway, exc)

    async def send_command(self, command: CommandMessage | WithdrawMessage) -> bool:
        """Publish a signed command frame, or the withdrawal of one, to its gateway (its id the message
        id); False if JetStream already had it (a retry within the duplicate window)."""
        assert self.js is not None, "connect() first"
        ack = await self.js.publish(
            self.deployment.subject(subjects.commands(command.gateway)),
            command.encode(),
            headers={subjects.MSG_ID: command.id},
        )
        return not ack.duplicate


async def _pause(exc: Exception) -> None:
    """After a fetch that failed at once (the connection closed, the consumer gone): a pause, so that a
    loop of fetches never spins without yielding to the event loop. A timeout has waited already."""
    if not isinstance(exc, TimeoutError):
        log.debug("backhaul: fetch failed: %s", exc)
        await asyncio.sleep(0.5)


def database_identity(url: str) -> str:
    """Which database a URL names, told apart from another whatever the spelling: a SQLite file's path,
    a server's address, port and database name (no user, no password)."""
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite":
        return f"sqlite:{Path(parsed.database or '').resolve()}"
    try:
        host = socket.gethostbyname(parsed.host or "localhost")
    except OSError:
        host = parsed.host or "localhost"
    return f"{parsed.get_backend_name()}://{host}:{parsed.port or 5432}/{parsed.database}"


async def refusal(
    url: str, auth: BrokerAuth, deployment: Deployment, instance: str, database: str
) -> str | None:
    """Why this center process may not join its deployment's (one line), or None: another live process
    has its instance name, or stores into another database (two databases would each hold half the
    vehicles). A broker that does not answer yet refuses nothing: the process waits for it."""
    try:
        nc = await nats.connect(url, connect_timeout=2, allow_reconnect=False, max_reconnect_attempts=0,
                                **auth.options())  # fmt: skip
    except (NatsError, OSError, TimeoutError):
        return None
    try:
        leases = Leases(nc.jetstream(), deployment.named(DURABLE), instance, 1.0)
        entries = await leases.entries() if await leases.bind() else {}
    except (NatsError, TimeoutError):
        return None
    finally:
        await nc.close()
    if instance in entries:
        return (
            f"a center process named {instance!r} runs already in deployment {deployment.name!r} (--instance)"
        )
    for name, entry in entries.items():
        if entry.get("database") not in (None, "", database):
            return (
                f"deployment {deployment.name!r}'s center process {name!r} stores into {entry['database']}, "
                f"this one into {database}: one database per deployment (--database-url, --deployment)"
            )
    return None


def default_instance() -> str:
    """A center process's name unless given: its host's and its process id."""
    return f"{re.sub(r'[^A-Za-z0-9_-]', '-', socket.gethostname())[:40]}-{os.getpid()}"


async def serve(
    shore: Shore,
    url: str,
    deployment: Deployment = UNNAMED,
    auth: BrokerAuth | None = None,
    instance: str | None = None,
) -> None:
    """The center's backhaul in a shore's app: the consumers of its share of the partitions into its
    ingest and the dispatcher of its command desk (a queued command wakes it; it dispatches the commands
    of the vehicles this process decodes), with the retention and ``/metrics`` (``server.ops``). Several processes may
    serve one broker and database, each under its own ``instance`` name."""
    from server.backhaul.dispatch import Dispatcher
    from server.ops.process import operate

    assert isinstance(shore.ingest, RelayIngest), "a center's shore is built with RelayIngest"
    center = Center(
        shore.ingest,
        url,
        deployment=deployment,
        auth=auth,
        instance=instance or default_instance(),
        lease=shore.settings.center_lease,
        database=database_identity(shore.settings.database_url),
    )
    dispatcher = Dispatcher(
        shore.commands,
        shore.routing,
        shore.settings,
        center.publish,
        shore.link.heartbeat,
        shore.ingest.states,
        coordinating=lambda: center.coordinator,
        kept=center.kept_schedules,
        decoding=center.decoding,
    )
    center.on_event = dispatcher.on_event
    shore.commands.wake = dispatcher.wake
    await operate(center, center.run(dispatcher.run()), shore.ingest.db, shore.settings)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--nats", default=None, help="the broker (default TACIT_NATS_URL or nats://127.0.0.1:4222)"
    )
    access.add_arguments_for_client(parser, {})  # their defaults are the settings' (TACIT_NATS_*)
    parser.add_argument(
        "--database-url",
        default=None,
        help="the center's store, e.g. postgresql+psycopg://user@host/tacit (default: "
        "TACIT_DATABASE_URL or the server's default)",
    )
    parser.add_argument(
        "--instance",
        type=_instance,
        default=None,
        help="this process's name among the center's processes on one broker and database (default: "
        "host-pid); run several, each with its own --port, --map-port and --metrics-port",
    )
    parser.add_argument(
        "--metrics-port",
        type=int,
        default=None,
        help="serve /metrics (Prometheus) on this port of TACIT_METRICS_HOST; 0: none "
        "(default TACIT_METRICS_PORT or 9464)",
    )
    parser.add_argument("--config", help="a TOML settings file (TACIT_* environment variables override it)")
    parser.add_argument("--host", help="the API's bind address (default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="API and dashboard port (default 8000)")
    parser.add_argument("--map-port", type=int, help="3D map port (default 8080)")
    parser.add_argument("--no-map", action="store_true", help="do not start the 3D map")
    parser.set_defaults(modem_url=None)  # the center has no modem: its gateways have


def _instance(name: str) -> str:
    try:
        return subjects.gateway_name(name)
    except ValueError:
        raise argparse.ArgumentTypeError("1-64 letters, digits, '_' or '-'") from None


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from server.app import create_app, settings_from

    settings = settings_from(args)
    settings.modem_url = ""
    overrides = {
        "nats_url": args.nats,
        "nats_credentials": args.nats_credentials,
        "nats_ca": args.nats_ca,
        "nats_insecure": args.insecure or None,
        "deployment": args.deployment,
        "metrics_port": args.metrics_port,
    }
    for name, value in overrides.items():
        if value is not None:
            setattr(settings, name, value)
    instance = args.instance or default_instance()
    try:
        deployment = Deployment(settings.deployment)
        auth = access.client_auth(
            f"tacit center {instance}", settings.nats_credentials, settings.nats_ca, settings.nats_insecure,
            deployment,
        )  # fmt: skip
    except (access.CredentialsError, ValueError) as exc:
        print(f"tacit center: {exc}", file=sys.stderr)
        return 2
    refused = asyncio.run(
        refusal(settings.nats_url, auth, deployment, instance, database_identity(settings.database_url))
    )
    if refused:
        print(f"tacit center: {refused}", file=sys.stderr)
        return 2
    app = create_app(
        settings,
        RelayIngest,
        [lambda shore: serve(shore, settings.nats_url, deployment, auth, instance)],
    )
    log.info(
        "center %s: sharing %s from %s with the other center processes; API on %s:%d",
        instance,
        deployment.subject(subjects.frames(">")),
        settings.nats_url,
        settings.host,
        settings.port,
    )
    uvicorn.run(app, host=settings.host, port=settings.port, log_level="info")
    return 0
