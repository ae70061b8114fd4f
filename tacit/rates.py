"""Micro-Modem packet rates: frames, frame sizes and nominal bit rates, as WHOI documents them.

Shared by the simulator (airtime) and the link policy (which rate to use, how long a slot lasts).
Airtime of a transmission = its bits / the rate's nominal bit rate + a fixed acquisition overhead.
Rate 6's figures are not verified against a manual.
"""

from __future__ import annotations

from dataclasses import dataclass

# Transmission timing (the simulator models it; the link engine sizes its slots and timeouts with it).
ACQUISITION_S = 0.4  # detection probe and guard per transmission
CYCLE_INIT_BITS = 21  # src, dest, rate, ack, frames of an FSK cycle-init
ACK_BITS = 13  # an acknowledgement is a mini-packet
PING_BITS = 13
TURNAROUND_S = 0.1  # a modem's processing between hearing and answering


@dataclass(frozen=True)
class Rate:
    number: int
    modulation: str
    frames: int
    frame_bytes: int
    bits_per_second: float

    @property
    def max_bytes(self) -> int:
        return self.frames * self.frame_bytes


RATES: dict[int, Rate] = {
    0: Rate(0, "FH-FSK", 1, 32, 80.0),
    1: Rate(1, "PSK, BCH 128:8", 3, 64, 250.0),
    2: Rate(2, "PSK, DSS 1/15", 3, 64, 500.0),
    3: Rate(3, "PSK, DSS 1/7", 2, 256, 1200.0),
    4: Rate(4, "PSK, BCH 64:10", 2, 256, 1300.0),
    5: Rate(5, "PSK, Hamming 14:9", 8, 256, 5300.0),
    6: Rate(6, "PSK, DSS 1/15", 6, 32, 490.0),
}


def rate(number: int) -> Rate:
    """The rate with this number, or a clear error."""
    try:
        return RATES[number]
    except KeyError:
        raise ValueError(f"unknown Micro-Modem rate {number} (0-6)") from None


def airtime_s(bits: int, rate_number: int) -> float:
    """Seconds one transmission of ``bits`` occupies the channel, acquisition included."""
    return ACQUISITION_S + bits / rate(rate_number).bits_per_second


def data_airtime_s(rate_number: int, nframes: int) -> float:
    r = rate(rate_number)
    return airtime_s(r.frame_bytes * 8 * nframes, rate_number)
