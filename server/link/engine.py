"""The link engine: owns the shore Micro-Modem and runs the shore half of the protocol.

The MAC schedule: the shore polls, as goby's polled MAC does, so transmissions never collide even with
several vehicles on one channel. Before each slot the engine asks ``server.link.schedule`` which vehicle
has it (commands first, then urgent data, each vehicle in proportion to its share; ``schedule_status()``
publishes the plan); in a vehicle's slot the shore sends its authenticated heartbeat first when one is
due (``server.link.heartbeat``: SYNC; it does not end the slot), then its next command
(``server.link.delivery``: attempts, ACKs, retries) unless commands have had their share of its slots,
or, with no command to send, pings it
when a range is due (``server.link.ranging``) and polls it for data at the rate ``tacit.link.choose_rate``
picks from the recent SNR. Slot lengths come from ``server.link.timing``. Received frames go to one
ingest worker (``server.link.ingest``) in arrival order; every database access runs off this event loop
(``server.link.store``), so a slow or locked database never delays the modem.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import Any

from sqlalchemy import Engine

from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.events import Bus, LinkNotice
from server.link.delivery import Delivery
from server.link.heartbeat import Heartbeat
from server.link.ingest import Ingest
from server.link.models import LinkEvent
from server.link.ranging import Ranging
from server.link.schedule import Schedule, SlotReason, Wants
from server.link.state import IncomingFrame, VehicleState
from server.link.store import LinkStore
from server.link.timing import Timing
from server.telemetry.models import Frame
from server.vehicles.service import Vehicles
from tacit import modem as mm
from tacit.link import choose_rate

log = logging.getLogger("tacit.server.link")


class LinkEngine:
    def __init__(
        self, settings: Settings, db: Engine, bus: Bus, ingest: Ingest, desk: CommandDesk, vehicles: Vehicles
    ) -> None:
        self.settings = settings
        self.bus = bus
        self.ingest = ingest
        self.store = LinkStore(db)
        self.timing = Timing(settings)
        self.delivery = Delivery(settings, self.store, desk, self.timing)
        self.ranging = Ranging(settings, self.store, bus, self.timing)
        self.heartbeat = Heartbeat(settings, self.store, self.timing, vehicles, ingest.next_sync)
        self.schedule = Schedule(settings.command_share)
        self.plan: list[tuple[VehicleState, SlotReason]] = []  # the order of the next slots, as last planned
        self.planned_at: float | None = None
        self.driver: mm.ModemDriver | None = None
        self._wake = asyncio.Event()
        self._heard: dict[int, asyncio.Event] = {}
        self._task: asyncio.Task[None] | None = None
        self._frames: asyncio.Queue[IncomingFrame] = asyncio.Queue()
        self._worker: asyncio.Task[None] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self.started_at = time.time()
        self.counters = {"polls": 0, "frames_in": 0}

    # --- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        await asyncio.to_thread(self.ingest.load_vehicles)  # rebuilding decoders can take seconds
        self._worker = asyncio.create_task(self._ingest())
        if not self.settings.modem_url:
            if not self.ingest.relayed:  # a center has no modem of its own: its gateways have them
                log.warning("no shore modem configured (TACIT_MODEM_URL): API and storage only")
            return
        scale = self.settings.time_scale
        self.driver = mm.ModemDriver(
            mm.DriverSettings(
                url=self.settings.modem_url,
                address=self.settings.modem_address,
                log_path=self.settings.modem_log or None,
                drq_timeout=max(2.0, 10.0 / scale),
                transmit_timeout=max(3.0, 30.0 / scale),
                keepalive=10.0,
            )
        )
        self.driver.add_listener(self._on_modem)
        await self.driver.start()
        self._task = asyncio.create_task(self._run())

    async def stop(self) -> None:
        for task in (self._task, self._worker):
            if task:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        if self.driver:
            await self.driver.stop()
        await asyncio.to_thread(self.ingest.save_states)  # a restart then has no frames to replay

    def wake(self) -> None:
        """Something was queued: start the next slot now instead of after the idle wait. Safe from any
        thread (routes run in a thread pool, the map in viser's thread)."""
        if self._loop is None:
            return
        try:
            on_loop = asyncio.get_running_loop() is self._loop
        except RuntimeError:
            on_loop = False
        if on_loop:
            self._wake.set()
        else:
            self._loop.call_soon_threadsafe(self._wake.set)

    def vehicles_changed(self) -> None:
        self.ingest.load_vehicles()
        self.wake()

    def share_changed(self, vehicle_id: int, share: float) -> None:
        """An operator changed the vehicle's share of the channel: the schedule weighs it from the next slot."""
        for vehicle in self.ingest.states():
            if vehicle.id == vehicle_id:
                vehicle.share = share

    # --- modem events ---------------------------------------------------------------------------

    def _on_modem(self, event: mm.Event) -> None:
        if isinstance(event, mm.ReceivedFrame):
            self.counters["frames_in"] += 1
            frame = IncomingFrame(event.src, event.dest, event.data, *event.reception(), event.time)
            self._frames.put_nowait(frame)
        elif isinstance(event, mm.StateChanged):
            self.bus.publish(
                LinkNotice(event="modem", detail={"state": event.state.value, "detail": event.detail})
            )
            self.store.add_later(
                LinkEvent(kind="modem_state", detail={"state": event.state.value, "detail": event.detail})
            )
        elif isinstance(event, mm.FrameBad) and event.reason == "timeout":
            for heard in self._heard.values():
                heard.set()

    async def _ingest(self) -> None:
        """One worker stores frames in arrival order; what queued up meanwhile goes in one commit."""
        while True:
            batch = [await self._frames.get()]
            while not self._frames.empty() and len(batch) < 500:
                batch.append(self._frames.get_nowait())
            try:
                await self.store.run(self.ingest.handle_batch, batch)
            except Exception:  # not the database being busy (that is retried): one by one, keep running
                log.exception("%d frame(s) could not be stored together: storing them one by one", len(batch))
                await self._one_by_one(batch)
            for frame in batch:
                heard = self._heard.get(frame.src)
                if heard is not None:
                    heard.set()

    async def _one_by_one(self, batch: list[IncomingFrame]) -> None:
        """Each frame in its own transaction; one that still cannot be handled is kept as it came
        (the raw frame and a link event), never dropped: the modem has already acknowledged it."""
        for frame in batch:
            try:
                await self.store.run(self.ingest.handle_batch, [frame])
            except Exception as exc:
                log.exception("frame from %d could not be handled: kept raw", frame.src)
                await self.store.add(
                    Frame(
                        direction="in",
                        src=frame.src,
                        dest=frame.dest,
                        rate=frame.rate,
                        data=frame.data,
                        at=frame.at,
                    ),
                    LinkEvent(kind="ingest_failed", detail={"src": frame.src, "error": repr(exc)[:200]}),
                )

    # --- the schedule ---------------------------------------------------------------------------

    async def _run(self) -> None:
        idle = 0  # slots in a row with nothing sent or heard
        while True:
            self._wake.clear()  # a wake from here on (a command queued during the slot) ends the idle pause
            plan = await self._plan()
            busy = False
            if plan:
                vehicle, reason = plan[0]
                try:
                    busy = await self._slot(vehicle)
                except asyncio.CancelledError:
                    raise
                except Exception:  # one vehicle's trouble must not stop the others' slots: its slot is spent
                    log.exception("vehicle %s: slot failed", vehicle.name)
                    self.schedule.used(vehicle, reason)
            idle = 0 if busy else idle + 1
            if idle >= max(1, len(plan)):  # a whole round with nothing to do
                idle = 0
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), self.timing.idle_wait())

    async def _plan(self) -> list[tuple[VehicleState, SlotReason]]:
        """The vehicles in the order of the next slots (``server.link.schedule``), kept for ``schedule_status()``."""
        states = self.ingest.states()
        demand = await self.delivery.demand(states)
        wants = {
            v.address: (v, Wants(command, in_flight, self.heartbeat.due(v)))
            for v, (command, in_flight) in zip(states, demand, strict=True)
        }
        self.plan, self.planned_at = self.schedule.order(wants), time.time()
        return self.plan

    async def _slot(self, vehicle: VehicleState) -> bool:
        """One vehicle's slot; True if something was sent or heard (or may still be: no idle pause)."""
        driver = self.driver
        if driver is None or driver.state is not mm.LinkState.READY:
            return False
        if self.heartbeat.due(vehicle) and not await self.heartbeat.sync(driver, vehicle):
            return True  # our modem was busy: the SYNC goes first in the next slot (an unsynced vehicle
        # takes no command before it); one on the air does not end the slot: a SYNC never costs a poll
        turn = self.schedule.command_turn(vehicle)  # commands share its slots with polls (schedule.py)
        if not self.heartbeat.synced(vehicle):
            turn = False  # it would refuse a command before its first check-point was heard and answered
        command = await self.delivery.next_command(vehicle.id) if turn else None
        if command is not None:
            if await self.delivery.attempt(driver, vehicle, command):
                self.schedule.used(vehicle, SlotReason.COMMAND)
            return True
        if self.ranging.due(vehicle):
            await self.ranging.ping(driver, vehicle)
        heard = await self._poll(driver, vehicle)
        return heard is not False or not turn  # commands may still wait: no idle pause before the next slot

    async def _poll(self, driver: mm.ModemDriver, vehicle: VehicleState) -> bool | None:
        """Poll the vehicle for its data; whether it answered, or None if our modem was still busy with the
        last cycle (the slot was not used: it stays the vehicle's after a short wait)."""
        rate = self._rate(vehicle)
        heard = self._heard.setdefault(vehicle.address, asyncio.Event())
        heard.clear()
        window = self.timing.poll_window(vehicle, rate)
        try:
            await driver.poll(vehicle.address, rate=rate, ack=True)
        except mm.ModemBusy:
            await asyncio.sleep(self.timing.busy_wait())
            return None
        except mm.ModemError as exc:
            log.info("vehicle %s: poll not sent: %s", vehicle.name, exc)
            self.schedule.used(vehicle, SlotReason.POLL)
            return False
        self.counters["polls"] += 1
        self.schedule.used(vehicle, SlotReason.POLL)
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(heard.wait(), window)
        return (
            heard.is_set()
            and vehicle.last_heard is not None
            and time.time() - vehicle.last_heard < window + 1
        )

    @staticmethod
    def _rate(vehicle: VehicleState) -> int:
        return choose_rate(vehicle.snr_in, loss_sensitive=False, packets=4)

    # --- status ---------------------------------------------------------------------------------

    def schedule_status(self) -> dict[str, Any]:
        """The MAC's plan as last made: per vehicle (next slot first) its share, when it was last polled
        and commanded, when its next slot is expected (after the slots of those ahead of it, each as long
        as the channel's timing at that vehicle's range) and why."""
        expected = self.planned_at or time.time()
        vehicles = []
        for vehicle, reason in self.plan:
            turn = self.schedule.turn(vehicle)
            slot = (
                self.timing.ack_timeout(vehicle)
                if reason is SlotReason.COMMAND
                else self.timing.poll_window(vehicle, self._rate(vehicle))
            )
            vehicles.append(
                {
                    "vehicle_id": vehicle.id,
                    "name": vehicle.name,
                    "address": vehicle.address,
                    "share": vehicle.share,
                    "next_slot": reason,
                    "expected_at": expected,
                    "slot_s": slot,
                    "range_m": self.timing.range_m(vehicle),
                    "last_polled": turn.last_polled,
                    "last_commanded": turn.last_commanded,
                    "polls": turn.polls,
                }
            )
            expected += slot
        return {
            "command_share": self.schedule.command_share,
            "planned_at": self.planned_at,
            "vehicles": vehicles,
        }

    def status(self) -> dict[str, Any]:
        modem = self.driver.state.value if self.driver else "none"
        hours = max(1e-9, (time.time() - self.started_at) / 3600)
        vehicles = {}
        for v in self.ingest.states():
            vehicles[v.name] = {
                "address": v.address, "last_heard": v.last_heard, "snr_in": v.snr_in, "snr_out": v.snr_out,
                "range_m": v.range_m, "frames": v.frames, "packets": v.packets, "duplicates": v.duplicates,
                "packets_per_hour": round(v.packets / hours, 1), "bytes_saved": v.bytes_saved,
                "checkpoint": v.link.checkpoint, "old_protocol": v.old_protocol,
            }  # fmt: skip
        counters = {
            **self.counters,
            **self.delivery.counters,
            "pings": self.ranging.pings,
            "syncs": self.heartbeat.syncs,
        }
        return {
            "modem": modem,
            "address": self.settings.modem_address,
            "counters": counters,
            "ingest": dict(self.ingest.stats),
            "strangers": dict(self.ingest.strangers),
            "vehicles": vehicles,
        }
