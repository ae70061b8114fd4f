"""A gateway: one shore modem's process, on a ship, a buoy or a pier. Every frame its modem hears is
committed to the local outbox first (``server.backhaul.outbox``), then published to the center over the
backhaul in order; commands the center signed come down, are kept in the outbox file, and their attempt
outcomes go up as events. It holds no vehicle key (docs/protocol.md).

Its medium access is the shore's one MAC (``gateway.mac`` with ``gateway.queue``): the frames the center
signed (SYNCs at their stamp, stops, commands) and polls of the vehicles the center's plan names, at the
rate the SNR allows, in its own slots of the TDMA frame the center hands the gateways sharing the band
(``gateway.slots``), each exchange only if it ends inside its slot. A ``WithdrawMessage`` takes a frame
back. Without a plan a gateway alone on its band sends at will and polls nobody. A command that reaches
the gateway after its ``start_by`` is not sent: the center has sent it through another gateway by then.
A gateway transmits nothing before it has read the last schedule the stream keeps for it (a restart
resumes its stored commands in its slots).

The SYNC budget: for each vehicle the center assigns to it, the gateway keeps the SYNCs the center
pre-signed for the coming hours (in its outbox file: a restart keeps them), and when the center's own
SYNCs for that vehicle have not come for two intervals (a backhaul outage, a center down) it sends the
newest whose time has come, one per interval, in its slots before the commands; a vehicle that moves to
another gateway has its budget here withdrawn. It cannot make one: it holds no key (docs/protocol.md).

Imports the standard library, the core (``tacit.modem``, ``tacit.packets``), the gateway wing and nats-py
only: ``tacit[gateway]`` has no web stack (tests/integration/server/test_backhaul.py checks that fastapi,
sqlmodel and sqlalchemy are not loaded).
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
from collections.abc import Awaitable, Callable
from pathlib import Path

from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.errors import Error as NatsError
from nats.js import JetStreamContext
from nats.js.errors import NotFoundError

from gateway.mac import Mac
from gateway.queue import FrameKind, Held, Outcome, Queue, Report
from gateway.slots import Schedule, SlotPlan
from gateway.timing import Timing
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
    WithdrawMessage,
)
from tacit import modem as mm
from tacit.packets import Command, ControlFlag, PacketError, decode_control

log = logging.getLogger("tacit.backhaul.gateway")
PING_INTERVAL = 300.0  # s: a ping holds a slot of its own; a vehicle's range changes slowly


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
        timing: Timing | None = None,
        ping_interval: float = PING_INTERVAL,
    ) -> None:
        """``place``: where its modem is (the screens show it); ``address``: its modem's; ``deployment``:
        the split shore it belongs to on its broker; ``timing``: its MAC's exchange durations;
        ``ping_interval``: s between two pings of a vehicle of the highest share (``gateway.queue``)."""
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
        self.queue = Queue(timing or Timing(), self._report, ping_interval)
        self.mac = (
            None if driver is None else Mac(self.name, driver, self.queue, self.schedule, self.queue.timing)
        )
        self._planned = asyncio.Event()  # the schedule the stream keeps for it was read, or there is none
        self._center_synced: dict[int, float] = {}  # by vehicle address: when the center's last SYNC came
        self._budget_used: dict[int, float] = {}  # by vehicle address: when its last pre-signed one left
        self._started = time.monotonic()  # these three on the monotonic clock
        self._tasks: list[asyncio.Task[None]] = []
        if driver is not None:
            driver.add_listener(self.on_modem)

    @property
    def polls(self) -> tuple[int, ...]:
        """The vehicles' addresses the center asks this gateway to poll."""
        return self.queue.polled

    @property
    def transmissions(self) -> list[tuple[float, float]]:
        """Each exchange's (start, end) on the air, UNIX s."""
        return [] if self.mac is None else self.mac.transmissions

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
        if self.mac is not None:
            for stored in self.outbox.commands("stored"):  # a restart resumes them
                self.queue.hold(_held(stored))
            self._tasks.append(asyncio.create_task(self._run_mac(self.mac)))

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
        """Keep a command (once, whatever the redeliveries), ack it, report it, send it if a modem is here;
        or take back one held (a withdrawal)."""
        try:
            command = subjects.down(msg.data)
        except PayloadError as exc:
            log.error("command dropped: %s", exc)
            await msg.term()
            return
        if isinstance(command, WithdrawMessage):
            await msg.ack()
            self._withdraw(command)
            return
        fresh = self.outbox.add_command(command, msg.data)
        await msg.ack()
        if not fresh:
            return
        if command.kind is FrameKind.SYNC:  # the center's SYNCs come: its pre-signed ones wait
            self._center_synced[command.address] = time.monotonic()
        if command.start_by and time.time() > command.start_by:  # the center went through another
            self._final(command.id, Outcome.EXPIRED)
            return
        self.outbox.add_event("attempt", {"command": command.id, "outcome": "stored", "attempt": 0})
        if self.mac is not None:
            self.queue.hold(_held(command))
            self.mac.wake()

    def _withdraw(self, withdrawal: WithdrawMessage) -> None:
        """The center took a frame back: not sent again (its end reported ``withdrawn`` if it was held; one
        that ended already keeps its end)."""
        log.info("gateway %s: %s withdrawn (%s)", self.name, withdrawal.command, withdrawal.reason)
        held = self.queue.withdraw(withdrawal.command)
        if not held and any(c.id == withdrawal.command for c in self.outbox.commands("stored")):
            self.outbox.set_command(withdrawal.command, Outcome.WITHDRAWN)  # kept, not sent (no modem)

    async def _run_mac(self, mac: Mac) -> None:
        await self._planned.wait()  # not a transmission at will before the slots it may already have
        budgets = asyncio.create_task(self._budget_loop(mac))
        try:
            await mac.run()
        finally:
            budgets.cancel()

    def _report(self, report: Report) -> None:
        """An attempt of a held frame, or its end, into the outbox (it goes up as an event: none is lost)."""
        if report.final:
            self._final(report.frame.id, report.outcome)
        else:
            self.outbox.add_event(
                "attempt", {"command": report.frame.id, "outcome": report.outcome, "attempt": report.attempt}
            )

    def _final(self, command_id: str, outcome: Outcome) -> None:
        self.outbox.set_command(command_id, outcome)
        self.outbox.add_event("attempt", {"command": command_id, "outcome": outcome, "final": True})

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
            self.queue.poll(schedule.poll)
            for address, share in schedule.shares:
                self.queue.share(address, share)
            if self.mac is not None:
                self.mac.wake()
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

    async def _budget_loop(self, mac: Mac) -> None:
        while True:
            if self._budget_syncs():
                mac.wake()
            await asyncio.sleep(1.0)

    def _budget_syncs(self) -> bool:
        """Hold a pre-signed SYNC for each vehicle the center's SYNCs have not reached for two intervals
        (its backhaul or the center is down) and that had none from here for one; whether one was."""
        held = False
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
            sync = Held(
                subjects.sync_id(budget.address, at), budget.address, frame, FrameKind.SYNC, attempts=1,
                expires_at=at + budget.step,
            )  # fmt: skip
            held = self.queue.hold(sync) or held
            log.info(
                "vehicle %d: pre-signed SYNC %d (due %.0f s ago); none from the center for %.0f s",
                budget.address, at, time.time() - at, quiet,
            )  # fmt: skip
        return held

    # --- heartbeat -------------------------------------------------------------------------------

    async def _beat(self) -> None:
        """The gateway's state, every ``heartbeat`` s while connected (not stored: a heartbeat from an
        outage is stale by the time it could go)."""
        while True:
            broker.stop_if_cancelled()  # a wait_for that ended as it was cancelled swallows the cancellation
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
        """What its heartbeat says: its outbox, modem, place, last outage and MAC."""
        return GatewayState(
            self.outbox.incarnation,
            self.outbox.depth(),
            self.driver.state.value if self.driver else "none",
            self.address,
            self.place,
            self.outage,
            link=None if self.mac is None else self.mac.detail(),
        )


def _held(command: CommandMessage) -> Held:
    """A command message as the MAC's queue holds it (a SYNC of a center that did not stamp the message
    goes at the time its frame carries)."""
    stamp = command.stamp
    if command.kind is FrameKind.SYNC and not stamp:
        with contextlib.suppress(PacketError):
            stamp = decode_control(command.data).time
    return Held(
        command.id, command.address, command.data, command.kind, command.rank, stamp, command.attempts,
        command.expires_at,
    )  # fmt: skip


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
        "--ping-interval",
        type=float,
        default=PING_INTERVAL,
        help="s between two ranging pings of a vehicle routed through this gateway (others: in proportion "
        "to their share; default %(default)s)",
    )
    parser.add_argument(
        "--time-scale",
        type=float,
        default=1.0,
        help="simulated seconds per wall second of a simulated sea: the MAC's exchanges shorten by it",
    )
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
            timing=Timing(time_scale=args.time_scale), ping_interval=args.ping_interval / args.time_scale,
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
