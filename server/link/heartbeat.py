"""SYNC: the shore's authenticated heartbeat.

The Micro-Modem's poll carries no data, so it cannot be authenticated; the vehicle resets its
link-lost timer only on authentic control packets. A vehicle's slot starts with a SYNC control packet
(the shore's time and the vehicle's SYNC counter, signed with the key the vehicle is known to hold)
every ``sync_interval`` seconds, every ``sync_retry`` seconds while ingest needs the vehicle to restart
its sample chains (``needs_restart``, cleared once the vehicle's modem acknowledged the request or after
``restart_sends`` requests, acknowledged or not: a second modem can make every ACK collide), and at once
when an unsynced check-point waits for its answer (``echo``: the SYNC echoes its MAC, once). The slot
goes on after a SYNC (``server.link.engine``): polling never stops for it.

The counter comes from ``Ingest.next_sync``, which saves it before the SYNC leaves: a vehicle accepts
only a counter above the last it accepted, whatever the shore's clock says.

SYNCs are signed with the key the vehicle is known to hold (``server.vehicles.keys``): during a key
rotation, the new key only once a check-point said the vehicle holds it.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from server.core.config import Settings
from server.link.state import VehicleState
from server.link.store import LinkStore
from server.link.timing import Timing
from server.vehicles import keys
from server.vehicles.service import Vehicles
from tacit import auth
from tacit import modem as mm
from tacit.packets import CHECKPOINT_MAC_SIZE, SYNC_RESTART_CHAINS, ControlPacket
from tacit.packets import Command as Kind

log = logging.getLogger("tacit.server.link")


@dataclass(frozen=True)
class Sync:
    """A signed SYNC frame and what it carries."""

    frame: bytes
    seq: int
    echo: bytes | None  # the unsynced check-point's MAC it answers
    restart: bool  # asks the vehicle to restart its sample chains


class Heartbeat:
    def __init__(
        self,
        settings: Settings,
        store: LinkStore,
        timing: Timing,
        vehicles: Vehicles,
        counter: Callable[[VehicleState], int],
    ) -> None:
        self.settings = settings
        self.store = store
        self.timing = timing
        self.vehicles = vehicles
        self.counter = counter  # the vehicle's next SYNC counter, saved (``Ingest.next_sync``)
        self.syncs = 0
        self._last: dict[int, float] = {}  # when each vehicle's last SYNC left, on the monotonic clock
        self._restarts: dict[int, int] = {}  # chain-restart requests sent since it was raised, by address

    def due(self, vehicle: VehicleState) -> bool:
        if vehicle.link.echo is not None:
            return True  # an unsynced vehicle accepts nothing before this answer
        interval = self.settings.sync_retry if vehicle.link.needs_restart else self.settings.sync_interval
        return (
            time.monotonic() - self._last.get(vehicle.address, -math.inf)
            > interval / self.settings.time_scale
        )

    async def sync(self, driver: mm.ModemDriver, vehicle: VehicleState) -> bool:
        """One SYNC; answers a waiting unsynced check-point, asks for a chain restart if ingest needs one.
        False if our modem refused the cycle (the SYNC is due again)."""
        sync = await self.signed(vehicle)
        result = await driver.send(
            vehicle.address, [sync.frame], rate=0, ack=True, ack_timeout=self.timing.ack_timeout(vehicle)
        )
        if not result.transmitted:  # our modem refused the cycle: due again at the next slot
            log.info(
                "vehicle %s: SYNC %d not transmitted (%s); next slot", vehicle.name, sync.seq, result.error
            )
            self._last[vehicle.address] = -math.inf
            await asyncio.sleep(self.timing.busy_wait())
            return False
        self.sent(vehicle, sync, result.all_acked)
        return True

    async def signed(self, vehicle: VehicleState) -> Sync:
        """The vehicle's next SYNC, signed now (its counter saved first); the heartbeat counts it as due
        no more until ``sync_interval`` has passed."""
        self._last[vehicle.address] = time.monotonic()  # a wall clock stepped back must not stop SYNCs
        restart = vehicle.link.needs_restart
        echo = vehicle.link.echo
        row = await self.store.run(self.vehicles.get, vehicle.id)
        version, key = keys.for_commands(row)
        seq = await self.store.run(self.counter, vehicle)
        packet = ControlPacket(
            Kind.SYNC,
            seq=seq,
            time=int(time.time()),
            echo=echo or bytes(CHECKPOINT_MAC_SIZE),
            param_id=SYNC_RESTART_CHAINS if restart else 0,
        )
        return Sync(auth.sign(packet, key, vehicle.address, epoch=version), seq, echo, restart)

    def sent(self, vehicle: VehicleState, sync: Sync, acked: bool) -> None:
        """``sync`` went on the air (``acked``: the vehicle's modem acknowledged it)."""
        if vehicle.link.echo == sync.echo:  # on the air: one answer per check-point (a newer one waits)
            vehicle.link.echo = None
        self.syncs += 1
        if sync.restart:
            self._restart_sent(vehicle, acked)

    def _restart_sent(self, vehicle: VehicleState, acked: bool) -> None:
        sent = self._restarts[vehicle.address] = self._restarts.get(vehicle.address, 0) + 1
        if acked or sent >= self.settings.restart_sends:
            vehicle.link.needs_restart = False
            self._restarts[vehicle.address] = 0
            log.info("vehicle %s: asked to restart its sample chains (%d request(s))", vehicle.name, sent)
