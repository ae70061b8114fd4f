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

from server.commands.models import CommandRecord, CommandState
from server.commands.service import CommandDesk
from server.core.config import Settings
from server.link.state import VehicleState
from server.link.store import LinkStore
from server.link.timing import Timing
from server.telemetry.models import Frame
from tacit import modem as mm

log = logging.getLogger("tacit.server.link")


class Delivery:
    def __init__(self, settings: Settings, store: LinkStore, desk: CommandDesk, timing: Timing) -> None:
        self.settings = settings
        self.store = store
        self.desk = desk
        self.timing = timing
        self.counters = {"commands_sent": 0, "commands_acked": 0}

    async def next_command(self, vehicle_id: int) -> CommandRecord | None:
        return await self.store.run(
            self.desk.next_to_send, vehicle_id, self.timing.confirm_deadline(time.time())
        )

    async def demand(self, vehicles: list[VehicleState]) -> list[tuple[bool, bool]]:
        """Per vehicle: whether a command waits, whether one is in flight (``CommandDesk.demand``)."""
        return await self.store.run(lambda: [self.desk.demand(v.id) for v in vehicles])

    async def attempt(self, driver: mm.ModemDriver, vehicle: VehicleState, command: CommandRecord) -> bool:
        """One attempt; whether it went on the air. If our own modem refused the cycle (busy acknowledging,
        say), the command waits for the next slot unchanged."""
        frame = await self.store.run(self.desk.frame, command)
        if frame is None:  # cancelled by an operator since it was chosen: never sent
            return False
        timeout = self.timing.ack_timeout(vehicle)
        started = time.time()  # "sent" is when it went on the air, not when the ACK came back after it
        result = await driver.send(vehicle.address, [frame], rate=0, ack=True, ack_timeout=timeout)
        if not result.transmitted:
            log.info(
                "vehicle %s: command seq %d not transmitted (%s); next slot",
                vehicle.name,
                command.seq,
                result.error,
            )
            await asyncio.sleep(self.timing.busy_wait())
            return False
        attempt = command.attempts + 1
        self.counters["commands_sent"] += 1
        await self.store.add(
            Frame(direction="out", src=self.settings.modem_address, dest=vehicle.address, rate=0, data=frame)
        )
        await self._record(
            command, CommandState.SENT, f"attempt {attempt}", at=started, attempts=attempt, frame=frame
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
            await self._record(command, CommandState.ACKNOWLEDGED)
            log.info("vehicle %s: command seq %d acknowledged", vehicle.name, command.seq)
        elif await self.store.run(self.desk.unanswered, command.id) >= self.settings.command_attempts:
            error = result.error or "no acknowledgement"
            await self._record(command, CommandState.FAILED, error, reason=error)
            log.warning("vehicle %s: command seq %d failed: %s", vehicle.name, command.seq, error)
        return True

    async def _record(
        self,
        command: CommandRecord,
        status: CommandState,
        detail: str = "",
        reason: str | None = None,
        at: float | None = None,
        **extra: int | bytes,
    ) -> None:
        await self.store.run(lambda: self.desk.record(command, status, detail, reason, at, **extra))
