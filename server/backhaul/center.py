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

``tacit center``: the consumer into ingest (PostgreSQL or SQLite). One center per broker.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import sys
import time
from collections import Counter
from typing import Any

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
from server.backhaul.subjects import CommandMessage

log = logging.getLogger("tacit.backhaul.center")

DURABLE = "tacit-center"


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
        await self.nc.subscribe(subjects.events(), cb=self._event)

    async def close(self) -> None:
        if self.nc is not None:
            with contextlib.suppress(NatsError, OSError):  # the backhaul may be down: closed all the same
                await self.nc.close()
        self.nc = self.js = self.sub = None
        self._state(False)

    async def run(self) -> None:
        await self.connect()
        try:
            while True:
                await self.step()
        finally:
            await self.close()

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
        except (TimeoutError, NatsError):
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

    async def _event(self, msg: Msg) -> None:
        event = self.guard.event(msg.subject, msg.data, time.time())
        if event is None:
            return
        if event.kind == "heartbeat":
            self.gateways[event.gateway] = {**event.detail, "at": event.at, "seen": time.time()}
        else:
            log.info("gateway %s: %s %s", event.gateway, event.kind, event.detail)

    async def send_command(self, command: CommandMessage) -> bool:
        """Publish a signed command frame to its gateway (its id the message id); False if JetStream
        already had it (a retry within the duplicate window)."""
        assert self.js is not None, "connect() first"
        ack = await self.js.publish(
            subjects.commands(command.gateway), command.encode(), headers={subjects.MSG_ID: command.id}
        )
        return not ack.duplicate


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


def run(args: argparse.Namespace) -> int:
    from server.core.config import Settings
    from server.core.db import make_engine, migrate
    from server.core.events import Bus
    from server.ops.process import operate
    from tacit.streams import default_streams

    settings = Settings()
    overrides = {
        "database_url": args.database_url,
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
    migrate(settings.database_url)
    ingest = RelayIngest(make_engine(settings.database_url), Bus(), default_streams(), settings)
    ingest.load_vehicles()
    log.info(
        "center: %d vehicles; consuming %s from %s",
        len(ingest.vehicles),
        subjects.frames(">"),
        settings.nats_url,
    )
    center = Center(ingest, settings.nats_url, durable=args.durable, auth=auth)
    asyncio.run(operate(center, center.run(), ingest.db, settings))
    ingest.save_states()  # a restart then has no frames to replay
    return 0
