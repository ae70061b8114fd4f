"""Micro-Modem packet rates: frames, frame sizes and nominal bit rates (REFERENCE §1).

Shared by the simulator (airtime) and the link policy (which rate to use for a transmission).
Rate 6's figures are not verified against a manual.
"""

from __future__ import annotations

from dataclasses import dataclass


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
