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

SYNC: the Micro-Modem's poll carries no data, so it cannot be authenticated; the vehicle resets its
link-lost timer only on authentic control packets. With no command to send, a vehicle's slot carries
a SYNC control packet (the shore's time, signed with the newest key) every ``SYNC_INTERVAL`` seconds,
and at once when ingest found that the vehicle's sample chains must restart (``needs_restart``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time

from sqlalchemy import Engine, update
from sqlmodel import Session, select

from server.db import writing
from server.events import EventBus
from server.link import keys
from server.link.ingest import IncomingFrame, Ingest, VehicleState
from server.models import Command, CommandEvent, Frame, LinkEvent, Vehicle, now
from server.services import commands
from server.settings import Settings
from tacit import auth, rates
from tacit import modem as mm
from tacit.link import capacity, choose_rate
from tacit.packets import SYNC_RESTART_CHAINS, ControlPacket
from tacit.packets import Command as Kind

log = logging.getLogger("tacit.server.link")

PENDING = ("queued", "sent")
SYNC_INTERVAL = 60.0  # s between SYNC heartbeats (a third to a fifth of the agent's link_lost_timeout)
SYNC_RETRY = 5.0  # s between SYNCs asking for a chain restart, until one is acknowledged


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
        self._last_sync: dict[int, float] = {}
        self._sync_seq = 0
        self.started_at = time.time()
        self.counters = {"commands_sent": 0, "commands_acked": 0, "polls": 0, "pings": 0, "frames_in": 0,
                         "syncs": 0}  # fmt: skip

    # --- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
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
        """Something was queued: start the next slot now instead of after the idle wait."""
        self._wake.set()

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
            self._store(
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
                await asyncio.to_thread(self.ingest.handle_batch, batch)
            except Exception:  # stored nothing: say so loudly, keep the engine running
                log.exception("%d frame(s) could not be stored", len(batch))
                continue
            for frame in batch:
                heard = self._heard.get(frame.src)
                if heard is not None:
                    heard.set()

    def _store(self, *rows: object) -> None:
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
        command = self._next_command(vehicle.id)
        if command is not None:
            await self._send_command(vehicle, command)
            return True
        since = time.time() - self._last_sync.get(vehicle.address, 0.0)
        if since > (SYNC_RETRY if vehicle.needs_restart else SYNC_INTERVAL) / self.settings.time_scale:
            await self._sync(vehicle)
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
            pending = s.exec(select(Command).where(Command.vehicle_id == vehicle_id, Command.status.in_(PENDING))
                             .order_by(Command.id)).first()  # type: ignore[attr-defined]  # fmt: skip
            if pending is not None:
                return pending
            latest = s.exec(select(Command).where(Command.vehicle_id == vehicle_id)
                            .order_by(Command.id.desc())).first()  # type: ignore[union-attr]  # fmt: skip
        stale = time.time() - self.settings.confirm_timeout / self.settings.time_scale
        if latest is not None and latest.status == "acknowledged" and latest.updated_at < stale:
            log.info(
                "vehicle %s: command seq %d acknowledged but never confirmed: sending again",
                vehicle_id,
                latest.seq,
            )
            return latest
        return None

    async def _sync(self, vehicle: VehicleState) -> None:
        """One SYNC: the shore's time, signed with the vehicle's newest key; asks for a chain restart if
        ingest needs one (cleared once the vehicle's modem acknowledged it)."""
        self._last_sync[vehicle.address] = time.time()
        restart = vehicle.needs_restart
        row = await asyncio.to_thread(self._vehicle_row, vehicle.id)
        if row is None:
            return
        version, key = keys.current(row)
        self._sync_seq += 1
        packet = ControlPacket(Kind.SYNC, seq=self._sync_seq, time=int(time.time()),
                               param_id=SYNC_RESTART_CHAINS if restart else 0)  # fmt: skip
        frame = auth.sign(packet, key, vehicle.address, epoch=version)
        result = await self.driver.send(vehicle.address, [frame], rate=0, ack=True,  # type: ignore[union-attr]
                                        ack_timeout=self._ack_timeout(vehicle))  # fmt: skip
        self.counters["syncs"] += 1
        if restart and result.all_acked:
            vehicle.needs_restart = False
            log.info("vehicle %s: asked to restart its sample chains", vehicle.name)

    def _vehicle_row(self, vehicle_id: int) -> Vehicle | None:
        with Session(self.db) as s:
            return s.get(Vehicle, vehicle_id)

    def _range(self, vehicle: VehicleState) -> float:
        return vehicle.range_m if vehicle.range_m is not None else self.settings.default_range

    def _ack_timeout(self, vehicle: VehicleState) -> float:
        travel = self._range(vehicle) / self.settings.sound_speed
        floor = 2 * travel + rates.TURNAROUND_S + rates.airtime_s(rates.ACK_BITS, 0)
        return (floor * 1.5 + 2.0) / self.settings.time_scale

    async def _send_command(self, vehicle: VehicleState, command: Command) -> None:
        """One attempt. Only a transmission that went on the air counts: if our own modem refused the
        cycle (busy acknowledging, say), the command waits for the next slot unchanged."""
        with Session(self.db) as s:
            frame = commands.sign(command, s.get(Vehicle, vehicle.id))  # type: ignore[arg-type]
        result = await self.driver.send(vehicle.address, [frame], rate=0, ack=True,  # type: ignore[union-attr]
                                        ack_timeout=self._ack_timeout(vehicle))  # fmt: skip
        if not result.transmitted:
            log.info("vehicle %s: command seq %d not transmitted (%s); next slot", vehicle.name, command.seq,
                     result.error)  # fmt: skip
            await asyncio.sleep(self._ack_timeout(vehicle) / 4)
            return
        attempt = command.attempts + 1
        self.counters["commands_sent"] += 1
        self._store(
            Frame(direction="out", src=self.settings.modem_address, dest=vehicle.address, rate=0, data=frame)
        )
        self._set_status(command, "sent", f"attempt {attempt}", attempts=attempt, frame=frame)
        log.info(
            "vehicle %s: command %s seq %d sent (attempt %d)",
            vehicle.name,
            command.command,
            command.seq,
            attempt,
        )
        if result.all_acked:
            self.counters["commands_acked"] += 1
            self._set_status(command, "acknowledged", "")
            log.info("vehicle %s: command seq %d acknowledged", vehicle.name, command.seq)
        elif attempt >= self.settings.command_attempts:
            self._set_status(command, "failed", result.error or "no acknowledgement")
            log.warning("vehicle %s: command seq %d failed: %s", vehicle.name, command.seq, result.error)

    def _set_status(self, command: Command, status: str, detail: str, **extra: object) -> None:
        with writing(self.db) as s:
            current = s.get(Command, command.id)
            if current is None:
                return
            if status in ("sent", "acknowledged") and current.status not in (*PENDING, "acknowledged"):
                return  # a check-point already said executing/executed/refused: keep the later state
            s.exec(update(Command).where(Command.id == command.id)
                   .values(status=status, updated_at=now(), reason=detail if status == "failed" else current.reason,
                           **extra))  # type: ignore[arg-type]  # fmt: skip
            s.add(CommandEvent(command_id=command.id, status=status, detail=detail))  # type: ignore[arg-type]
            s.commit()
        self.bus.publish("command", id=command.id, seq=command.seq, status=status, detail=detail)

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
        self._store(LinkEvent(vehicle_id=vehicle.id, kind="range", detail={"range_m": vehicle.range_m}))
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
