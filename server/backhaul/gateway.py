"""A gateway: one shore modem's process, on a ship, a buoy or a pier. Every frame its modem hears is
committed to the local outbox first (``server.backhaul.outbox``), then published to the center over the
backhaul in order; commands the center signed come down, are kept in the outbox file, and their attempt
outcomes go up as events. It holds no vehicle key (docs/protocol.md).

Gateways sharing the band transmit only in their own slots of the TDMA frame the center hands them
(``server.backhaul.slots``; without a plan, a gateway alone on its band transmits at will). A command
that reaches the gateway after its ``start_by`` is not sent: the center has sent it through another
gateway by then. Polling the vehicles (the MAC) and the SYNC budget are the next slice
(docs/backhaul.md).

Imports the standard library, the core (``tacit.modem``) and nats-py only: ``tacit[gateway]`` has no web
stack (tests/integration/server/test_backhaul.py checks that fastapi, sqlmodel and sqlalchemy are not loaded).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import time
from pathlib import Path

from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.errors import Error as NatsError
from nats.js import JetStreamContext
from nats.js.api import AckPolicy, ConsumerConfig, DeliverPolicy

from server.backhaul import broker, subjects
from server.backhaul.outbox import Outbox, Publisher
from server.backhaul.slots import ATTEMPT_AIRTIME, Schedule, SlotPlan
from server.backhaul.subjects import CommandMessage, EventMessage, PayloadError, ScheduleMessage
from tacit import modem as mm

log = logging.getLogger("tacit.backhaul.gateway")


class Gateway:
    def __init__(
        self,
        outbox: Outbox,
        url: str,
        driver: mm.ModemDriver | None = None,
        heartbeat: float = 10.0,
        duplicate_window: float = subjects.DUPLICATE_WINDOW,
    ) -> None:
        self.outbox = outbox
        self.name = outbox.gateway
        self.url = url
        self.driver = driver
        self.heartbeat = heartbeat
        self.duplicate_window = duplicate_window
        self.nc: Client | None = None
        self.publisher: Publisher | None = None
        self.backhaul = False  # connected to the broker
        self.schedule = Schedule()  # the center's TDMA frames; none: transmit at will
        self.transmissions: list[tuple[float, float]] = []  # (start, end) of each attempt, UNIX s
        self._tasks: list[asyncio.Task[None]] = []
        if driver is not None:
            driver.add_listener(self.on_modem)

    # --- the modem: store first ------------------------------------------------------------------

    def on_modem(self, event: mm.Event) -> None:
        """A modem event: a frame heard is committed to the outbox before this returns."""
        if isinstance(event, mm.ReceivedFrame):
            stats = event.stats
            self.outbox.add_frame(
                event.src,
                event.dest,
                event.data,
                stats.rate if stats else 0,
                stats.snr_in if stats else None,
                stats.snr_out if stats else None,
                vars(stats) if stats else None,
                event.time,
            )
        elif isinstance(event, mm.StateChanged):
            self.outbox.add_event("modem", {"state": event.state.value, "detail": event.detail})

    # --- lifecycle -------------------------------------------------------------------------------

    async def start(self) -> None:
        """Connect (waiting for the broker if it does not answer: the outbox keeps storing meanwhile) and
        start publishing, taking commands and beating."""
        if self.driver is not None:  # frames heard from now on are stored, broker or not
            await self.driver.start()
        self.nc = await broker.connect(self.url, f"tacit-gateway-{self.name}", self._state)
        js = self.nc.jetstream()
        await broker.ensure_streams(js, self.duplicate_window)
        self.publisher = Publisher(self.outbox, js)
        commands = await js.pull_subscribe(
            subjects.commands(self.name),
            durable=f"gateway-{self.name}",
            stream=subjects.COMMANDS_STREAM,
            config=ConsumerConfig(ack_policy=AckPolicy.EXPLICIT, ack_wait=30.0),
        )
        await js.subscribe(
            subjects.schedule(self.name),
            stream=subjects.SCHEDULE_STREAM,
            cb=self._schedule,
            ordered_consumer=True,
            deliver_policy=DeliverPolicy.LAST_PER_SUBJECT,
        )
        self._tasks = [
            asyncio.create_task(self.publisher.run()),
            asyncio.create_task(self._commands(commands)),
            asyncio.create_task(self._beat()),
        ]

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._tasks = []
        if self.nc is not None:
            with contextlib.suppress(NatsError):
                await self.nc.close()
            self.nc = None
        if self.driver is not None:
            await self.driver.stop()

    def _state(self, up: bool) -> None:
        self.backhaul = up

    # --- commands down ---------------------------------------------------------------------------

    async def _commands(self, sub: JetStreamContext.PullSubscription) -> None:
        while True:
            try:
                msgs = await sub.fetch(16, timeout=1.0)
            except (TimeoutError, NatsError):
                continue
            for msg in msgs:
                await self._command(msg)

    async def _command(self, msg: Msg) -> None:
        """Keep a command (once, whatever the redeliveries), ack it, report it, send it if a modem is here."""
        try:
            command = CommandMessage.decode(msg.data)
        except PayloadError as exc:
            log.error("command dropped: %s", exc)
            await msg.term()
            return
        fresh = self.outbox.add_command(command, msg.data)
        await msg.ack()
        if not fresh:
            return
        if command.start_by and time.time() > command.start_by:  # the center went through another
            self._final(command, "expired")
            return
        self.outbox.add_event("attempt", {"command": command.id, "outcome": "stored", "attempt": 0})
        if self.driver is not None:
            self._tasks.append(asyncio.create_task(self._send(command)))

    async def _send(self, command: CommandMessage) -> None:
        """The attempts, each in this gateway's slot: each outcome goes up as an event (through the
        outbox: none is lost), then the final one."""
        assert self.driver is not None
        outcome = "failed"
        for attempt in range(1, command.attempts + 1):
            await self._slot(ATTEMPT_AIRTIME + command.ack_timeout)
            if command.expires_at and time.time() > command.expires_at:
                outcome = "expired"
                break
            outcome = await self._attempt(command, attempt)
            if outcome == "acked":
                break
        self._final(
            command, "acked" if outcome == "acked" else "expired" if outcome == "expired" else "failed"
        )

    async def _attempt(self, command: CommandMessage, attempt: int) -> str:
        """One data cycle with ACK: ``acked``, ``sent`` (no ACK) or ``failed`` (not transmitted)."""
        assert self.driver is not None
        started = time.time()
        try:
            result = await self.driver.send(
                command.address, [command.data], ack=True, ack_timeout=command.ack_timeout
            )
        except mm.ModemError as exc:
            self.outbox.add_event(
                "attempt", {"command": command.id, "outcome": "failed", "attempt": attempt, "error": str(exc)}
            )
            return "failed"
        self.transmissions.append((started, time.time()))
        outcome = "acked" if result.all_acked else "sent" if result.transmitted else "failed"
        self.outbox.add_event("attempt", {"command": command.id, "outcome": outcome, "attempt": attempt})
        return outcome

    def _final(self, command: CommandMessage, outcome: str) -> None:
        self.outbox.set_command(command.id, outcome)
        self.outbox.add_event("attempt", {"command": command.id, "outcome": outcome, "final": True})

    async def _slot(self, duration: float) -> None:
        """Wait for this gateway's next slot that holds ``duration`` s (at once without a plan)."""
        start = self.schedule.start(self.name, time.time(), duration)
        await asyncio.sleep(max(0.0, start - time.time()))

    async def _schedule(self, msg: Msg) -> None:
        """The center's TDMA frame for the gateways on this band."""
        try:
            schedule = ScheduleMessage.decode(msg.data)
            self.schedule.receive(
                SlotPlan(schedule.epoch, schedule.slot, schedule.guard, schedule.order), time.time()
            )
        except (PayloadError, ValueError) as exc:
            log.error("schedule refused: %s", exc)
            return
        log.info(
            "schedule: slot %.1f s, guard %.1f s, order %s", schedule.slot, schedule.guard, schedule.order
        )

    # --- heartbeat -------------------------------------------------------------------------------

    async def _beat(self) -> None:
        """The gateway's state, every ``heartbeat`` s while connected (not stored: a heartbeat from an
        outage is stale by the time it could go)."""
        while True:
            if self.nc is not None and self.nc.is_connected:
                detail = {
                    "backhaul": "up",
                    "outbox": self.outbox.depth(),
                    "modem": self.driver.state.value if self.driver else "none",
                }
                beat = EventMessage(
                    f"{self.name}-beat-{time.time():.3f}", self.name, "heartbeat", time.time(), detail
                )
                with contextlib.suppress(NatsError):
                    await self.nc.publish(subjects.events(self.name), beat.encode())
            await asyncio.sleep(self.heartbeat)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--nats", default="nats://127.0.0.1:4222", help="the broker (default %(default)s)")
    parser.add_argument(
        "--name", required=True, help="this gateway's name, a subject token (ship, buoy, pier)"
    )
    parser.add_argument(
        "--outbox", type=Path, default=None, help="the local store (SQLite file; default gateway-NAME.db)"
    )
    parser.add_argument(
        "--modem-url", default="", help="the shore modem: a serial port, or socket://host:port"
    )
    parser.add_argument("--modem-address", type=int, default=0, help="the shore modem's address (default 0)")
    parser.add_argument("--modem-log", default=None, help="append the modem's sentences to this file")


def run(args: argparse.Namespace) -> int:
    name = subjects.gateway_name(args.name)
    outbox = Outbox(args.outbox or Path(f"gateway-{name}.db"), name)
    driver = None
    if args.modem_url:
        driver = mm.ModemDriver(
            mm.DriverSettings(
                url=args.modem_url, address=args.modem_address, log_path=args.modem_log, keepalive=10.0
            )
        )
    else:
        log.warning("no modem (--modem-url): relaying nothing but commands' receipts")

    async def main() -> None:
        gateway = Gateway(outbox, args.nats, driver)
        await gateway.start()
        log.info(
            "gateway %s: outbox %s (%d waiting), publishing to %s",
            name,
            args.outbox,
            outbox.depth(),
            args.nats,
        )
        try:
            await asyncio.Event().wait()
        finally:
            await gateway.stop()
            outbox.close()

    asyncio.run(main())
    return 0
