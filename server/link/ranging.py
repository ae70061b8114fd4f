"""Ranging: the modem's two-way travel-time pings, which set each vehicle's slot timings."""

from __future__ import annotations

import logging
import math
import time

from server.core.config import Settings
from server.core.events import Bus, LinkNotice
from server.link.models import LinkEvent
from server.link.state import VehicleState
from server.link.store import LinkStore
from server.link.timing import Timing
from tacit import modem as mm

log = logging.getLogger("tacit.server.link")


class Ranging:
    def __init__(self, settings: Settings, store: LinkStore, bus: Bus, timing: Timing) -> None:
        self.settings = settings
        self.store = store
        self.bus = bus
        self.timing = timing
        self.pings = 0
        self._last: dict[int, float] = {}

    def due(self, vehicle: VehicleState) -> bool:
        return self.timing.ping_due(self._last.get(vehicle.address, -math.inf), time.monotonic())

    async def ping(self, driver: mm.ModemDriver, vehicle: VehicleState) -> None:
        self._last[vehicle.address] = time.monotonic()  # intervals: a wall clock step must not stop pings
        self.pings += 1
        travel = await driver.ping(vehicle.address, timeout=self.timing.ping_timeout())
        if travel is None:
            return
        vehicle.range_m = travel * self.settings.sound_speed
        await self.store.add(
            LinkEvent(vehicle_id=vehicle.id, kind="range", detail={"range_m": vehicle.range_m})
        )
        self.bus.publish(
            LinkNotice(event="range", vehicle=vehicle.name, detail={"range_m": round(vehicle.range_m, 1)})
        )
        log.info("vehicle %s: range %.1f m", vehicle.name, vehicle.range_m)
