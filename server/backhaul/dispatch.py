"""The center's command path: each command queued at the center (the REST API, the map, missions) goes
down to the gateway of its vehicle, signed at dispatch, and the gateway's reports move its lifecycle.

One **dispatch** per gateway tried, its id the command message's (``cmd-<command id>-<n>``): the row is
committed before the publish, and a publish that failed or was cut by a center restart is made again
with the same id, which the broker (within its window) and the gateway's store (always) keep once. A
dispatch whose gateway has not reported it stored by ``start_by`` (the gateway is down, or its backhaul
is), whose gateway fell silent (no heartbeat for ``gateway_timeout``), that outlived its frame's age
(``deadline``), or that ended without an ACK, is followed by
a dispatch through the next gateway that heard the vehicle (``Routing.candidates``); when none is left
the command has failed. A gateway that gets a command after its ``start_by`` does not send it, so the
vehicle does not get it from both (and if a receipt is merely late, the vehicle's sequence window still
executes the command once).

SYNCs go the same way: the center holds the keys, so it signs each vehicle's SYNC when the heartbeat
says it is due (``server.link.heartbeat``: an unsynced check-point waits for its answer, a chain restart
is needed, or ``sync_interval`` has passed) and sends it to the vehicle's gateway as a one-attempt
command message ``sync-<address>-<counter>``; a vehicle accepts no command before a SYNC has answered
its check-points. Only while the backhaul is up: a budget of pre-signed SYNCs for a gateway cut off
longer than a vehicle's link-lost timeout is not built yet (docs/backhaul.md).

The dispatcher also hands the gateways their TDMA slots (``server.backhaul.slots``) whenever the set of
live gateways or of vehicles to poll changes.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import math
import time
from collections.abc import Awaitable, Callable

from server.backhaul import subjects
from server.backhaul.slots import ATTEMPT_AIRTIME
from server.backhaul.subjects import CommandMessage, EventMessage, ScheduleMessage
from server.commands.models import CommandRecord, CommandState
from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.db import saved_id
from server.link.heartbeat import Heartbeat
from server.link.state import VehicleState
from server.routing.models import Dispatch, DispatchState
from server.routing.service import Route, Routing
from server.vehicles.models import Vehicle

log = logging.getLogger("tacit.backhaul.dispatch")

Publish = Callable[[str, bytes, str], Awaitable[None]]  # subject, payload, message id
FINAL = {"acked": DispatchState.ACKED, "failed": DispatchState.FAILED, "expired": DispatchState.EXPIRED}
STEP = {"stored": DispatchState.STORED, "sent": DispatchState.SENT, "acked": DispatchState.SENT}


class Dispatcher:
    def __init__(
        self,
        desk: CommandDesk,
        routing: Routing,
        settings: Settings,
        publish: Publish,
        heartbeat: Heartbeat | None = None,
        states: Callable[[], list[VehicleState]] = list,
        tick: float = 0.5,
    ) -> None:
        self.desk = desk
        self.routing = routing
        self.settings = settings
        self.publish = publish
        self.heartbeat = heartbeat  # the link's: when a vehicle's SYNC is due, and signing it
        self.states = states  # the vehicles' link states (ingest's), by which SYNCs are due
        self.tick = tick
        self.handed: tuple[tuple[str, ...], tuple[int, ...]] = ((), ())  # the last schedule's gateways, polls
        self._published: set[str] = set()  # dispatches published by this process
        self._wake = asyncio.Event()
        self._loop: asyncio.AbstractEventLoop | None = None

    def wake(self) -> None:
        """A command was queued: dispatch now rather than at the next tick (from any thread)."""
        loop = self._loop
        if loop is not None:
            loop.call_soon_threadsafe(self._wake.set)

    async def run(self) -> None:
        self._loop = asyncio.get_running_loop()
        while True:
            try:
                await self.step()
            except Exception:  # the database or the broker away: the next tick tries again
                log.exception("dispatch: step failed")
            self._wake.clear()
            try:
                await asyncio.wait_for(self._wake.wait(), self.tick)
            except TimeoutError:
                pass

    async def step(self, now: float | None = None) -> None:
        """Re-assign vehicles, hand out slots if the gateways changed, dispatch what waits."""
        now = time.time() if now is None else now
        await asyncio.to_thread(self.routing.update, now)
        routes = await asyncio.to_thread(self.routing.routes, now)
        await self._schedule(now, tuple(sorted(r.vehicle.address for r in routes)))
        await self._syncs(routes)
        for route in routes:
            await self._vehicle(route.vehicle, now)

    # --- SYNCs down ------------------------------------------------------------------------------

    async def _syncs(self, routes: list[Route]) -> None:
        """A SYNC to each vehicle whose heartbeat is due, through its gateway (before its commands)."""
        if self.heartbeat is None:
            return
        gateways = {r.vehicle.address: r.gateway for r in routes if r.gateway is not None}
        for state in self.states():
            gateway = gateways.get(state.address)
            if gateway is None or not self.heartbeat.due(state):
                continue
            sync = await self.heartbeat.signed(state)
            message = CommandMessage(
                f"sync-{state.address}-{sync.seq}", gateway, state.address, sync.frame, attempts=1,
                ack_timeout=self.ack_timeout(), expires_at=time.time() + self.settings.sync_interval,
                start_by=time.time() + self.settings.dispatch_receipt,
            )  # fmt: skip
            await self.publish(subjects.commands(gateway), message.encode(), message.id)
            self.heartbeat.sent(state, sync, acked=False)

    # --- commands down ---------------------------------------------------------------------------

    async def _vehicle(self, vehicle: Vehicle, now: float) -> None:
        deadline = now - self.settings.confirm_timeout / self.settings.time_scale  # as the link's timing
        command = await asyncio.to_thread(self.desk.next_to_send, saved_id(vehicle), deadline)
        if command is None:
            return
        tries = await asyncio.to_thread(self.routing.dispatches, saved_id(command))
        acked = [i for i, d in enumerate(tries) if d.state == DispatchState.ACKED]
        round_ = tries[acked[-1] + 1 :] if acked else tries  # an unconfirmed command sent again: anew
        latest = round_[-1] if round_ else None
        if latest is not None and not latest.final:
            if not await self._overdue(latest, now):
                if latest.state == DispatchState.PUBLISHED and latest.id not in self._published:
                    await self._publish(latest, command, vehicle)  # a restart cut it: the same id
                return
        tried = {d.gateway for d in round_}
        options = [
            g for g in await asyncio.to_thread(self.routing.candidates, vehicle, now) if g not in tried
        ]
        if options:
            await self._dispatch(command, vehicle, options[0], len(tries) + 1, now)
        elif round_:
            detail = f"no gateway reached it (tried {', '.join(sorted(tried))})"
            await asyncio.to_thread(self.desk.record, command, CommandState.FAILED, detail, "unreachable")

    async def _overdue(self, dispatch: Dispatch, now: float) -> bool:
        """A dispatch whose receipt is late, whose gateway fell silent (no heartbeat), or that outlived
        its frame's age (the gateway would have said ``expired``): its gateway is taken for down. A
        gateway that stored it and beats is waited for: its attempts share its slots with its polls
        and its other vehicles' commands, so no fixed time bounds them."""
        late = (
            (dispatch.state == DispatchState.PUBLISHED and now > dispatch.start_by)
            or now > dispatch.deadline
            or dispatch.gateway not in await asyncio.to_thread(self.routing.alive, now)
        )
        if late:
            log.warning("dispatch %s: %s did not answer in time; next gateway", dispatch.id, dispatch.gateway)
            await asyncio.to_thread(self.routing.set_dispatch, dispatch.id, DispatchState.UNANSWERED)
        return late

    async def _dispatch(
        self, command: CommandRecord, vehicle: Vehicle, gateway: str, n: int, now: float
    ) -> None:
        row = Dispatch(
            id=f"cmd-{saved_id(command)}-{n}",
            command_id=saved_id(command),
            gateway=gateway,
            start_by=now + self.settings.dispatch_receipt,
            deadline=now + self.settings.dispatch_receipt + subjects.COMMAND_MAX_AGE,
        )
        await asyncio.to_thread(self.routing.add_dispatch, row)
        log.info("vehicle %s: command seq %d through %s (%s)", vehicle.name, command.seq, gateway, row.id)
        await self._publish(row, command, vehicle)

    async def _publish(self, row: Dispatch, command: CommandRecord, vehicle: Vehicle) -> None:
        frame = await asyncio.to_thread(self.desk.frame, command)  # signed now: a fresh stamp
        message = CommandMessage(
            row.id,
            row.gateway,
            vehicle.address,
            frame,
            attempts=self.settings.command_attempts,
            ack_timeout=self.ack_timeout(),
            expires_at=time.time() + subjects.COMMAND_MAX_AGE,
            start_by=row.start_by,
        )
        await self.publish(subjects.commands(row.gateway), message.encode(), row.id)
        self._published.add(row.id)

    def ack_timeout(self) -> float:
        """The ACK wait that fits a slot with the attempt's airtime (faster in a faster simulation) and
        both guards."""
        airtime = ATTEMPT_AIRTIME / self.settings.time_scale
        return max(1.0, self.settings.tdma_slot - 2 * self.settings.tdma_guard - airtime)

    # --- what the gateways report ----------------------------------------------------------------

    async def on_event(self, event: EventMessage) -> None:
        await asyncio.to_thread(self.routing.seen, event.gateway, min(event.at, time.time()))
        if event.kind == "attempt":
            await asyncio.to_thread(self._attempt, event)

    def _attempt(self, event: EventMessage) -> None:
        """A gateway's attempt report, into the dispatch and the command's lifecycle."""
        detail = event.detail
        outcome = str(detail.get("outcome", ""))
        final = bool(detail.get("final"))
        state = FINAL.get(outcome) if final else STEP.get(outcome)
        attempt = int(detail.get("attempt") or 0) if outcome in ("sent", "acked") and not final else 0
        if str(detail.get("command", "")).startswith("sync-"):
            return  # a SYNC's outcome: the next check-point says whether it arrived
        report = self.routing.report(str(detail.get("command", "")), state, attempt)
        if report is None:
            log.warning("gateway %s reported an unknown command %s", event.gateway, detail.get("command"))
            return
        command, _ = self.desk.get(report.dispatch.command_id)
        if report.fresh_attempt:
            self.desk.record(
                command, CommandState.SENT, f"attempt {command.attempts + 1} via {event.gateway}",
                at=event.at, attempts=command.attempts + 1,
            )  # fmt: skip
        if final and outcome == "acked":
            self.desk.record(command, CommandState.ACKNOWLEDGED, f"via {event.gateway}", at=event.at)

    # --- slots -----------------------------------------------------------------------------------

    async def _schedule(self, now: float, polls: tuple[int, ...]) -> None:
        """Hand the live gateways a new TDMA frame when they (or the vehicles they poll) change; it
        starts two slots from now, so every gateway has it before it applies. Every gateway polls every
        vehicle in its slots: each one's answers score the gateways that hear it."""
        order = tuple(sorted(await asyncio.to_thread(self.routing.alive, now)))
        if (order, polls) == self.handed or not order:
            return
        slot = self.settings.tdma_slot
        epoch = math.ceil(now / slot) * slot + slot
        plan = hashlib.sha256(
            repr((epoch, slot, self.settings.tdma_guard, order, polls)).encode()
        ).hexdigest()
        for gateway in order:  # the id names the plan: another plan from the same epoch is not a duplicate
            message = ScheduleMessage(f"schedule-{plan[:16]}-{gateway}", gateway, epoch, slot,
                                      self.settings.tdma_guard, order, polls)  # fmt: skip
            await self.publish(subjects.schedule(gateway), message.encode(), message.id)
        log.info("schedule: %d gateways, %.1f s slots from %.0f, polling %s", len(order), slot, epoch, polls)
        self.handed = (order, polls)
