"""The broker, as both ends use it: a connection that is retried until the broker answers (and then
reconnects by itself, forever), the JetStream streams, created or brought to this configuration, and the
gateways' consumers, which the center makes and each gateway binds to (``bind``).

Standard library and nats-py: the gateway imports it.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

import nats
from nats.aio.client import Client
from nats.errors import Error as NatsError
from nats.js import JetStreamContext
from nats.js.api import AckPolicy, ConsumerConfig, DeliverPolicy, RetentionPolicy, StorageType, StreamConfig
from nats.js.errors import BadRequestError, NotFoundError

from server.backhaul import access, subjects
from server.backhaul.access import BrokerAuth, GatewayConsumer
from server.backhaul.subjects import UNNAMED, Deployment

log = logging.getLogger("tacit.backhaul.broker")
# A link that goes silent (a cellular or satellite backhaul lost, no reset) is taken for down after this
# many unanswered pings, one every PING_INTERVAL s (the client's default waits four minutes).
PING_INTERVAL = 5.0
MAX_OUTSTANDING_PINGS = 2
GATEWAY_ACK_WAIT = 30.0  # s: a message a gateway fetched and did not ack comes again after this


async def connect(
    url: str,
    name: str,
    on_state: Callable[[bool], None] | None = None,
    retry: float = 0.2,
    retry_max: float = 5.0,
    auth: BrokerAuth | None = None,
) -> Client:
    """A connection to ``url`` as ``auth``'s user; waits (retrying) while the broker does not answer or
    refuses the credentials (logged: a broker being reconfigured, or a wrong file). Once connected, the
    client reconnects by itself after any outage; ``on_state`` hears ``True``/``False`` as it comes and
    goes."""

    async def up() -> None:
        log.info("backhaul: connected to %s", url)
        if on_state:
            on_state(True)

    clients: list[Client] = []

    async def down() -> None:
        if clients and (clients[0].is_closed or clients[0].is_draining):
            return  # closed on purpose
        log.warning("backhaul: lost %s; reconnecting", url)
        if on_state:
            on_state(False)

    async def error(exc: Exception) -> None:
        log.debug("backhaul: %s", exc)

    wait = retry
    while True:
        try:
            client = await nats.connect(
                url,
                name=name,
                max_reconnect_attempts=-1,
                reconnect_time_wait=0.5,
                connect_timeout=2,
                ping_interval=PING_INTERVAL,
                max_outstanding_pings=MAX_OUTSTANDING_PINGS,
                allow_reconnect=True,
                disconnected_cb=down,
                reconnected_cb=up,
                error_cb=error,
                **(auth or BrokerAuth()).options(),
            )
        except (NatsError, OSError, TimeoutError) as exc:
            log.warning("backhaul: %s does not answer (%s); retrying in %.1f s", url, exc, wait)
            await asyncio.sleep(wait)
            wait = min(wait * 2, retry_max)
            continue
        clients.append(client)
        await up()
        return client


def stream_configs(
    duplicate_window: float = subjects.DUPLICATE_WINDOW, deployment: Deployment = UNNAMED
) -> list[StreamConfig]:
    """The streams: frames (kept until the center has them: limits by size and age, not by interest, so
    a center away for hours finds them), commands, events, each gateway's last schedule (a gateway
    restarting reads its own, center or not: direct gets) and the last SYNC budget of each gateway and
    vehicle. File storage: a broker restart loses none. Names and subjects are ``deployment``'s."""
    d = deployment
    return [
        StreamConfig(name=d.named(subjects.FRAMES_STREAM), subjects=[d.subject(subjects.frames(">"))],
                     storage=StorageType.FILE, retention=RetentionPolicy.LIMITS, duplicate_window=duplicate_window,
                     max_age=7 * 86400.0),
        StreamConfig(name=d.named(subjects.COMMANDS_STREAM), subjects=[d.subject(subjects.commands(">"))],
                     storage=StorageType.FILE, retention=RetentionPolicy.LIMITS, duplicate_window=duplicate_window,
                     max_age=subjects.COMMAND_MAX_AGE),
        StreamConfig(name=d.named(subjects.EVENTS_STREAM), subjects=[d.subject(subjects.events(">"))],
                     storage=StorageType.FILE, retention=RetentionPolicy.LIMITS, duplicate_window=duplicate_window,
                     max_age=subjects.EVENTS_MAX_AGE),
        StreamConfig(name=d.named(subjects.SCHEDULE_STREAM), subjects=[d.subject(subjects.schedule(">"))],
                     storage=StorageType.FILE, retention=RetentionPolicy.LIMITS, max_msgs_per_subject=1,
                     allow_direct=True),
        StreamConfig(name=d.named(subjects.SYNCS_STREAM), subjects=[d.subject(subjects.syncs(">"))],
                     storage=StorageType.FILE, retention=RetentionPolicy.LIMITS, duplicate_window=duplicate_window,
                     max_msgs_per_subject=1),
    ]  # fmt: skip


async def ensure_streams(
    js: JetStreamContext,
    duplicate_window: float = subjects.DUPLICATE_WINDOW,
    deployment: Deployment = UNNAMED,
) -> None:
    """Create the streams, or update them to this configuration (the center's, at its start)."""
    for config in stream_configs(duplicate_window, deployment):
        try:
            await js.add_stream(config)
        except BadRequestError:  # exists with another configuration
            await js.update_stream(config)


def _owner(name: str, consumer: GatewayConsumer, incarnation: str) -> str:
    """A gateway's consumer's description: what it was made for. One that begins at the last messages is
    made for one outbox (a gateway whose outbox is new has none of what it read before)."""
    return f"gateway {name}, outbox {incarnation}" if consumer.last else f"gateway {name}"


async def ensure_gateway_consumers(
    js: JetStreamContext, name: str, incarnation: str, deployment: Deployment = UNNAMED
) -> list[str]:
    """Gateway ``name``'s consumers (``access.gateway_consumers``), made by the center, which the gateway
    binds to: created if missing, and those that begin at the last messages (its schedule, its SYNC
    budgets) made anew for an outbox ``incarnation`` they were not made for; the names of those made."""
    made = []
    for consumer in access.gateway_consumers(name, deployment):
        owner = _owner(name, consumer, incarnation)
        try:
            info = await js.consumer_info(consumer.stream, consumer.name)
        except NotFoundError:
            info = None
        if info is not None and info.config.description == owner:
            continue
        if info is not None and not consumer.last:
            continue  # the commands: the same for any outbox
        if info is not None:
            await js.delete_consumer(consumer.stream, consumer.name)
        await js.add_consumer(
            consumer.stream,
            ConsumerConfig(
                durable_name=consumer.name,
                description=owner,
                filter_subject=consumer.subject,
                ack_policy=AckPolicy.EXPLICIT,
                ack_wait=GATEWAY_ACK_WAIT,
                deliver_policy=DeliverPolicy.LAST_PER_SUBJECT if consumer.last else DeliverPolicy.ALL,
            ),
        )
        made.append(consumer.name)
    if made:
        log.info("backhaul: gateway %s's consumers %s made (outbox %s)", name, made, incarnation)
    return made


async def bind(
    js: JetStreamContext, consumer: GatewayConsumer, who: str
) -> JetStreamContext.PullSubscription:
    """A gateway's consumer once the center has made it: waits (said once in the log) while it does not
    exist yet, or the broker does not answer."""
    said = ""
    while True:
        try:
            await js.consumer_info(consumer.stream, consumer.name)
            return await js.pull_subscribe_bind(durable=consumer.name, stream=consumer.stream)
        except NotFoundError:
            why = f"waiting for the center to make its consumer {consumer.name} on {consumer.stream}"
        except (NatsError, TimeoutError) as exc:
            stop_if_cancelled()
            why = f"consumer {consumer.name} not reachable yet ({type(exc).__name__}); retrying"
        if why != said:
            log.info("%s: %s", who, why)
            said = why
        await asyncio.sleep(0.5)


def stop_if_cancelled() -> None:
    """Raise CancelledError if this task is being cancelled: nats-py turns a cancellation that comes
    during a request or a fetch into its TimeoutError, which a retrying loop would swallow for ever."""
    task = asyncio.current_task()
    if task is not None and task.cancelling():
        raise asyncio.CancelledError
