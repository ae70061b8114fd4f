"""How long each exchange of the MAC holds the band: the one home of the link's timing rules.

An exchange is over when its last sound has left the shore's modem and what answers it is in: a command's
frame, the vehicle's ACK back; a poll, the vehicle's frames at the rate asked and the shore modem's ACK of
them; a ping, its reply. Each is sized from the airtime of the rate (``tacit.rates``) and the two-way
travel at the vehicle's last known range (its default until a ping or a round trip measured it), with a
margin. The MAC starts an exchange only when this whole time ends inside its slot (``gateway.mac``).

``time_scale`` shortens every duration for simulations running faster than real time.
"""

from __future__ import annotations

from dataclasses import dataclass

from tacit import rates

MAX_PING_RANGE_M = 4000.0
MARGIN_S = 0.5  # on every wait for an answer: the modems' own latencies, the serial lines
HOST_ANSWER_S = 1.0  # the vehicle's modem asking its host for the data it sends
SETTLE_S = 0.2  # what the shore's modem needs between two exchanges (its log lines, the next cycle-init)


@dataclass(frozen=True)
class Timing:
    default_range: float = 1000.0  # m, until a vehicle's range is measured
    sound_speed: float = 1500.0
    time_scale: float = 1.0

    def travel_s(self, range_m: float | None) -> float:
        return (self.default_range if range_m is None else range_m) / self.sound_speed

    def ack_wait(self, range_m: float | None) -> float:
        """How long a command's frame waits for the vehicle's ACK once it has left."""
        floor = 2 * self.travel_s(range_m) + rates.TURNAROUND_S + rates.airtime_s(rates.ACK_BITS, 0)
        return (floor + MARGIN_S) / self.time_scale

    def command(self, range_m: float | None) -> float:
        """A command (or SYNC) attempt: cycle-init and one rate-0 frame out, the ACK back."""
        out = rates.airtime_s(rates.CYCLE_INIT_BITS, 0) + rates.data_airtime_s(0, 1)
        return out / self.time_scale + self.ack_wait(range_m) + SETTLE_S / self.time_scale

    def poll_window(self, range_m: float | None, rate: int) -> float:
        """How long a poll's answer at ``rate`` may take to be in: the cycle-init, the round trip, the
        vehicle's host and its longest answer at the rate (the modem reports the frames once the whole
        transmission is in). An unanswered poll costs all of it."""
        answer = rates.data_airtime_s(rate, rates.rate(rate).frames)
        window = (
            rates.airtime_s(rates.CYCLE_INIT_BITS, 0) + 2 * self.travel_s(range_m) + HOST_ANSWER_S + answer
        )
        return (window + MARGIN_S) / self.time_scale

    def ack_tail(self) -> float:
        """After a poll's answer is in: the shore modem's ACK of its frames, and the next cycle's settling."""
        return (rates.TURNAROUND_S + rates.airtime_s(rates.ACK_BITS, 0) + SETTLE_S) / self.time_scale

    def poll(self, range_m: float | None, rate: int) -> float:
        """A whole poll exchange at ``rate``."""
        return self.poll_window(range_m, rate) + self.ack_tail()

    def ping_timeout(self, range_m: float | None) -> float:
        """A ping's reply wait: twice the last known range (or ``MAX_PING_RANGE_M`` when none is known)."""
        reach = MAX_PING_RANGE_M if range_m is None else min(MAX_PING_RANGE_M, 2 * range_m + 200.0)
        return (2 * reach / self.sound_speed + 2 * rates.airtime_s(rates.PING_BITS, 0)) / self.time_scale

    def ping(self, range_m: float | None) -> float:
        """A whole ranging exchange."""
        return self.ping_timeout(range_m) + SETTLE_S / self.time_scale

    def shortest(self) -> float:
        """The shortest slot that holds one exchange: a rate-0 command at the default range."""
        return self.command(None)
