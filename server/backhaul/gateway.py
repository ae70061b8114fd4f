"""A gateway: one shore modem's process, on a ship, a buoy or a pier. Every frame its modem hears is
committed to the local outbox first (``server.backhaul.outbox``), then published to the center over the
backhaul in order; commands the center signed come down, are kept in the outbox file, and their attempt
outcomes go up as events. It holds no vehicle key (docs/protocol.md).

The MAC: one exchange per slot of the TDMA frame the center hands the gateways sharing the band
(``gateway.slots``): a command's next attempt (SYNCs are commands here) or a poll of the next
vehicle of the center's poll list (its answer, heard by this gateway's modem, goes up as frames; the
center scores the gateways by them), taking turns when both wait. The center's SYNCs come first, each in
the slot it was stamped for: a SYNC's time sets the vehicle's clock, so it goes only within
``SYNC_WINDOW`` of its stamp (one waits for it; one past it is reported expired, and the center signs
another), and the vehicle's newest replaces one still waiting. Without a plan a gateway alone on its
band sends its commands at will and polls nobody. A command that reaches the gateway after its ``start_by`` is not sent: the center has sent it
through another gateway by then. A gateway transmits nothing before it has read the last schedule the
stream keeps for it (a restart resumes its stored commands in its slots).

The SYNC budget: for each vehicle the center assigns to it, the gateway keeps the SYNCs the center
pre-signed for the coming hours (in its outbox file: a restart keeps them), and when the center's own
SYNCs for that vehicle have not come for two intervals (a backhaul outage, a center down) it sends the
newest whose time has come, one per interval, in its slots before the commands; a vehicle that moves to
another gateway has its budget here withdrawn. It cannot make one: it holds no key (docs/protocol.md).

Imports the standard library, the core (``tacit.modem``, ``tacit.packets``) and nats-py only: ``tacit[gateway]`` has no web
stack (tests/integration/server/test_backhaul.py checks that fastapi, sqlmodel and sqlalchemy are not loaded).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import math
import os
import sys
import time
from collections import deque
from collections.abc import Awaitable, Callable
from pathlib import Path

from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.errors import Error as NatsError
from nats.js import JetStreamContext
from nats.js.errors import NotFoundError

from gateway.slots import ATTEMPT_AIRTIME, SYNC_WINDOW, Schedule, SlotPlan
from server.backhaul import access, broker, subjects
from server.backhaul.access import BrokerAuth
from server.backhaul.outbox import PUBLISH_TIMEOUT, Outbox, Publisher
from server.backhaul.subjects import (
    UNNAMED,
    CommandMessage,
    Deployment,
    EventMessage,
    GatewayState,
    Outage,
    PayloadError,
    Place,
    ScheduleMessage,
    SyncBudgetMessage,
)
from tacit import modem as mm
from tacit.packets import Command, ControlFlag, PacketError, decode_control

log = logging.getLogger("tacit.backhaul.gateway")


class Gateway:
    def __init__(
        self,
        outbox: Outbox,
        url: str,
        driver: mm.ModemDriver | None = None,
        heartbeat: float = subjects.HEARTBEAT,
        duplicate_window: float = subjects.DUPLICATE_WINDOW,
        auth: BrokerAuth | None = None,
        place: Place | None = None,
        address: int | None = None,
        deployment: Deployment = UNNAMED,
    ) -> None:
        """``place``: where its modem is (the screens show it); ``address``: its modem's; ``deployment``:
        the split shore it belongs to on its broker."""
        self.outbox = outbox
        self.auth = auth or BrokerAuth()
        self.deployment = deployment
        self.consumers = access.gateway_consumers(outbox.gateway, deployment)  # made by the center
        self.name = outbox.gateway
        self.url = url
        self.driver = driver
        self.heartbeat = heartbeat
        self.duplicate_window = duplicate_window
        self.nc: Client | None = None
        self.publisher: Publisher | None = None
        self.backhaul = False  # connected to the broker
        self.place = place
        self.address = address
        self.down_since: float | None = None  # when the backhaul went down (None: up, or never connected)
        self.outage: Outage | None = None  # the last outage, said in every heartbeat after it
        self._beat_now = asyncio.Event()  # a heartbeat at once: the backhaul came back
        self.schedule = Schedule()  # the center's TDMA frames; none: transmit at will
        self.polls: tuple[int, ...] = ()  # the vehicles' addresses the center asks this gateway to poll
        self.queue: deque[tuple[CommandMessage, int]] = deque()  # commands to send, attempts made
        self.syncs: dict[int, CommandMessage] = {}  # the center's SYNC waiting for its time, by address
        self._polled = 0
        self._commanded = False  # the last slot carried a command
        self._work = asyncio.Event()
        self._planned = asyncio.Event()  # the schedule the stream keeps for it was read, or there is none
        self.transmissions: list[tuple[float, float]] = []  # (start, end) of each attempt, UNIX s
        self._center_synced: dict[int, float] = {}  # by vehicle address: when the center's last SYNC came
        self._budget_used: dict[int, float] = {}  # by vehicle address: when its last pre-signed one left
        self._started = time.monotonic()  # these three on the monotonic clock
        self._tasks: list[asyncio.Task[None]] = []
        if driver is not None:
            driver.add_listener(self.on_modem)

    # --- the modem: store first ------------------------------------------------------------------

    def on_modem(self, event: mm.Event) -> None:
        """A modem event: a frame heard is committed to the outbox before this returns."""
        if isinstance(event, mm.ReceivedFrame):
            self.outbox.add_frame(event.src, event.dest, event.data, *event.reception(), event.time)
        elif isinstance(event, mm.StateChanged):
            self.outbox.add_event("modem", {"state": event.state.value, "detail": event.detail})

    # --- lifecycle -------------------------------------------------------------------------------

    async def start(self) -> None:
        """Connect (waiting for the broker if it does not answer: the outbox keeps storing meanwhile) and
        start publishing, taking commands and beating."""
        if self.driver is not None:  # frames heard from now on are stored, broker or not
            await self.driver.start()
        self.nc = await broker.connect(self.url, f"tacit-gateway-{self.name}", self._state, auth=self.auth)
        js = self.nc.jetstream(prefix=self.auth.api_prefix)  # the streams and consumers are the center's
        self.publisher = Publisher(self.outbox, js, self.deployment)
        self._tasks = [
            asyncio.create_task(self.publisher.run()),
            asyncio.create_task(self._commands(js)),
            asyncio.create_task(self._schedules(js)),
            asyncio.create_task(self._budgets(js)),
            asyncio.create_task(self._beat()),
        ]
        if self.driver is not None:
            for stored in self.outbox.commands("stored"):  # a restart resumes them
                self._keep(stored)
            self._tasks.append(asyncio.create_task(self._mac()))

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._tasks = []
        if self.nc is not None:
            with contextlib.suppress(NatsError, OSError):  # the backhaul may be down: closed all the same
                await self.nc.close()
            self.nc = None
        if self.driver is not None:
            await self.driver.stop()

    def _state(self, up: bool) -> None:
        """The broker connection came or went: an outage is timed, and the heartbeat after it says how
        long it lasted and what waited in the outbox. A silent cut (no reset: a radio link gone) is
        noticed by the client's pings only some seconds on: the outage began at the first publish
        that failed since."""
        self.backhaul = up
        now = time.time()
        if not up:
            failing = self.publisher.failing_since if self.publisher is not None else None
            noticed = broker.PING_INTERVAL * (broker.MAX_OUTSTANDING_PINGS + 1) + PUBLISH_TIMEOUT
            self.down_since = max(failing or now, now - noticed)  # not an older failure of another cause
            return
        if self.down_since is not None:
            self.outage = Outage(now - self.down_since, now, self.outbox.depth())
            self.down_since = None
            log.info(
                "gateway %s: backhaul back after %.0f s, %d messages waiting",
                *(self.name, self.outage.lasted, self.outage.backlog),
            )
        self._beat_now.set()

    # --- commands down ---------------------------------------------------------------------------

    def _bind(self, js: JetStreamContext, which: int) -> Awaitable[JetStreamContext.PullSubscription]:
        """One of its consumers (0 commands, 1 schedule, 2 SYNC budgets), once the center has made it."""
        return broker.bind(js, self.consumers[which], f"gateway {self.name}")

    async def _commands(self, js: JetStreamContext) -> None:
        await _consume(await self._bind(js, 0), self._command)

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
        if subjects.is_sync(command.id):  # the center's SYNCs come: its pre-signed ones wait
            self._center_synced[command.address] = time.monotonic()
        if command.start_by and time.time() > command.start_by:  # the center went through another
            self._final(command, "expired")
            return
        self.outbox.add_event("attempt", {"command": command.id, "outcome": "stored", "attempt": 0})
        if self.driver is not None:
            self._keep(command)
            self._work.set()

    def _keep(self, command: CommandMessage) -> None:
        """Queue a command; a center's SYNC waits for its time apart (its vehicle's newest only)."""
        if not subjects.is_sync(command.id):
            self.queue.append((command, 0))
            return
        older = self.syncs.get(command.address)
        if older is not None:
            self._final(older, "expired")
        self.syncs[command.address] = command

    def _sync_due(self, now: float) -> CommandMessage | None:
        """A center's SYNC whose time is within ``SYNC_WINDOW`` of ``now`` (taken); those past it are
        reported expired."""
        for address, command in list(self.syncs.items()):
            stamp = decode_control(command.data).time
            if now > stamp + SYNC_WINDOW:
                log.info("vehicle %d: SYNC %s missed its slot (stamped %.0f s ago)", address, command.id,
                         now - stamp)  # fmt: skip
                self._final(self.syncs.pop(address), "expired")
            elif now >= stamp - SYNC_WINDOW:
                return self.syncs.pop(address)
        return None

    # --- the MAC: one exchange per slot ------------------------------------------------------------

    async def _mac(self) -> None:
        await self._planned.wait()  # not a transmission at will before the slots it may already have
        while True:
            self._budget_syncs()
            plan = self.schedule.plan(time.time())
            usable = plan.usable if plan is not None and self.name in plan.order else 0.0
            polling = bool(self.polls) and usable > 0  # polls only in slots: never at will
            if not self.queue and not self.syncs and not polling:
                self._work.clear()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._work.wait(), 1.0)
                continue
            start = self.schedule.start(self.name, time.time(), usable or ATTEMPT_AIRTIME)
            await asyncio.sleep(max(0.0, start - time.time()))
            sync = self._sync_due(time.time())
            if sync is not None:  # in the slot it was stamped for: before the commands and polls
                self._final(sync, "acked" if await self._attempt(sync, 1) == "acked" else "failed")
            elif self.queue and not (polling and self._commanded):
                await self._next_attempt()
                self._commanded = True
            elif polling:  # polls and commands take turns: a vehicle's answers come while commands wait
                await self._poll()
                self._commanded = False
            else:  # only a SYNC waiting for its time
                await asyncio.sleep(SYNC_WINDOW / 2)
            await asyncio.sleep(max(0.0, start + usable - time.time()))  # the slot's answers still come

    async def _next_attempt(self) -> None:
        """The first waiting command's next attempt; it leaves the queue when acked, out of attempts or
        expired (each outcome goes up as an event, through the outbox: none is lost)."""
        command, made = self.queue.popleft()
        if command.expires_at and time.time() > command.expires_at:
            self._final(command, "expired")
            return
        outcome = await self._attempt(command, made + 1)
        if outcome == "acked" or made + 1 >= command.attempts:
            self._final(command, "acked" if outcome == "acked" else "failed")
        else:
            self.queue.appendleft((command, made + 1))

    async def _poll(self) -> None:
        """Ask the next vehicle of the poll list for its data (with ACK: its link counts on them)."""
        assert self.driver is not None
        address = self.polls[self._polled % len(self.polls)]
        self._polled += 1
        try:
            await self.driver.poll(address, rate=0, ack=True)
        except mm.ModemError as exc:
            log.warning("poll of %d failed: %s", address, exc)

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

    async def _schedules(self, js: JetStreamContext) -> None:
        """Its schedule: the last the stream keeps for it (a restart resumes its slots, center or not),
        then each new one through its consumer."""
        sub = await self._bind(js, 1)
        await self._last_schedule(js)
        while True:
            try:
                msgs = await sub.fetch(1, timeout=1.0)
            except TimeoutError:
                broker.stop_if_cancelled()
                self._planned.set()  # none kept: at will until the center hands one out
                continue
            except NatsError:  # failed at once (closed, consumer gone): never spin without yielding
                broker.stop_if_cancelled()
                await asyncio.sleep(0.5)
                continue
            for msg in msgs:
                await msg.ack()
                self._schedule(msg.data)
            self._planned.set()

    async def _last_schedule(self, js: JetStreamContext) -> None:
        """The last schedule the stream keeps for this gateway, read directly (none: it waits for one)."""
        consumer = self.consumers[1]
        try:
            msg = await js.get_last_msg(consumer.stream, consumer.subject, direct=True)
        except NotFoundError:
            return
        except (NatsError, TimeoutError) as exc:  # its consumer brings the next one all the same
            broker.stop_if_cancelled()
            log.warning("gateway %s: the last schedule kept not read (%s)", self.name, type(exc).__name__)
            return
        self._schedule(msg.data or b"")

    def _schedule(self, data: bytes) -> None:
        """The center's TDMA frame for the gateways on this band."""
        try:
            schedule = ScheduleMessage.decode(data)
            self.schedule.receive(
                SlotPlan(schedule.epoch, schedule.slot, schedule.guard, schedule.order), time.time()
            )
            self.polls = schedule.poll
            self._work.set()
        except (PayloadError, ValueError) as exc:
            log.error("schedule refused: %s", exc)
            return
        log.info(
            "schedule: slot %.1f s, guard %.1f s, order %s, polling %s",
            *(schedule.slot, schedule.guard, schedule.order, schedule.poll),
        )

    # --- the SYNC budget -------------------------------------------------------------------------

    async def _budgets(self, js: JetStreamContext) -> None:
        await _consume(await self._bind(js, 2), self._budget)

    async def _budget(self, msg: Msg) -> None:
        self.keep_budget(self.deployment.local(msg.subject), msg.data)
        await msg.ack()

    def keep_budget(self, subject: str, data: bytes) -> bool:
        """Keep a vehicle's pre-signed SYNCs (none: drop those kept, withdrawn); a message that is not a
        budget for this gateway on its own subject, or holds anything but scheduled SYNCs, is refused
        (logged). Whether it was kept."""
        try:
            budget = SyncBudgetMessage.decode(data)
            if budget.gateway != self.name or subject != subjects.syncs(self.name, budget.address):
                raise PayloadError(f"one for {budget.gateway}'s vehicle {budget.address} on {subject}")
            packets = [decode_control(frame) for frame in budget.syncs]
        except (PayloadError, PacketError) as exc:
            log.error("SYNC budget refused on %s: %s", subject, exc)
            return False
        if any(p.command is not Command.SYNC or not p.flags & ControlFlag.SCHEDULED for p in packets):
            log.error(
                "SYNC budget %s for vehicle %d refused: not only scheduled SYNCs", budget.id, budget.address
            )
            return False
        if not self.outbox.keep_budget(budget, [p.time for p in packets]):
            return True  # a redelivery: kept already
        if packets:
            last = time.strftime("%H:%M:%S", time.gmtime(max(p.time for p in packets)))
            log.info("vehicle %d: %d pre-signed SYNCs kept, to %s UTC", budget.address, len(packets), last)
        else:
            log.info("vehicle %d: its pre-signed SYNCs withdrawn (%s)", budget.address, budget.id)
        return True

    def _budget_syncs(self) -> None:
        """Queue first a pre-signed SYNC for each vehicle the center's SYNCs have not reached for two
        intervals (its backhaul or the center is down) and that had none from here for one."""
        if self.driver is None:
            return
        now = time.monotonic()
        for budget in self.outbox.budgets():
            quiet = now - self._center_synced.get(budget.address, self._started)
            if (
                quiet < 2 * budget.interval
                or now - self._budget_used.get(budget.address, -math.inf) < budget.interval
            ):
                continue
            taken = self.outbox.take_sync(budget, time.time())
            if taken is None:
                continue
            at, frame = taken
            self._budget_used[budget.address] = now
            command = CommandMessage(
                subjects.sync_id(budget.address, at), self.name, budget.address, frame, attempts=1,
                ack_timeout=budget.ack_timeout, expires_at=at + budget.step,
            )  # fmt: skip
            self.queue.appendleft((command, 0))
            log.info(
                "vehicle %d: pre-signed SYNC %d (due %.0f s ago); none from the center for %.0f s",
                budget.address, at, time.time() - at, quiet,
            )  # fmt: skip

    # --- heartbeat -------------------------------------------------------------------------------

    async def _beat(self) -> None:
        """The gateway's state, every ``heartbeat`` s while connected (not stored: a heartbeat from an
        outage is stale by the time it could go)."""
        while True:
            if self.nc is not None and self.nc.is_connected:
                beat = EventMessage(
                    f"{self.name}-beat-{time.time():.3f}", self.name, "heartbeat", time.time(),
                    self.state().detail(),
                )  # fmt: skip
                with contextlib.suppress(NatsError):
                    await self.nc.publish(self.deployment.subject(subjects.events(self.name)), beat.encode())
            self._beat_now.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._beat_now.wait(), self.heartbeat)

    def state(self) -> GatewayState:
        """What its heartbeat says: its outbox, modem, place and last outage."""
        return GatewayState(
            self.outbox.incarnation,
            self.outbox.depth(),
            self.driver.state.value if self.driver else "none",
            self.address,
            self.place,
            self.outage,
        )


async def _consume(sub: JetStreamContext.PullSubscription, handle: Callable[[Msg], Awaitable[None]]) -> None:
    """Fetch from a pull consumer for ever, each message to ``handle`` in order."""
    while True:
        try:
            msgs = await sub.fetch(16, timeout=1.0)
        except TimeoutError:
            broker.stop_if_cancelled()
            continue
        except NatsError:  # failed at once (closed, consumer gone): never spin without yielding
            broker.stop_if_cancelled()
            await asyncio.sleep(0.5)
            continue
        for msg in msgs:
            await handle(msg)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--nats",
        default=os.environ.get("TACIT_NATS_URL", "nats://127.0.0.1:4222"),
        help="the broker (default TACIT_NATS_URL or %(default)s)",
    )
    access.add_arguments_for_client(parser, os.environ)
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
    parser.add_argument(
        "--position",
        type=_place,
        default=None,
        metavar="NORTH,EAST[,DEPTH]",
        help="where the modem is: metres north and east of the fleet's origin (TACIT_ORIGIN), and its "
        "depth; the center's screens show it (--position=-300,0,1 when it starts with a minus)",
    )


def _place(text: str) -> Place:
    """``--position``'s value; a refusal says what a place is."""
    try:
        return Place.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def run(args: argparse.Namespace) -> int:
    name = subjects.gateway_name(args.name)
    try:
        deployment = Deployment(args.deployment or "")
        who = f"tacit gateway {name}"
        auth = access.client_auth(who, args.nats_credentials, args.nats_ca, args.insecure, deployment)
    except (access.CredentialsError, ValueError) as exc:
        print(f"tacit gateway: {exc}", file=sys.stderr)
        return 2
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
        gateway = Gateway(
            outbox, args.nats, driver, auth=auth, place=args.position,
            address=args.modem_address if driver else None, deployment=deployment,
        )  # fmt: skip
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
