"""The link engine: owns the shore Micro-Modem and runs the shore half of the protocol.

The MAC schedule: the shore polls, as goby's polled MAC does, so transmissions never collide even with
several vehicles on one channel. Slots go round the vehicles; in a vehicle's slot the shore sends its
next command (``server.link.delivery``: attempts, ACKs, retries), or its authenticated heartbeat when
one is due (``server.link.heartbeat``: SYNC), or, with nothing to send, pings it
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

from server.events import EventBus
from server.link.delivery import Delivery
from server.link.heartbeat import Heartbeat
from server.link.ingest import IncomingFrame, Ingest, VehicleState
from server.link.ranging import Ranging
from server.link.store import LinkStore
from server.link.timing import Timing
from server.models import Frame, LinkEvent
from server.settings import Settings
from tacit import modem as mm
from tacit.link import choose_rate

log = logging.getLogger("tacit.server.link")


class LinkEngine:
    def __init__(self, settings: Settings, db: Engine, bus: EventBus, ingest: Ingest) -> None:
        self.settings = settings
        self.bus = bus
        self.ingest = ingest
        self.store = LinkStore(db)
        self.timing = Timing(settings)
        self.delivery = Delivery(settings, self.store, bus, self.timing)
        self.ranging = Ranging(settings, self.store, bus, self.timing)
        self.heartbeat = Heartbeat(settings, self.store, self.timing)
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
            log.warning("no shore modem configured (TACIT_MODEM_URL): API and storage only")
            return
        scale = self.settings.time_scale
        self.driver = mm.ModemDriver(mm.DriverSettings(
            url=self.settings.modem_url, address=self.settings.modem_address,
            log_path=self.settings.modem_log or None, drq_timeout=max(2.0, 10.0 / scale),
            transmit_timeout=max(3.0, 30.0 / scale), keepalive=10.0))  # fmt: skip
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

    # --- modem events ---------------------------------------------------------------------------

    def _on_modem(self, event: mm.Event) -> None:
        if isinstance(event, mm.ReceivedFrame):
            self.counters["frames_in"] += 1
            stats = event.stats
            frame = IncomingFrame(event.src, event.dest, event.data, stats.rate if stats else 0,
                                  stats.snr_in if stats else None, stats.snr_out if stats else None,
                                  vars(stats) if stats else None, event.time)  # fmt: skip
            self._frames.put_nowait(frame)
        elif isinstance(event, mm.StateChanged):
            self.bus.publish("link", event="modem", state=event.state.value, detail=event.detail)
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
                    Frame(direction="in", src=frame.src, dest=frame.dest, rate=frame.rate, data=frame.data, at=frame.at),
                    LinkEvent(kind="ingest_failed", detail={"src": frame.src, "error": repr(exc)[:200]}))  # fmt: skip

    # --- the schedule ---------------------------------------------------------------------------

    async def _run(self) -> None:
        while True:
            busy = False
            for vehicle in list(self.ingest.vehicles.values()):
                try:
                    busy |= await self._slot(vehicle)
                except asyncio.CancelledError:
                    raise
                except Exception:  # one vehicle's trouble must not stop the others' slots
                    log.exception("vehicle %s: slot failed", vehicle.name)
            if not busy:
                self._wake.clear()
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), self.timing.idle_wait())

    async def _slot(self, vehicle: VehicleState) -> bool:
        """One vehicle's slot; True if something was sent or heard."""
        driver = self.driver
        if driver is None or driver.state is not mm.LinkState.READY:
            return False
        command = await self.delivery.next_command(vehicle.id)
        if command is not None:
            await self.delivery.attempt(driver, vehicle, command)
            return True
        if self.heartbeat.due(vehicle):
            await self.heartbeat.sync(driver, vehicle)
            return True
        if self.ranging.due(vehicle):
            await self.ranging.ping(driver, vehicle)
        return await self._poll(driver, vehicle)

    async def _poll(self, driver: mm.ModemDriver, vehicle: VehicleState) -> bool:
        rate = choose_rate(vehicle.snr_in, loss_sensitive=False, packets=4)
        heard = self._heard.setdefault(vehicle.address, asyncio.Event())
        heard.clear()
        window = self.timing.poll_window(vehicle, rate)
        self.counters["polls"] += 1
        try:
            await driver.poll(vehicle.address, rate=rate, ack=True)
        except mm.ModemError as exc:
            log.info("vehicle %s: poll not sent: %s", vehicle.name, exc)
            return False
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(heard.wait(), window)
        return (
            heard.is_set()
            and vehicle.last_heard is not None
            and time.time() - vehicle.last_heard < window + 1
        )

    # --- status ---------------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        modem = self.driver.state.value if self.driver else "none"
        hours = max(1e-9, (time.time() - self.started_at) / 3600)
        vehicles = {}
        for v in self.ingest.vehicles.values():
            vehicles[v.name] = {
                "address": v.address, "last_heard": v.last_heard, "snr_in": v.snr_in, "snr_out": v.snr_out,
                "range_m": v.range_m, "frames": v.frames, "packets": v.packets, "duplicates": v.duplicates,
                "packets_per_hour": round(v.packets / hours, 1), "bytes_saved": v.bytes_saved,
                "checkpoint": v.checkpoint,
            }  # fmt: skip
        counters = {**self.counters, **self.delivery.counters, "pings": self.ranging.pings,
                    "syncs": self.heartbeat.syncs}  # fmt: skip
        return {"modem": modem, "address": self.settings.modem_address, "counters": counters,
                "ingest": dict(self.ingest.stats), "vehicles": vehicles}  # fmt: skip
