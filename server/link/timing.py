"""How long the MAC waits: slot timings from the range to the vehicle and the rate's airtime.

``time_scale`` shortens every wait for simulations running faster than real time.
"""

from __future__ import annotations

from server.core.config import Settings
from server.link.state import VehicleState
from tacit import rates

MAX_PING_RANGE_M = 4000.0


class Timing:
    def __init__(self, settings: Settings) -> None:
        self.settings = settings

    def range_m(self, vehicle: VehicleState) -> float:
        """The measured range (pings), or the configured default until one is measured."""
        return vehicle.range_m if vehicle.range_m is not None else self.settings.default_range

    def travel_s(self, vehicle: VehicleState) -> float:
        return self.range_m(vehicle) / self.settings.sound_speed

    def ack_timeout(self, vehicle: VehicleState) -> float:
        """How long to wait for a command's ACK: the round trip, the turnaround and the ACK's airtime."""
        floor = 2 * self.travel_s(vehicle) + rates.TURNAROUND_S + rates.airtime_s(rates.ACK_BITS, 0)
        return (floor * 1.5 + 2.0) / self.settings.time_scale

    def poll_window(self, vehicle: VehicleState, rate: int) -> float:
        """How long a poll's answer may take: the cycle-init, the round trip, the vehicle's modem asking
        its host for data, and the longest answer at the rate (the modem reports the frames once the
        whole transmission is in). An unanswered poll costs all of it."""
        answer = rates.data_airtime_s(rate, rates.rate(rate).frames)
        window = rates.airtime_s(rates.CYCLE_INIT_BITS, 0) + 2 * self.travel_s(vehicle) + 1.0 + answer
        return window * 1.3 / self.settings.time_scale

    def busy_wait(self) -> float:
        """How long our modem may still be busy with the last cycle (it owes the answer's ACK) when the
        next slot starts: tried again after this, the slot stays the same vehicle's."""
        return (rates.TURNAROUND_S + 2 * rates.airtime_s(rates.ACK_BITS, 0)) / self.settings.time_scale

    def ping_timeout(self) -> float:
        return (2 * MAX_PING_RANGE_M / self.settings.sound_speed + 2) / self.settings.time_scale

    def idle_wait(self) -> float:
        return self.settings.poll_interval / self.settings.time_scale

    def ping_due(self, last_ping: float, now: float) -> bool:
        return now - last_ping > self.settings.ping_interval / self.settings.time_scale

    def confirm_deadline(self, now: float) -> float:
        """An ACKed command last updated before this, with no check-point confirming it, is sent again."""
        return now - self.settings.confirm_timeout / self.settings.time_scale
