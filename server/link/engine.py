"""The link engine: owns the shore Micro-Modem and runs the shore half of the protocol.

Schedule (the MAC): the shore polls, as goby's polled MAC does, so transmissions never collide even
with several vehicles on one channel. Slots go round the vehicles; in a vehicle's slot the shore sends
its oldest pending command (rate 0, with ACK; the same 32 bytes on every retry, so the vehicle counts
it once) or, with nothing to send, polls it for data at the rate ``tacit.link.choose_rate`` picks from
the recent SNR. Slot lengths come from the range (pings, or the configured default) and the rate's
airtime; ``time_scale`` shortens them for simulations running faster than real time.

Commands: queued -> sent (each attempt) -> acknowledged (the vehicle's modem ACKed) -> executing /
executed / refused (from the vehicle's check-points) or failed (no ACK after ``command_attempts``).
Each attempt is signed afresh (same sequence number, current time stamp), so a command that waited
in the queue still falls inside the vehicle's replay window, and the vehicle's sequence window still
executes it once however many copies arrive.
A server restart resumes queued and sent commands from the database.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Coroutine
from typing import TypeVar

from sqlalchemy import Engine
from sqlalchemy.exc import OperationalError
from sqlmodel import Session, select

from server.db import writing
from server.events import EventBus
from server.link.ingest import IncomingFrame, Ingest, VehicleState
from server.models import Command, Frame, LinkEvent, Vehicle
from server.services import commands
from server.settings import Settings
from tacit import modem as mm
from tacit import rates
from tacit.link import capacity, choose_rate

log = logging.getLogger("tacit.server.link")
T = TypeVar("T")


class LinkEngine:
    def __init__(self, settings: Settings, db: Engine, bus: EventBus, ingest: Ingest) -> None:
        self.settings = settings
        self.db = db
        self.bus = bus
        self.ingest = ingest
        self.driver: mm.ModemDriver | None = None
        self._wake = asyncio.Event()
        self._heard: dict[int, asyncio.Event] = {}
        self._task: asyncio.Task[None] | None = None
        self._frames: asyncio.Queue[IncomingFrame] = asyncio.Queue()
        self._worker: asyncio.Task[None] | None = None
        self._last_ping: dict[int, float] = {}
        self._writes: set[asyncio.Task[None]] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self.started_at = time.time()
        self.counters = {"commands_sent": 0, "commands_acked": 0, "polls": 0, "pings": 0, "frames_in": 0}

    # --- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self.ingest.load_vehicles()
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
            row = LinkEvent(kind="modem_state", detail={"state": event.state.value, "detail": event.detail})
            self._background(self._store(row))
        elif isinstance(event, mm.FrameBad) and event.reason == "timeout":
            for heard in self._heard.values():
                heard.set()

    async def _ingest(self) -> None:
        """One worker stores frames in arrival order; what queued up meanwhile goes in one commit."""
        while True:
            batch = [await self._frames.get()]
            while not self._frames.empty() and len(batch) < 500:
                batch.append(self._frames.get_nowait())
            if not await self._store_batch(batch):
                continue
            for frame in batch:
                heard = self._heard.get(frame.src)
                if heard is not None:
                    heard.set()

    async def _store_batch(self, batch: list[IncomingFrame]) -> bool:
        try:
            await self._write(self.ingest.handle_batch, batch)
            return True
        except Exception:  # not the database being busy: say so loudly, keep the engine running
            log.exception("%d frame(s) could not be stored", len(batch))
            return False

    async def _write(self, work: Callable[..., T], *args: object) -> T:
        """``work(*args)`` in a worker thread, so the event loop serving the modem never waits on the
        database; while the database is busy (another process holds its write lock past the busy
        timeout), try again with backoff: what arrived is kept in memory, never dropped."""
        delay = 0.2
        while True:
            try:
                return await asyncio.to_thread(work, *args)
            except OperationalError as exc:
                log.warning("database busy (%s): retrying in %.1f s", exc.orig, delay)
                await asyncio.sleep(delay)
                delay = min(delay * 2, 5.0)

    def _background(self, work: Coroutine[object, object, None]) -> None:
        """A write started from a modem callback, kept referenced until it finishes."""
        task = asyncio.get_running_loop().create_task(work)
        self._writes.add(task)
        task.add_done_callback(self._writes.discard)

    async def _store(self, *rows: object) -> None:
        await self._write(self._store_now, *rows)

    def _store_now(self, *rows: object) -> None:
        with writing(self.db) as s:
            s.add_all(rows)
            s.commit()

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
                    await asyncio.wait_for(
                        self._wake.wait(), self.settings.poll_interval / self.settings.time_scale
                    )

    async def _slot(self, vehicle: VehicleState) -> bool:
        """One vehicle's slot; True if something was sent or heard."""
        if self.driver is None or self.driver.state is not mm.LinkState.READY:
            return False
        command = await asyncio.to_thread(self._next_command, vehicle.id)
        if command is not None:
            await self._send_command(vehicle, command)
            return True
        if (
            time.time() - self._last_ping.get(vehicle.address, 0.0)
            > self.settings.ping_interval / self.settings.time_scale
        ):
            await self._ping(vehicle)
        return await self._poll(vehicle)

    def _next_command(self, vehicle_id: int) -> Command | None:
        """The oldest queued or sent command; else the vehicle's latest command if it was acknowledged but no
        check-point has confirmed it within ``confirm_timeout`` (the modem ACKs in hardware, even when the
        vehicle's host is down). Only the latest: re-sending an older one could run it after a newer one."""
        with Session(self.db) as s:
            pending = s.exec(select(Command).where(Command.vehicle_id == vehicle_id, Command.status.in_(commands.PENDING))
                             .order_by(Command.id)).first()  # type: ignore[attr-defined]  # fmt: skip
            if pending is not None:
                return pending
            latest = s.exec(select(Command).where(Command.vehicle_id == vehicle_id)
                            .order_by(Command.id.desc())).first()  # type: ignore[union-attr]  # fmt: skip
        stale = time.time() - self.settings.confirm_timeout / self.settings.time_scale
        if latest is not None and latest.status == commands.Status.ACKNOWLEDGED and latest.updated_at < stale:
            log.info(
                "vehicle %s: command seq %d acknowledged but never confirmed: sending again",
                vehicle_id,
                latest.seq,
            )
            return latest
        return None

    def _range(self, vehicle: VehicleState) -> float:
        return vehicle.range_m if vehicle.range_m is not None else self.settings.default_range

    def _ack_timeout(self, vehicle: VehicleState) -> float:
        travel = self._range(vehicle) / self.settings.sound_speed
        floor = 2 * travel + rates.TURNAROUND_S + rates.airtime_s(rates.ACK_BITS, 0)
        return (floor * 1.5 + 2.0) / self.settings.time_scale

    async def _send_command(self, vehicle: VehicleState, command: Command) -> None:
        """One attempt. Only a transmission that went on the air counts: if our own modem refused the
        cycle (busy acknowledging, say), the command waits for the next slot unchanged."""
        frame = await asyncio.to_thread(self._sign, command, vehicle.id)
        result = await self.driver.send(vehicle.address, [frame], rate=0, ack=True,  # type: ignore[union-attr]
                                        ack_timeout=self._ack_timeout(vehicle))  # fmt: skip
        if not result.transmitted:
            log.info("vehicle %s: command seq %d not transmitted (%s); next slot", vehicle.name, command.seq,
                     result.error)  # fmt: skip
            await asyncio.sleep(self._ack_timeout(vehicle) / 4)
            return
        attempt = command.attempts + 1
        self.counters["commands_sent"] += 1
        await self._store(
            Frame(direction="out", src=self.settings.modem_address, dest=vehicle.address, rate=0, data=frame)
        )
        await self._advance(
            command, commands.Status.SENT, f"attempt {attempt}", attempts=attempt, frame=frame
        )
        log.info(
            "vehicle %s: command %s seq %d sent (attempt %d)",
            vehicle.name,
            command.command,
            command.seq,
            attempt,
        )
        if result.all_acked:
            self.counters["commands_acked"] += 1
            await self._advance(command, commands.Status.ACKNOWLEDGED)
            log.info("vehicle %s: command seq %d acknowledged", vehicle.name, command.seq)
        elif attempt >= self.settings.command_attempts:
            error = result.error or "no acknowledgement"
            await self._advance(command, commands.Status.FAILED, error, reason=error)
            log.warning("vehicle %s: command seq %d failed: %s", vehicle.name, command.seq, result.error)

    def _sign(self, command: Command, vehicle_id: int) -> bytes:
        with Session(self.db) as s:
            vehicle = s.get(Vehicle, vehicle_id)
            if vehicle is None:
                raise LookupError(f"vehicle {vehicle_id} was removed")
            return commands.sign(command, vehicle)

    async def _advance(
        self, command: Command, status: commands.Status, detail: str = "", **extra: object
    ) -> None:
        """What the modem said of a command (sent, acknowledged, failed), if the lifecycle allows it: a
        check-point may already have said executing / executed / refused, which a late ACK must not undo."""
        if await self._write(self._advance_now, command.id, status, detail, extra):
            self.bus.publish("command", id=command.id, seq=command.seq, status=status.value, detail=detail)

    def _advance_now(self, command_id: int | None, status: commands.Status, detail: str, extra: dict) -> bool:
        with writing(self.db) as s:
            current = s.get(Command, command_id)
            if current is None or not commands.advance(s, current, status, detail, **extra):
                return False
            s.commit()
            return True

    async def _poll(self, vehicle: VehicleState) -> bool:
        rate = choose_rate(vehicle.snr_in, loss_sensitive=False, packets=4)
        heard = self._heard.setdefault(vehicle.address, asyncio.Event())
        heard.clear()
        travel = self._range(vehicle) / self.settings.sound_speed
        window = (rates.airtime_s(rates.CYCLE_INIT_BITS, 0) + 2 * travel + 1.0
                  + rates.data_airtime_s(rate, max(1, capacity(rate) // 2))) * 1.3 / self.settings.time_scale  # fmt: skip
        self.counters["polls"] += 1
        try:
            await self.driver.poll(vehicle.address, rate=rate, ack=True)  # type: ignore[union-attr]
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

    async def _ping(self, vehicle: VehicleState) -> None:
        self._last_ping[vehicle.address] = time.time()
        self.counters["pings"] += 1
        travel = await self.driver.ping(
            vehicle.address, timeout=(2 * 4000 / 1500 + 2) / self.settings.time_scale
        )  # type: ignore[union-attr]
        if travel is None:
            return
        vehicle.range_m = travel * self.settings.sound_speed
        await self._store(LinkEvent(vehicle_id=vehicle.id, kind="range", detail={"range_m": vehicle.range_m}))
        self.bus.publish("link", event="range", vehicle=vehicle.name, range_m=round(vehicle.range_m, 1))
        log.info("vehicle %s: range %.1f m", vehicle.name, vehicle.range_m)

    # --- status ---------------------------------------------------------------------------------

    def status(self) -> dict[str, object]:
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
        return {"modem": modem, "address": self.settings.modem_address, "counters": dict(self.counters),
                "ingest": dict(self.ingest.stats), "vehicles": vehicles}  # fmt: skip
