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
import logging
import time
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.errors import Error as NatsError
from nats.js import JetStreamContext
from nats.js.api import AckPolicy, ConsumerConfig, DeliverPolicy
from nats.js.errors import NotFoundError

from server.backhaul import broker, subjects
from server.backhaul.relay import RelayedIncoming, RelayIngest
from server.backhaul.subjects import CommandMessage, EventMessage, FrameMessage, PayloadError

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
    ) -> None:
        self.ingest = ingest
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

    async def connect(self) -> None:
        self.nc = await broker.connect(self.url, "tacit-center")
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
            await self.nc.close()
        self.nc = self.js = self.sub = self.events = None

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
        frames, good = [], []
        for msg in msgs:
            try:
                frame = FrameMessage.decode(msg.data)
                if msg.subject != subjects.frames(frame.gateway) or not frame.id.startswith(
                    f"{frame.gateway}-"
                ):
                    raise PayloadError(
                        f"gateway {frame.gateway!r}, id {frame.id!r} on another gateway's subject"
                    )
                frames.append(RelayedIncoming.of(frame))
                good.append(msg)
            except PayloadError as exc:
                self.counters["malformed"] += 1
                log.error("backhaul: malformed frame message on %s dropped: %s", msg.subject, exc)
                await msg.term()
        await self._store(frames, good)
        for msg in good:
            await msg.ack()
        self.counters["messages"] += len(msgs)
        self.counters["batches"] += 1
        return len(msgs)

    async def _store(self, frames: list[RelayedIncoming], msgs: list[Msg]) -> None:
        """Ingest the batch; retried (the messages kept in progress) until it commits."""
        wait = 0.2
        while frames:
            try:
                await asyncio.to_thread(self.ingest.handle_batch, list(frames))
                return
            except Exception:  # the database away: nothing is acked, nothing later fetched
                self.counters["retries"] += 1
                log.exception("backhaul: storing %d frames failed; retrying in %.1f s", len(frames), wait)
                for msg in msgs:
                    await msg.in_progress()
                await asyncio.sleep(wait)
                wait = min(wait * 2, 5.0)

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
        try:
            event = EventMessage.decode(msg.data)
        except PayloadError as exc:
            log.warning("backhaul: malformed event on %s: %s", msg.subject, exc)
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


async def serve(shore: Shore, url: str, durable: str = DURABLE) -> None:
    """The center's backhaul in a shore's app: the consumers into its ingest and the dispatcher of its
    command desk (a queued command wakes it)."""
    from server.backhaul.dispatch import Dispatcher

    assert isinstance(shore.ingest, RelayIngest), "a center's shore is built with RelayIngest"
    center = Center(shore.ingest, url, durable=durable)
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
    await center.run(dispatcher.run())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--nats", default="nats://127.0.0.1:4222", help="the broker (default %(default)s)")
    parser.add_argument(
        "--database-url",
        default=None,
        help="the center's store, e.g. postgresql+psycopg://user@host/tacit (default: "
        "TACIT_DATABASE_URL or the server's default)",
    )
    parser.add_argument(
        "--durable", default=DURABLE, help="the consumer's durable name (default %(default)s)"
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
    app = create_app(settings, RelayIngest, [lambda shore: serve(shore, args.nats, args.durable)])
    log.info(
        "center: consuming %s from %s; API on %s:%d",
        subjects.frames(">"),
        args.nats,
        settings.host,
        settings.port,
    )
    uvicorn.run(app, host=settings.host, port=settings.port, log_level="info")
    return 0
