"""SYNC: the shore's authenticated heartbeat.

The Micro-Modem's poll carries no data, so it cannot be authenticated; the vehicle resets its
link-lost timer only on authentic control packets. A vehicle's slot starts with a SYNC control packet
(the shore's time and the vehicle's SYNC counter, signed with the key the vehicle is known to hold)
every ``sync_interval`` seconds, every ``sync_retry`` seconds while ingest needs the vehicle to restart
its sample chains (``needs_restart``, cleared once the vehicle's modem acknowledged the request or after
``restart_sends`` requests, acknowledged or not: a second modem can make every ACK collide), and at once
when an unsynced check-point waits for its answer (``echo``: the SYNC echoes its MAC until the vehicle's
modem acknowledges one, or a synced check-point says it arrived). The slot goes on after a SYNC
(``server.link.engine``): polling never stops for it.

First contact: nothing goes to a vehicle before the shore has heard a check-point of it. A vehicle that
lost its state (a new one has none) accepts no SYNC but one echoing a check-point of its current start,
and no command before that SYNC; so the first SYNC waits for the first check-point, and commands wait
(``synced``) until the vehicle's challenge, if it made one, has been answered.

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
        counter: Callable[[VehicleState, int], int],
    ) -> None:
        self.settings = settings
        self.store = store
        self.timing = timing
        self.vehicles = vehicles
        self.counter = (
            counter  # the vehicle's next SYNC counter, at least a floor, saved (``Ingest.next_sync``)
        )
        self.syncs = 0
        self._last: dict[int, float] = {}  # when each vehicle's last SYNC left, on the monotonic clock
        self._restarts: dict[int, int] = {}  # chain-restart requests sent since it was raised, by address

    @staticmethod
    def synced(vehicle: VehicleState) -> bool:
        """Whether the vehicle may be commanded: heard, and no challenge of its waits for its answer."""
        return vehicle.link.checkpoint is not None and vehicle.link.echo is None

    def due(self, vehicle: VehicleState) -> bool:
        if vehicle.link.echo is not None:
            return True  # an unsynced vehicle accepts nothing before this answer
        if vehicle.link.checkpoint is None:
            return False  # not heard yet: a SYNC now would answer none of its current start's check-points
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
        if sync.echo is not None and not result.all_acked and vehicle.link.echo is None:
            vehicle.link.echo = sync.echo  # the answer again at the next slot: commands wait for it
        return True

    async def signed(self, vehicle: VehicleState, floor: int = 0, at: float | None = None) -> Sync:
        """The vehicle's next SYNC, signed now and stamped now (or ``at``: when it will go on the air;
        its counter, at least ``floor``, saved first); the heartbeat counts it as due no more until
        ``sync_interval`` has passed."""
        ahead = 0.0 if at is None else max(0.0, at - time.time())  # the interval runs from when it goes
        self._last[vehicle.address] = (
            time.monotonic() + ahead
        )  # a wall clock stepped back must not stop SYNCs
        restart = vehicle.link.needs_restart
        echo = vehicle.link.echo
        row = await self.store.run(self.vehicles.get, vehicle.id)
        version, key = keys.for_commands(row)
        seq = await self.store.run(self.counter, vehicle, floor)
        packet = ControlPacket(
            Kind.SYNC,
            seq=seq,
            time=int(time.time() if at is None else at),
            echo=echo or bytes(CHECKPOINT_MAC_SIZE),
            param_id=SYNC_RESTART_CHAINS if restart else 0,
        )
        return Sync(auth.sign(packet, key, vehicle.address, epoch=version), seq, echo, restart)

    def again(self, vehicle: VehicleState) -> None:
        """The vehicle's last SYNC never went on the air: the next is due at once."""
        self._last[vehicle.address] = -math.inf

    def sent(self, vehicle: VehicleState, sync: Sync, acked: bool) -> None:
        """``sync`` went on the air (``acked``: the vehicle's modem acknowledged it)."""
        if vehicle.link.echo == sync.echo:  # on the air (a newer challenge waits for its own answer)
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
