"""Command delivery: which command a vehicle's slot carries, one attempt at a time, until acknowledged.

Each attempt is signed afresh (same sequence number, current time stamp), so a command that waited in
the queue still falls inside the vehicle's replay window, and the vehicle's sequence window still
executes it once however many copies arrive. Only an attempt that went on the air counts. After
``command_attempts`` unacknowledged attempts the command has failed. The modem ACKs in hardware even
when the vehicle's host is down, so the latest acknowledged command is sent again when no check-point
confirms it within ``confirm_timeout``. A server restart resumes from the database.
"""

from __future__ import annotations

import asyncio
import logging
import time

from sqlmodel import Session, col, select

from server.db import writing
from server.events import EventBus
from server.link.ingest import VehicleState
from server.link.store import LinkStore
from server.link.timing import Timing
from server.models import Command, CommandEvent, Frame, Vehicle
from server.services import commands
from server.services.commands import Status
from server.settings import Settings
from tacit import modem as mm

log = logging.getLogger("tacit.server.link")


class Delivery:
    def __init__(self, settings: Settings, store: LinkStore, bus: EventBus, timing: Timing) -> None:
        self.settings = settings
        self.store = store
        self.bus = bus
        self.timing = timing
        self.counters = {"commands_sent": 0, "commands_acked": 0}

    async def next_command(self, vehicle_id: int) -> Command | None:
        return await self.store.run(self._next_command, vehicle_id)

    def _next_command(self, vehicle_id: int) -> Command | None:
        """The oldest queued or sent command; else the vehicle's latest if it was acknowledged but not
        confirmed in time. Only the latest: re-sending an older one could run it after a newer one."""
        with Session(self.store.db) as s:
            by_vehicle = select(Command).where(Command.vehicle_id == vehicle_id)
            pending = s.exec(by_vehicle.where(col(Command.status).in_(commands.PENDING))
                             .order_by(col(Command.id))).first()  # fmt: skip
            if pending is not None:
                return pending
            latest = s.exec(by_vehicle.order_by(col(Command.id).desc())).first()
        if latest is not None and latest.status == Status.ACKNOWLEDGED:
            if latest.updated_at < self.timing.confirm_deadline(time.time()):
                log.info("vehicle %d: command seq %d acknowledged but never confirmed: sending again",
                         vehicle_id, latest.seq)  # fmt: skip
                return latest
        return None

    async def attempt(self, driver: mm.ModemDriver, vehicle: VehicleState, command: Command) -> None:
        """One attempt. If our own modem refused the cycle (busy acknowledging, say), the command waits
        for the next slot unchanged."""
        frame = await self.store.run(self._sign, command, vehicle.id)
        timeout = self.timing.ack_timeout(vehicle)
        result = await driver.send(vehicle.address, [frame], rate=0, ack=True, ack_timeout=timeout)
        if not result.transmitted:
            log.info("vehicle %s: command seq %d not transmitted (%s); next slot", vehicle.name, command.seq,
                     result.error)  # fmt: skip
            await asyncio.sleep(timeout / 4)
            return
        attempt = command.attempts + 1
        self.counters["commands_sent"] += 1
        await self.store.add(
            Frame(direction="out", src=self.settings.modem_address, dest=vehicle.address, rate=0, data=frame)
        )
        await self._advance(command, Status.SENT, f"attempt {attempt}", attempts=attempt, frame=frame)
        log.info("vehicle %s: command %s seq %d sent (attempt %d)", vehicle.name, command.command, command.seq,
                 attempt)  # fmt: skip
        if result.all_acked:
            self.counters["commands_acked"] += 1
            await self._advance(command, Status.ACKNOWLEDGED)
            log.info("vehicle %s: command seq %d acknowledged", vehicle.name, command.seq)
        elif await self.store.run(self._unanswered, command.id) >= self.settings.command_attempts:
            error = result.error or "no acknowledgement"
            await self._advance(command, Status.FAILED, error, reason=error)
            log.warning("vehicle %s: command seq %d failed: %s", vehicle.name, command.seq, error)

    def _unanswered(self, command_id: int | None) -> int:
        """Attempts since the command was last acknowledged: a command sent again because no check-point
        confirmed it gets its own ``command_attempts``, not what is left of the first round's."""
        with Session(self.store.db) as s:
            steps = s.exec(select(CommandEvent.status).where(CommandEvent.command_id == command_id)
                           .order_by(col(CommandEvent.id))).all()  # fmt: skip
        since = (
            steps[len(steps) - steps[::-1].index(Status.ACKNOWLEDGED) :]
            if Status.ACKNOWLEDGED in steps
            else steps
        )
        return sum(step == Status.SENT for step in since)

    def _sign(self, command: Command, vehicle_id: int) -> bytes:
        with Session(self.store.db) as s:
            vehicle = s.get(Vehicle, vehicle_id)
            if vehicle is None:
                raise LookupError(f"vehicle {vehicle_id} was removed")
            return commands.sign(command, vehicle)

    async def _advance(
        self,
        command: Command,
        status: Status,
        detail: str = "",
        reason: str | None = None,
        **extra: int | bytes,
    ) -> None:
        """What the modem said of a command, if the lifecycle allows it: a check-point may already have
        said executing / executed / refused, which a late ACK must not undo. ``extra``: column values
        (attempts, frame)."""
        if await self.store.run(self._advance_now, command.id, status, detail, reason, extra):
            self.bus.publish("command", id=command.id, seq=command.seq, status=status.value, detail=detail)

    def _advance_now(
        self,
        command_id: int | None,
        status: Status,
        detail: str,
        reason: str | None,
        extra: dict[str, int | bytes],
    ) -> bool:
        with writing(self.store.db) as s:
            current = s.get(Command, command_id)
            if current is None or not commands.advance(
                s, current, status, detail, reason=reason, report=None, **extra
            ):
                return False
            s.commit()
            return True
