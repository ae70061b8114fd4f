"""The broker, as both ends use it: a connection that is retried until the broker answers (and then
reconnects by itself, forever), and the JetStream streams, created or brought to this configuration.

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
from nats.js.api import RetentionPolicy, StorageType, StreamConfig
from nats.js.errors import BadRequestError

from server.backhaul import subjects
from server.backhaul.access import BrokerAuth

log = logging.getLogger("tacit.backhaul.broker")
# A link that goes silent (a cellular or satellite backhaul lost, no reset) is taken for down after this
# many unanswered pings, one every PING_INTERVAL s (the client's default waits four minutes).
PING_INTERVAL = 5.0
MAX_OUTSTANDING_PINGS = 2


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


def stream_configs(duplicate_window: float = subjects.DUPLICATE_WINDOW) -> list[StreamConfig]:
    """The streams: frames (kept until the center has them: limits by size and age, not by interest, so
    a center away for hours finds them), commands, events, each gateway's last schedule (a gateway
    restarting finds its slots, center or not) and the last SYNC budget of each gateway and vehicle.
    File storage: a broker restart loses none."""
    return [
        StreamConfig(name=subjects.FRAMES_STREAM, subjects=[subjects.frames(">")],
                     storage=StorageType.FILE, retention=RetentionPolicy.LIMITS, duplicate_window=duplicate_window,
                     max_age=7 * 86400.0),
        StreamConfig(name=subjects.COMMANDS_STREAM, subjects=[subjects.commands(">")], storage=StorageType.FILE,
                     retention=RetentionPolicy.LIMITS, duplicate_window=duplicate_window,
                     max_age=subjects.COMMAND_MAX_AGE),
        StreamConfig(name=subjects.EVENTS_STREAM, subjects=[subjects.events(">")], storage=StorageType.FILE,
                     retention=RetentionPolicy.LIMITS, duplicate_window=duplicate_window,
                     max_age=subjects.EVENTS_MAX_AGE),
        StreamConfig(name=subjects.SCHEDULE_STREAM, subjects=[subjects.schedule(">")], storage=StorageType.FILE,
                     retention=RetentionPolicy.LIMITS, max_msgs_per_subject=1),
        StreamConfig(name=subjects.SYNCS_STREAM, subjects=[subjects.syncs(">")], storage=StorageType.FILE,
                     retention=RetentionPolicy.LIMITS, duplicate_window=duplicate_window, max_msgs_per_subject=1),
    ]  # fmt: skip


async def ensure_streams(js: JetStreamContext, duplicate_window: float = subjects.DUPLICATE_WINDOW) -> None:
    """Create the streams, or update them to this configuration (gateways and the center both call it;
    whoever comes first creates them)."""
    for config in stream_configs(duplicate_window):
        try:
            await js.add_stream(config)
        except BadRequestError:  # exists with another configuration
            await js.update_stream(config)
