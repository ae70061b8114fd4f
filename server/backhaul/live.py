"""Live events across the center's processes. Each process decodes only its partitions' vehicles, but a
browser is connected to one process: every event on a process's bus (a packet stored, a command's new
status, a check-point, ...) is published on core NATS ``tacit.v1.live.<instance>`` while other processes
are alive, and each process shows the others' to its browsers' event streams (``Bus.show``, which
calls no handler: the safety checks, the team missions and the 3D map's handlers react in the process
where the event happened, once). Core NATS, not a stream: a live event missed while the broker is away is not replayed
(the screens read the database).
"""

from __future__ import annotations

import asyncio
import json
import logging

from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.errors import Error as NatsError

from server.backhaul import subjects
from server.core.events import Bus, Event, Relayed

log = logging.getLogger("tacit.backhaul.live")


class Live:
    def __init__(self, bus: Bus, instance: str, deployment: subjects.Deployment = subjects.UNNAMED) -> None:
        self.bus = bus
        self.deployment = deployment
        self.subject = deployment.subject(subjects.live(instance))
        self.peers = False  # other center processes are alive: publish (set by the leases' renewal)
        self.nc: Client | None = None
        self._sending: set[asyncio.Task[None]] = set()
        bus.on_event(self._out)

    async def start(self, nc: Client) -> None:
        self.nc = nc
        await nc.subscribe(self.deployment.subject(subjects.live()), cb=self._in)

    def _out(self, event: Event) -> None:
        """A local event (from the event loop), to the other processes."""
        if self.nc is None or not self.peers:
            return
        task = asyncio.create_task(self._send(self.nc, json.dumps(event.as_dict()).encode()))
        self._sending.add(task)
        task.add_done_callback(self._sending.discard)

    async def _send(self, nc: Client, payload: bytes) -> None:
        try:
            await nc.publish(self.subject, payload)
        except (NatsError, OSError) as exc:  # the broker away: live events are not kept
            log.debug("live event not sent: %s", exc)

    async def _in(self, msg: Msg) -> None:
        if msg.subject == self.subject:
            return
        try:
            body = json.loads(msg.data)
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            log.error("live event on %s refused: %s", msg.subject, exc)
            return
        if not isinstance(body, dict) or not isinstance(body.get("kind"), str):
            log.error("live event on %s refused: not an event", msg.subject)
            return
        self.bus.show(Relayed(body=body))
