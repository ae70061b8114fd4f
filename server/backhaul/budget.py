"""The SYNC budget (docs/backhaul.md): SYNCs the center signs ahead for each vehicle and hands to the
vehicle's gateway, which sends them while the center's own SYNCs do not reach it (its backhaul is cut,
the center is down), so that a vehicle behind a cut longer than its link-lost timeout still hears
authentic SYNCs. Gateways hold no key: this is all they can send a vehicle on their own.

Each is a *scheduled* SYNC (``ControlFlag.SCHEDULED``; the vehicle accepts it within
``tacit.auth.SCHEDULED_WINDOW`` of its clock and never corrects its clock by it) whose counter is its
time. The center's own SYNCs take a counter of at least their time too (``Ingest.next_sync``'s floor), so
whichever kind a vehicle hears, its counters grow with time: neither kind makes the other's later ones
stale, and no feedback from the gateway is needed. One every ``step`` s (the sync interval, at most half
the window) for ``sync_budget`` s ahead (both of the vehicles' time: divided by ``time_scale``, as the
heartbeat does), signed with the key the vehicle is known to hold, on ``tacit.v1.syncs.<gateway>.
<address>`` (the stream keeps the last per subject, so a gateway back from an outage reads only the
newest). A budget is renewed every eighth of its length (a gateway cut off at the worst moment holds
seven eighths of it) and when the key to sign with changes; when the vehicle moves to another gateway,
the old one's is withdrawn (an empty budget on its subject) and the new one gets one. A center starting
does not know what it handed out before: it withdraws every vehicle's budget from every other gateway.
With several center processes, the coordinator's dispatcher alone runs the budgets (one taking the role
starts afresh, likewise).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass

from server.backhaul import subjects
from server.backhaul.subjects import SyncBudgetMessage
from server.core.config import Settings
from server.routing.service import Route
from server.vehicles import keys
from server.vehicles.models import Vehicle
from tacit import auth
from tacit.packets import Command, ControlFlag, ControlPacket

log = logging.getLogger("tacit.backhaul.budget")

Publish = Callable[[str, bytes, str], Awaitable[None]]  # subject, payload, message id
RENEW = 8  # a budget is renewed every RENEW-th of its length


@dataclass(frozen=True)
class Issued:
    """The budget a gateway holds for a vehicle: where, when it was signed, with which key."""

    gateway: str
    at: float
    key: tuple[int, bytes]


def scheduled_syncs(vehicle: Vehicle, start: int, step: float, count: int) -> list[bytes]:
    """``count`` scheduled SYNCs for ``vehicle``, one every ``step`` s from ``start`` (UNIX s), each one's
    counter its time, signed with the key the vehicle is known to hold."""
    version, key = keys.for_commands(vehicle)
    stamps = sorted({start + int(i * step) for i in range(count)})
    return [
        auth.sign(
            ControlPacket(Command.SYNC, seq=t, time=t, flags=ControlFlag.SCHEDULED),
            key,
            vehicle.address,
            epoch=version,
        )
        for t in stamps
    ]


class SyncBudgets:
    """The center's side: which gateway holds which vehicle's budget, issued, renewed and withdrawn on
    the dispatcher's tick."""

    def __init__(
        self,
        settings: Settings,
        publish: Publish,
        gateways: Callable[[], list[str]],
        ack_timeout: Callable[[], float],
    ) -> None:
        self.settings = settings
        self.publish = publish
        self.gateways = gateways  # every gateway the center knows of
        self.ack_timeout = ack_timeout  # the ACK wait that fits a slot (the dispatcher's)
        self.issued: dict[int, Issued] = {}  # by vehicle address
        self.started = False  # every other gateway's budgets withdrawn

    @property
    def interval(self) -> float:
        """How often a gateway sends one while the center's SYNCs do not come: as the center would."""
        return self.settings.sync_interval / self.settings.time_scale

    @property
    def step(self) -> float:
        """The budget's spacing: the interval, and at most half the window, so that one sent before the
        next is due reaches the vehicle inside the window with the vehicle's clock error the other half."""
        return min(self.interval, auth.SCHEDULED_WINDOW / 2)

    async def update(self, routes: list[Route], counters: Mapping[int, int], now: float) -> None:
        """Issue, renew and withdraw after this tick's routes; ``counters``: each vehicle's last SYNC
        counter (by address), which its budget starts after."""
        if not self.started:
            await self._withdraw_everywhere(routes)
            self.started = True
        for route in routes:
            await self._vehicle(route, counters.get(route.vehicle.address, 0), now)

    async def _withdraw_everywhere(self, routes: list[Route]) -> None:
        known = await asyncio.to_thread(self.gateways)
        for route in routes:
            own = route.gateway if self.settings.sync_budget > 0 else None
            for gateway in known:
                if gateway != own:
                    await self._withdraw(route.vehicle, gateway, "the center started")

    async def _vehicle(self, route: Route, counter: int, now: float) -> None:
        vehicle, gateway = route.vehicle, route.gateway
        held = self.issued.get(vehicle.address)
        if held is not None and held.gateway != gateway:
            await self._withdraw(vehicle, held.gateway, f"it is on {gateway} now")
            del self.issued[vehicle.address]
            held = None
        if gateway is None or self.settings.sync_budget <= 0:
            return
        key = keys.for_commands(vehicle)
        horizon = self.settings.sync_budget / self.settings.time_scale
        if held is not None and held.key == key and now < held.at + horizon / RENEW:
            return
        start = max(int(now) + 1, counter + 1)
        frames = scheduled_syncs(vehicle, start, self.step, math.ceil(horizon / self.step))
        message = SyncBudgetMessage(
            f"syncs-{gateway}-{vehicle.address}-{start}-k{key[0]}", gateway, vehicle.address, tuple(frames),
            self.interval, self.step, self.ack_timeout(),
        )  # fmt: skip
        await self.publish(subjects.syncs(gateway, vehicle.address), message.encode(), message.id)
        self.issued[vehicle.address] = Issued(gateway, now, key)
        log.info(
            "vehicle %s: %d pre-signed SYNCs to %s, one every %.0f s for %.0f s",
            vehicle.name, len(frames), gateway, self.step, horizon,
        )  # fmt: skip

    async def _withdraw(self, vehicle: Vehicle, gateway: str, why: str) -> None:
        message = SyncBudgetMessage(
            f"withdraw-{gateway}-{vehicle.address}-{time.time_ns()}", gateway, vehicle.address, (),
            self.interval, self.step, self.ack_timeout(),
        )  # fmt: skip
        await self.publish(subjects.syncs(gateway, vehicle.address), message.encode(), message.id)
        log.info("vehicle %s: pre-signed SYNCs withdrawn from %s (%s)", vehicle.name, gateway, why)
