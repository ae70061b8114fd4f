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
command message ``sync-<address>-<counter>``, its counter at least its time (the budget's rule),
stamped for the opening of the gateway's first slot after it can be there (``SYNC_LEAD``): the center
hands out the slots, so it knows when that gateway transmits next, and the gateway sends it only within
``SYNC_WINDOW`` of that stamp, so the vehicle's clock is set to within seconds of the shore's. One that
misses its window comes back expired and is signed anew (with the same answer, if it carried one). A
vehicle accepts no command before a SYNC has answered its check-points, so its commands wait here until
the center has heard one of its check-points and sent the SYNC answering a challenge in it: of several
center processes, the one that decodes the vehicle (it alone holds its link state) sends its SYNCs and
its commands. A command is signed when it is dispatched: if the vehicle challenges again while its
gateway holds the frame (the answer was lost), the SYNC answering it moves the vehicle's replay floor past
the frame's stamp, so that dispatch is superseded and the command dispatched again, signed anew. For when
SYNCs stop coming (the backhaul cut, the center down), the vehicle's gateway holds a budget of SYNCs
signed ahead (``server.backhaul.budget``), which the dispatcher keeps after the routes.

The dispatcher also hands the gateways their TDMA slots (``gateway.slots``) whenever the set of
live gateways or of vehicles to poll changes. A center that starts finds the plans the stream kept from
the one before it (``kept``): gateways may still follow them, heard from or not, so for its first
``gateway_timeout`` s every gateway they name keeps a slot in its plans (a dead one is dropped after),
and its first epoch leaves the longest kept slot time to end (a different ``tdma_slot``, or time scale,
does not cut a transmission in progress short).
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import math
import time
from collections.abc import Awaitable, Callable

from gateway.queue import FrameKind
from gateway.slots import ATTEMPT_AIRTIME, SYNC_WINDOW, Schedule, SlotPlan
from server.backhaul import subjects
from server.backhaul.budget import Publish, SyncBudgets
from server.backhaul.subjects import (
    CommandMessage,
    EventMessage,
    GatewayState,
    ScheduleMessage,
    WithdrawMessage,
    WithdrawReason,
)
from server.commands.models import CommandRecord, CommandState, Origin, StepSource
from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.db import saved_id
from server.link.heartbeat import Heartbeat, Sync
from server.link.state import VehicleState
from server.routing.models import Dispatch, DispatchState
from server.routing.service import Route, Routing
from server.vehicles.models import Vehicle
from tacit import auth
from tacit.packets import Command

log = logging.getLogger("tacit.backhaul.dispatch")

Kept = Callable[[], Awaitable[list[ScheduleMessage]]]  # the last schedule the stream keeps per gateway
FINAL = {
    "acked": DispatchState.ACKED, "failed": DispatchState.FAILED, "expired": DispatchState.EXPIRED,
    "withdrawn": DispatchState.WITHDRAWN,
}  # fmt: skip
UNSENT = ("withdrawn", "expired")  # a gateway's final word of a frame it never sent
STEP = {"stored": DispatchState.STORED, "sent": DispatchState.SENT, "acked": DispatchState.SENT}
SYNC_LEAD = 1.0  # s: a SYNC published now reaches its gateway before a slot opening this much later
OWN_SHARE = 4.0  # a vehicle's own gateway polls it this many times as often as each other gateway


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
        kept: Kept | None = None,
        coordinating: Callable[[], bool] = lambda: True,
        decoding: Callable[[int], bool] = lambda address: True,
    ) -> None:
        self.desk = desk
        self.routing = routing
        self.settings = settings
        self.publish = publish
        self.heartbeat = heartbeat  # the link's: when a vehicle's SYNC is due, and signing it
        self.states = states  # the vehicles' link states (ingest's), by which SYNCs are due
        self.tick = tick
        self.coordinating = coordinating  # this process runs the routing, the slots and the SYNC budgets
        self.decoding = decoding  # by address: this process decodes the vehicle, its lease fresh
        # the last schedule's gateways, polls and (address, gateway, share) of each vehicle
        self.handed: tuple[tuple[str, ...], tuple[int, ...], tuple[tuple[int, str, float], ...]] = (
            (),
            (),
            (),
        )
        self.kept = kept
        self.inherited: tuple[float, set[str], float] | None = None  # (read at, gateways, slot) of kept plans
        self._published: set[str] = set()  # dispatches published by this process
        self._withdrawn: set[str] = set()  # dispatches this process withdrew (their commands cancelled)
        self.slots = Schedule()  # the TDMA frames handed out: when each gateway transmits next
        self._last_sync: dict[int, tuple[str, Sync]] = {}  # by address: the last SYNC sent, its message id
        self._answer_at: dict[int, float] = {}  # by address: the stamp of the last SYNC answering a challenge
        self.budgets = self._budgets()  # the SYNC budgets: in the coordinating process only
        self._followed = -math.inf  # when a process that does not coordinate last read the slots handed out
        self._wake = asyncio.Event()
        self._loop: asyncio.AbstractEventLoop | None = None

    def _budgets(self) -> SyncBudgets:
        return SyncBudgets(
            self.settings, self.publish, lambda: [g.name for g in self.routing.gateways()], self.ack_timeout
        )

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
        """Re-assign vehicles, hand out slots if the gateways changed, renew the SYNC budgets: while this
        process coordinates. SYNCs and commands in every center process, to the vehicles whose states it
        holds (those it decodes)."""
        now = time.time() if now is None else now
        coordinating = self.coordinating()
        if coordinating:
            await self._withdraw(now)
            for refuted in await asyncio.to_thread(self.routing.audit, now):
                await asyncio.to_thread(self._refuted, refuted)
            await asyncio.to_thread(self.routing.update, now)
        routes = await asyncio.to_thread(self.routing.routes, now)
        if coordinating:
            await self._schedule(now, routes)
        else:
            await self._follow(now)
        await self._syncs(routes)
        if not coordinating:
            if self.budgets.issued or self.budgets.started:  # the role lost: its next holder withdraws them
                self.budgets = self._budgets()
        elif self.heartbeat is not None:  # a center that sends SYNCs: its budgets too (the coordinator's)
            await self.budgets.update(routes, {s.address: s.link.sync_counter for s in self.states()}, now)
        ready = self._commandable(routes, coordinating)
        for route in routes:
            if route.vehicle.address in ready and self.decoding(route.vehicle.address):  # still
                await self._vehicle(route.vehicle, now)

    # --- SYNCs down ------------------------------------------------------------------------------

    async def _syncs(self, routes: list[Route]) -> None:
        """A SYNC to each vehicle whose heartbeat is due, through its gateway (before its commands)."""
        if self.heartbeat is None:
            return
        gateways = {r.vehicle.address: r.gateway for r in routes if r.gateway is not None}
        for state in self.states():
            gateway = gateways.get(state.address)
            if gateway is None or not self.decoding(state.address) or not self.heartbeat.due(state):
                continue
            at = round(self.slots.opening(gateway, time.time() + SYNC_LEAD))
            sync = await self.heartbeat.signed(state, floor=at, at=at)  # counter at least its time
            message = CommandMessage(
                subjects.sync_id(state.address, sync.seq), gateway, state.address, sync.frame, attempts=1,
                ack_timeout=self.ack_timeout(), expires_at=at + SYNC_WINDOW,
                start_by=time.time() + self.settings.dispatch_receipt, kind=FrameKind.SYNC, stamp=at,
            )  # fmt: skip
            await self.publish(subjects.commands(gateway), message.encode(), message.id)
            self.heartbeat.sent(state, sync, acked=False)
            self._last_sync[state.address] = (message.id, sync)
            if sync.echo is not None:
                self._answer_at[state.address] = at

    def _sync_lost(self, command_id: str, expired: bool) -> None:
        """The vehicle's last SYNC missed its slot's window (``expired``: the next step signs another),
        or went unacknowledged: if it answered a challenge, the answer goes again (unless a newer
        challenge came) and the vehicle's commands wait for it."""
        for state in self.states():
            sent = self._last_sync.get(state.address)
            if self.heartbeat is None or sent is None or sent[0] != command_id:
                continue
            if sent[1].echo is not None and state.link.echo is None:
                state.link.echo = sent[1].echo
            if expired or sent[1].echo is not None:
                self.heartbeat.again(state)

    # --- commands down ---------------------------------------------------------------------------

    def _commandable(self, routes: list[Route], coordinating: bool) -> set[int]:
        """The addresses whose commands this process sends now. Where SYNCs are sent, the vehicles it
        decodes (their states are here: of several center processes, only the one that decodes a
        vehicle's check-points knows whether a SYNC has answered them), unless not heard yet, a
        challenge of theirs is not answered (``Heartbeat.synced``: the vehicle would refuse them), or its
        answer's slot has not opened yet (a command sent before the answer would be refused, and one
        stamped before the answer's time less ``FLOOR_SLACK`` is older than the floor that answer sets).
        Where none are, every routed vehicle's, by the coordinating process."""
        if self.heartbeat is None:
            return {r.vehicle.address for r in routes} if coordinating else set()
        now = time.time()
        return {
            s.address
            for s in self.states()
            if self.decoding(s.address)
            and self.heartbeat.synced(s)
            and now >= self._answer_at.get(s.address, 0.0)
        }

    async def _vehicle(self, vehicle: Vehicle, now: float) -> None:
        deadline = now - self.settings.confirm_timeout / self.settings.time_scale  # as the link's timing
        command = await asyncio.to_thread(self.desk.next_to_send, saved_id(vehicle), deadline)
        if command is None:
            return
        tries = await asyncio.to_thread(self.routing.dispatches, saved_id(command))
        acked = [i for i, d in enumerate(tries) if d.state == DispatchState.ACKED]
        round_ = tries[acked[-1] + 1 :] if acked else tries  # an unconfirmed command sent again: anew
        if acked and not round_ and command.status != CommandState.ACKNOWLEDGED:
            return  # its ACK is being recorded (the gateway's report, in the events' task): no new round
        latest = round_[-1] if round_ else None
        ended = latest.updated_at if latest is not None else now  # when the round's last try ended
        if latest is not None and not latest.final:
            if await self._in_flight(latest, command, vehicle, len(tries), now):
                return
            ended = now
        tried = {d.gateway for d in round_ if d.state != DispatchState.SUPERSEDED}
        candidates = await asyncio.to_thread(self.routing.candidates, vehicle, now)
        options = [g for g in candidates if g not in tried]
        if not options and round_ and command.status == CommandState.ACKNOWLEDGED:
            # sent again for want of a check-point, through every gateway in vain: it stays acknowledged
            # (the vehicle's modem did ACK it; it cannot fail), sent again once a confirmation is overdue
            # again, through any gateway alive then
            if ended > deadline or not candidates:
                return
            options = candidates
        if options:
            await self._dispatch(command, vehicle, options[0], len(tries) + 1, now)
        elif round_:
            detail = f"no gateway reached it (tried {', '.join(sorted(tried))})"
            shore = Origin(StepSource.SHORE)
            await asyncio.to_thread(
                self.desk.said, shore, command, CommandState.FAILED, detail, "unreachable"
            )

    async def _in_flight(
        self, latest: Dispatch, command: CommandRecord, vehicle: Vehicle, tries: int, now: float
    ) -> bool:
        """The command's dispatch not final yet: whether it is still in hand (published again if a
        restart cut its publish; superseded and dispatched anew if its frame went stale), or overdue: its
        gateway taken for down, for the next one to try."""
        if self._stale(latest, vehicle.address):
            await asyncio.to_thread(self.routing.set_dispatch, latest.id, DispatchState.SUPERSEDED)
            await self.withdraw(latest, WithdrawReason.SUPERSEDED)  # before the new frame is there
            log.info(
                "vehicle %s: dispatch %s signed before its answering SYNC: anew", vehicle.name, latest.id
            )
            await self._dispatch(command, vehicle, latest.gateway, tries + 1, now)
            return True
        if await self._overdue(latest, now):
            await self.withdraw(latest, WithdrawReason.SUPERSEDED)  # the next gateway sends it, not both
            return False
        if latest.state == DispatchState.PUBLISHED and latest.id not in self._published:
            await self._publish(latest, command, vehicle)  # a restart cut it: the same id
        return True

    def _stale(self, dispatch: Dispatch, address: int) -> bool:
        """The dispatch's frame was signed before the vehicle's replay floor as the SYNC answering its
        challenge since sets it (the answer's time less ``FLOOR_SLACK``): the vehicle would refuse it,
        though its modem ACKs it (a challenge again while the gateway held the frame: an answer lost)."""
        answered = self._answer_at.get(address)
        return answered is not None and dispatch.created_at < answered - auth.FLOOR_SLACK

    async def _overdue(self, dispatch: Dispatch, now: float) -> bool:
        """A dispatch whose receipt is late, whose gateway fell silent (no heartbeat) or was found faulty
        (``Routing.audit``), or that outlived
        its frame's age (the gateway would have said ``expired``): its gateway is taken for down. A
        gateway that stored it and beats is waited for: its attempts share its slots with its polls
        and its other vehicles' commands, so no fixed time bounds them."""
        late = (
            (dispatch.state == DispatchState.PUBLISHED and now > dispatch.start_by)
            or now > dispatch.deadline
            or dispatch.gateway not in await asyncio.to_thread(self.routing.usable, now)
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
        if frame is None:  # cancelled by an operator since it was chosen: never published
            await asyncio.to_thread(self.routing.set_dispatch, row.id, DispatchState.WITHDRAWN)
            return
        stops = Command[command.command.upper()].stops
        message = CommandMessage(
            row.id,
            row.gateway,
            vehicle.address,
            frame,
            attempts=self.settings.command_attempts,
            ack_timeout=self.ack_timeout(),
            expires_at=time.time() + subjects.COMMAND_MAX_AGE,
            start_by=row.start_by,
            kind=FrameKind.STOP if stops else FrameKind.COMMAND,
            rank=command.seq,  # the vehicle's commands in the order queued
        )
        await self.publish(subjects.commands(row.gateway), message.encode(), row.id)
        self._published.add(row.id)

    async def withdraw(self, dispatch: Dispatch, reason: WithdrawReason) -> None:
        """Take back the frame of ``dispatch`` from its gateway (it sends it no more). The broker keeps one
        withdrawal per dispatch: asking twice is harmless."""
        message = WithdrawMessage(subjects.withdraw_id(dispatch.id), dispatch.gateway, dispatch.id, reason)
        await self.publish(subjects.commands(dispatch.gateway), message.encode(), message.id)
        log.info("dispatch %s withdrawn from %s (%s)", dispatch.id, dispatch.gateway, reason)

    def ack_timeout(self) -> float:
        """The ACK wait that fits a slot with the attempt's airtime (faster in a faster simulation) and
        both guards."""
        airtime = ATTEMPT_AIRTIME / self.settings.time_scale
        return max(1.0, self.settings.tdma_slot - 2 * self.settings.tdma_guard - airtime)

    # --- what the gateways report ----------------------------------------------------------------

    async def on_event(self, event: EventMessage) -> None:
        """A gateway's event (the guard let it through): it is alive; a heartbeat's state is kept for the
        screens; an attempt report moves its command."""
        at = min(event.at, time.time())
        if event.kind == "heartbeat":
            await asyncio.to_thread(self.routing.beat, event.gateway, at, GatewayState.of(event.detail))
        else:
            await asyncio.to_thread(self.routing.seen, event.gateway, at)
        if event.kind == "attempt":
            for other in await asyncio.to_thread(self._attempt, event):
                await self.withdraw(other, WithdrawReason.ACKNOWLEDGED)

    def _attempt(self, event: EventMessage) -> list[Dispatch]:
        """A gateway's attempt report, into the dispatch and the command's lifecycle; the dispatches to
        withdraw since (the command's others, once one is acknowledged)."""
        detail = event.detail
        outcome = str(detail.get("outcome", ""))
        final = bool(detail.get("final"))
        state = FINAL.get(outcome) if final else STEP.get(outcome)
        attempt = int(detail.get("attempt") or 0) if outcome in ("sent", "acked") and not final else 0
        if subjects.is_sync(str(detail.get("command", ""))):
            if final and outcome in ("expired", "failed"):
                self._sync_lost(str(detail["command"]), expired=outcome == "expired")
            return []  # sent: the next check-point says whether it arrived
        report = self.routing.report(str(detail.get("command", "")), state, attempt, event.gateway)
        if report is None or report.foreign:
            return []  # unknown, or another gateway's dispatch (logged and counted by the routing)
        if report.dispatch.state == DispatchState.SUPERSEDED:
            return []  # its frame, refused by the vehicle, says nothing of the command
        command, _ = self.desk.get(report.dispatch.command_id)
        said = Origin(StepSource.GATEWAY, event.gateway)
        if report.fresh_attempt:
            lost = (
                ": on the air before its withdrawal, the cancel lost"
                if command.status == CommandState.CANCELLING
                else ""
            )
            self.desk.said(
                said, command, CommandState.SENT, f"attempt {command.attempts + 1} via {event.gateway}{lost}",
                at=event.at, attempts=command.attempts + 1,
            )  # fmt: skip
        elif final and outcome in UNSENT and command.status == CommandState.CANCELLING:
            self.desk.said(
                said, command, CommandState.CANCELLED, f"withdrawn from {event.gateway}: never sent"
            )
        if final and outcome == "acked":
            self.desk.said(said, command, CommandState.ACKNOWLEDGED, f"via {event.gateway}", at=event.at)
            return self._others(report.dispatch)
        return []

    def _others(self, acked: Dispatch) -> list[Dispatch]:
        """The command's other dispatches still held at gateways, superseded: acknowledged through
        ``acked``'s gateway, they are withdrawn (no other gateway sends the frame again)."""
        others = [d for d in self.routing.dispatches(acked.command_id) if d.id != acked.id and not d.final]
        for other in others:
            self.routing.set_dispatch(other.id, DispatchState.SUPERSEDED)
        return others

    async def _withdraw(self, now: float) -> None:
        """The frames of the commands being cancelled taken back from the gateways that hold them (a
        ``WithdrawMessage`` each, once; their words end the cancels, ``_attempt``); one a gateway never
        stored before its ``start_by`` it never sends: cancelled at once."""
        for command in await asyncio.to_thread(self.desk.cancelling):
            for dispatch in await asyncio.to_thread(self.routing.dispatches, saved_id(command)):
                if dispatch.state == DispatchState.PUBLISHED and now > dispatch.start_by:
                    detail = f"{dispatch.gateway} never had it in time: never sent"
                    shore = Origin(StepSource.SHORE)
                    await asyncio.to_thread(self.desk.said, shore, command, CommandState.CANCELLED, detail)
                elif not dispatch.final and dispatch.id not in self._withdrawn:
                    await self.withdraw(dispatch, WithdrawReason.CANCELLED)
                    self._withdrawn.add(dispatch.id)

    def _refuted(self, dispatch: Dispatch) -> None:
        """A gateway's ACK the vehicle's check-points refute: the command is the link's again (sent, not
        acknowledged), for another gateway to send."""
        command, _ = self.desk.get(dispatch.command_id)
        detail = f"{dispatch.gateway}'s acknowledgement refuted by the vehicle's check-points: sent again"
        self.desk.said(Origin(StepSource.VEHICLE), command, CommandState.SENT, detail)

    # --- slots -----------------------------------------------------------------------------------

    async def _schedule(self, now: float, routes: list[Route]) -> None:
        """Hand the live gateways a new TDMA frame when they (or the vehicles they poll, or whose gateway
        each vehicle has) change; it starts two slots from now, so every gateway has it before it
        applies. Every gateway polls every vehicle in its slots (each one's answers score the gateways
        that hear it); a vehicle's own gateway polls it ``OWN_SHARE`` times as often as the others, each
        by the vehicle's share."""
        inherited, lead = await self._inherited(now)
        order = tuple(sorted(await asyncio.to_thread(self.routing.alive, now) | inherited))
        polls = tuple(sorted(r.vehicle.address for r in routes))
        owners = tuple(sorted((r.vehicle.address, r.gateway or "", r.vehicle.share) for r in routes))
        if (order, polls, owners) == self.handed or not order:
            return
        slot = self.settings.tdma_slot
        epoch = math.ceil((now + max(slot, lead)) / slot) * slot
        plan = hashlib.sha256(
            repr((epoch, slot, self.settings.tdma_guard, order, polls, owners)).encode()
        ).hexdigest()
        self.slots.receive(SlotPlan(epoch, slot, self.settings.tdma_guard, order), now)
        for gateway in order:  # the id names the plan: another plan from the same epoch is not a duplicate
            shares = tuple((a, share * (OWN_SHARE if own == gateway else 1.0)) for a, own, share in owners)
            message = ScheduleMessage(f"schedule-{plan[:16]}-{gateway}", gateway, epoch, slot,
                                      self.settings.tdma_guard, order, polls, shares)  # fmt: skip
            await self.publish(subjects.schedule(gateway), message.encode(), message.id)
        log.info("schedule: %d gateways, %.1f s slots from %.0f, polling %s", len(order), slot, epoch, polls)
        self.handed = (order, polls, owners)

    async def _follow(self, now: float) -> None:
        """A process that does not hand out the slots reads them from the stream, once a slot: it stamps
        its own vehicles' SYNCs for their gateways' next slot openings as the coordinator would."""
        if self.kept is None or now < self._followed + self.settings.tdma_slot:
            return
        self._followed = now
        for plan in await self.kept():
            self.slots.receive(SlotPlan(plan.epoch, plan.slot, plan.guard, plan.order), now)

    async def _inherited(self, now: float) -> tuple[set[str], float]:
        """The gateways the plans kept from before this center name (while they may still follow them:
        ``gateway_timeout`` s from the first look), and the longest of their slots."""
        if self.inherited is None:
            plans = await self.kept() if self.kept is not None else []
            names = {name for plan in plans for name in (plan.gateway, *plan.order)}
            for plan in plans[:1]:  # what the gateways follow until this center's first epoch
                self.slots.receive(SlotPlan(plan.epoch, plan.slot, plan.guard, plan.order), now)
            self.inherited = (now, names, max((plan.slot for plan in plans), default=0.0))
            if names:
                log.info("schedule: the kept plans name %s; they keep their slots for now", sorted(names))
        since, names, slot = self.inherited
        return (names, slot) if now < since + self.settings.gateway_timeout else (set(), 0.0)
