"""The center's end of the backhaul: a durable pull consumer on the frames stream feeding the shore's
ingest (``RelayIngest``), and the commands it sends down.

A frame must come on its own gateway's subject with an id of that gateway (with per-gateway publish
permissions on the broker, a gateway cannot pass its frames off as another's). For each fetched batch,
in stream order: the frames are handed to ingest in one transaction (the
store de-duplicates by message id and across gateways), then every message is acked. A failing
transaction is retried (the messages kept in progress) before anything later is fetched, so a vehicle's
frames are stored in the order the stream holds them. A center that dies between its commit and its
acks gets the messages again (the store drops them); at start, if messages were left unacked, the
consumer is set back to just after its ack floor, so they come again at once and in order instead of
after ``ack_wait`` behind newer ones.

The gateways' events (attempt outcomes, heartbeats) come through a second durable consumer
(``tacit-center-events``) to ``on_event`` (the command dispatcher, ``server.backhaul.dispatch``), acked
after it returns; its reports are idempotent, so a redelivery does no harm.

``tacit center``: the consumers into ingest and the dispatcher (PostgreSQL or SQLite), with the REST
API, the dashboard and the map of ``tacit serve`` (no shore modem of its own). One center per broker.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import sys
import time
from collections import Counter
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.errors import Error as NatsError
from nats.js import JetStreamContext
from nats.js.api import AckPolicy, ConsumerConfig, DeliverPolicy
from nats.js.errors import NotFoundError
from sqlalchemy.exc import InterfaceError, OperationalError

from server.backhaul import access, broker, subjects
from server.backhaul.access import BrokerAuth
from server.backhaul.guard import Guard
from server.backhaul.relay import RelayedIncoming, RelayIngest
from server.backhaul.subjects import CommandMessage, EventMessage

if TYPE_CHECKING:
    from server.shore import Shore

log = logging.getLogger("tacit.backhaul.center")

DURABLE = "tacit-center"  # its events' durable is "<durable>-events"


class Center:
    def __init__(
        self,
        ingest: RelayIngest,
        url: str,
        durable: str = DURABLE,
        batch: int = 64,
        ack_wait: float = 30.0,
        duplicate_window: float = subjects.DUPLICATE_WINDOW,
        auth: BrokerAuth | None = None,
    ) -> None:
        self.ingest = ingest
        self.auth = auth
        self.url = url
        self.durable = durable
        self.batch = batch
        self.ack_wait = ack_wait
        self.duplicate_window = duplicate_window
        self.nc: Client | None = None
        self.js: JetStreamContext | None = None
        self.sub: JetStreamContext.PullSubscription | None = None
        self.gateways: dict[str, dict[str, Any]] = {}  # each gateway's last heartbeat
        self.on_event: Callable[[EventMessage], Awaitable[None]] | None = None
        self.events: JetStreamContext.PullSubscription | None = None
        self.counters = {"messages": 0, "batches": 0, "malformed": 0, "retries": 0}
        self.guard = Guard()
        self.frames: Counter[str] = Counter()  # frame messages consumed, by gateway
        self.pending = 0  # frame messages in the stream not yet delivered to this center
        self.up, self.since = False, time.time()  # the broker connection, and since when

    def _state(self, up: bool) -> None:
        self.up, self.since = up, time.time()

    async def connect(self) -> None:
        self.nc = await broker.connect(self.url, "tacit-center", self._state, auth=self.auth)
        self.js = self.nc.jetstream()
        await broker.ensure_streams(self.js, self.duplicate_window)
        self.sub = await self._subscribe(self.js)
        self.events = await self.js.pull_subscribe(
            subjects.events(">"),
            durable=f"{self.durable}-events",
            stream=subjects.EVENTS_STREAM,
            config=ConsumerConfig(ack_policy=AckPolicy.EXPLICIT, ack_wait=self.ack_wait),
        )

    async def close(self) -> None:
        if self.nc is not None:
            with contextlib.suppress(NatsError, OSError):  # the backhaul may be down: closed all the same
                await self.nc.close()
        self.nc = self.js = self.sub = self.events = None
        self._state(False)

    async def run(self, *also: Awaitable[None]) -> None:
        """Connect, then consume frames and events for ever, with ``also`` (the dispatcher)."""
        await self.connect()
        try:
            await asyncio.gather(self._forever(self.step), self._forever(self.step_events), *also)
        finally:
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
        await self.js.publish(subject, payload, headers={subjects.MSG_ID: message_id})

    async def _subscribe(self, js: JetStreamContext) -> JetStreamContext.PullSubscription:
        config = ConsumerConfig(
            durable_name=self.durable,
            ack_policy=AckPolicy.EXPLICIT,
            ack_wait=self.ack_wait,
            max_ack_pending=10 * self.batch,
            filter_subject=subjects.frames(">"),
        )
        try:
            info = await js.consumer_info(subjects.FRAMES_STREAM, self.durable)
        except NotFoundError:
            info = None
        if info is not None and info.num_ack_pending:
            floor = info.ack_floor.stream_seq if info.ack_floor else 0
            log.warning(
                "backhaul: %d frames were left unacked; consumer set back to after %d",
                info.num_ack_pending,
                floor,
            )
            await js.delete_consumer(subjects.FRAMES_STREAM, self.durable)
            config.deliver_policy, config.opt_start_seq = DeliverPolicy.BY_START_SEQUENCE, floor + 1
        return await js.pull_subscribe(
            subjects.frames(">"), durable=self.durable, stream=subjects.FRAMES_STREAM, config=config
        )

    async def step(self, timeout: float = 1.0) -> int:
        """Fetch one batch, store it, ack it; how many messages it held."""
        assert self.sub is not None, "connect() first"
        try:
            msgs = await self.sub.fetch(self.batch, timeout=timeout)
        except (TimeoutError, NatsError) as exc:
            await _pause(exc)
            return 0
        batch: list[tuple[RelayedIncoming, Msg]] = []
        for msg in msgs:
            frame = self.guard.frame(msg.subject, msg.data)
            if frame is None:
                self.counters["malformed"] += 1
                await msg.term()
            else:
                batch.append((RelayedIncoming.of(frame), msg))
                self.frames[frame.gateway] += 1
        self.pending = msgs[-1].metadata.num_pending if msgs else 0
        for msg in await self._store(batch) if batch else []:
            await msg.ack()
        self.counters["messages"] += len(msgs)
        self.counters["batches"] += 1
        return len(msgs)

    async def _store(self, batch: list[tuple[RelayedIncoming, Msg]]) -> list[Msg]:
        """Ingest the batch in one transaction; the messages stored. Retried while the database is away
        (the messages kept in progress, nothing later fetched). A batch the pipeline fails on for what it
        holds is taken frame by frame, and a frame it fails on alone is stored undecoded, logged with its
        stream sequence: one bad frame must not stop every gateway's, nor be lost."""
        wait = 0.2
        while True:
            try:
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
        event = self.guard.event(msg.subject, msg.data, time.time())
        if event is None:
            await msg.term()
            return
        if event.kind == "heartbeat":
            self.gateways[event.gateway] = {**event.detail, "at": event.at, "seen": time.time()}
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

    async def send_command(self, command: CommandMessage) -> bool:
        """Publish a signed command frame to its gateway (its id the message id); False if JetStream
        already had it (a retry within the duplicate window)."""
        assert self.js is not None, "connect() first"
        ack = await self.js.publish(
            subjects.commands(command.gateway), command.encode(), headers={subjects.MSG_ID: command.id}
        )
        return not ack.duplicate


async def _pause(exc: Exception) -> None:
    """After a fetch that failed at once (the connection closed, the consumer gone): a pause, so that a
    loop of fetches never spins without yielding to the event loop. A timeout has waited already."""
    if not isinstance(exc, TimeoutError):
        log.debug("backhaul: fetch failed: %s", exc)
        await asyncio.sleep(0.5)


async def serve(shore: Shore, url: str, durable: str = DURABLE, auth: BrokerAuth | None = None) -> None:
    """The center's backhaul in a shore's app: the consumers into its ingest and the dispatcher of its
    command desk (a queued command wakes it), with the retention and ``/metrics`` (``server.ops``)."""
    from server.backhaul.dispatch import Dispatcher
    from server.ops.process import operate

    assert isinstance(shore.ingest, RelayIngest), "a center's shore is built with RelayIngest"
    center = Center(shore.ingest, url, durable=durable, auth=auth)
    dispatcher = Dispatcher(
        shore.commands,
        shore.routing,
        shore.settings,
        center.publish,
        shore.link.heartbeat,
        shore.ingest.states,
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
        "--durable", default=DURABLE, help="the consumer's durable name (default %(default)s)"
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


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from server.app import create_app, settings_from

    settings = settings_from(args)
    settings.modem_url = ""
    overrides = {
        "nats_url": args.nats,
        "nats_credentials": args.nats_credentials,
        "nats_ca": args.nats_ca,
        "metrics_port": args.metrics_port,
    }
    for name, value in overrides.items():
        if value is not None:
            setattr(settings, name, value)
    try:
        auth = BrokerAuth.load(settings.nats_credentials, settings.nats_ca)
    except access.CredentialsError as exc:
        print(f"tacit center: {exc}", file=sys.stderr)
        return 2
    app = create_app(
        settings, RelayIngest, [lambda shore: serve(shore, settings.nats_url, args.durable, auth)]
    )
    log.info(
        "center: consuming %s from %s; API on %s:%d",
        subjects.frames(">"),
        settings.nats_url,
        settings.host,
        settings.port,
    )
    uvicorn.run(app, host=settings.host, port=settings.port, log_level="info")
    return 0
