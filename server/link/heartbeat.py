"""SYNC: the shore's authenticated heartbeat.

The Micro-Modem's poll carries no data, so it cannot be authenticated; the vehicle resets its
link-lost timer only on authentic control packets. With no command to send, a vehicle's slot carries a
SYNC control packet (the shore's time, signed with the vehicle's newest key) every ``sync_interval``
seconds, and every ``sync_retry`` seconds while ingest needs the vehicle to restart its sample chains
(``needs_restart``, cleared once the vehicle's modem acknowledged the request).
"""

from __future__ import annotations

import logging
import time

from sqlmodel import Session

from server.link import keys
from server.link.ingest import VehicleState
from server.link.store import LinkStore
from server.link.timing import Timing
from server.models import Vehicle
from server.settings import Settings
from tacit import auth
from tacit import modem as mm
from tacit.packets import SYNC_RESTART_CHAINS, ControlPacket
from tacit.packets import Command as Kind

log = logging.getLogger("tacit.server.link")


class Heartbeat:
    def __init__(self, settings: Settings, store: LinkStore, timing: Timing) -> None:
        self.settings = settings
        self.store = store
        self.timing = timing
        self.syncs = 0
        self._last: dict[int, float] = {}
        self._seq = 0

    def due(self, vehicle: VehicleState) -> bool:
        interval = self.settings.sync_retry if vehicle.needs_restart else self.settings.sync_interval
        return time.time() - self._last.get(vehicle.address, 0.0) > interval / self.settings.time_scale

    async def sync(self, driver: mm.ModemDriver, vehicle: VehicleState) -> None:
        """One SYNC; asks for a chain restart if ingest needs one."""
        self._last[vehicle.address] = time.time()
        restart = vehicle.needs_restart
        row = await self.store.run(self._vehicle_row, vehicle.id)
        if row is None:
            return
        version, key = keys.current(row)
        self._seq += 1
        packet = ControlPacket(Kind.SYNC, seq=self._seq, time=int(time.time()),
                               param_id=SYNC_RESTART_CHAINS if restart else 0)  # fmt: skip
        frame = auth.sign(packet, key, vehicle.address, epoch=version)
        result = await driver.send(vehicle.address, [frame], rate=0, ack=True,
                                   ack_timeout=self.timing.ack_timeout(vehicle))  # fmt: skip
        self.syncs += 1
        if restart and result.all_acked:
            vehicle.needs_restart = False
            log.info("vehicle %s: asked to restart its sample chains", vehicle.name)

    def _vehicle_row(self, vehicle_id: int) -> Vehicle | None:
        with Session(self.store.db) as s:
            return s.get(Vehicle, vehicle_id)
