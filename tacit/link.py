"""Link policy shared by the shore and the vehicle: which rate to use, and how packets fill frames.

Rate choice (the paper's evaluation: "the decision on which packet type to use is taken based on the
underwater channel along with a metric between loss-sensitivity and delay-sensitivity"):
loss-sensitive traffic (control packets, their acknowledgements) always goes at rate 0, the most
robust; bulk traffic (queued priority and check-point packets) goes at the fastest rate whose SNR
threshold, plus a margin, is below the recent SNR, and at rate 0 when the SNR is unknown or poor.
Every packet stays 32 bytes whatever the rate (the paper's uniformity); a faster rate carries several
packets per frame.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

from tacit.packets import PACKET_SIZE
from tacit.rates import RATES, rate

# SNR (dB, the modem's $CACST snr_in) above which each rate is used for bulk traffic. Rate 0's is
# -inf: it is the fallback. The thresholds follow the simulator's FER model plus a 6 dB margin.
BULK_RATE_SNR_DB: dict[int, float] = {0: float("-inf"), 1: 14.0, 5: 20.0}


def choose_rate(snr_db: float | None, loss_sensitive: bool, packets: int = 1) -> int:
    """The rate for a transmission of ``packets`` 32-byte packets (rate 0 when the SNR is unknown or
    not a number: a ``nan`` from the modem must never leave no rate to choose)."""
    if loss_sensitive or snr_db is None or not math.isfinite(snr_db) or packets <= 1:
        return 0
    usable = [r for r, threshold in BULK_RATE_SNR_DB.items() if snr_db >= threshold]
    return max(usable)


def packets_per_frame(rate_number: int) -> int:
    return max(1, rate(rate_number).frame_bytes // PACKET_SIZE)


def capacity(rate_number: int) -> int:
    """How many 32-byte packets one transmission at this rate carries."""
    r = rate(rate_number)
    return packets_per_frame(rate_number) * r.frames


def to_frames(packets: Iterable[bytes], rate_number: int) -> list[bytes]:
    """Pack packets into the frames of one transmission (at most ``capacity`` packets)."""
    per_frame = packets_per_frame(rate_number)
    chunk: list[bytes] = []
    frames: list[bytes] = []
    for packet in packets:
        if len(packet) != PACKET_SIZE:
            raise ValueError(f"a packet is {PACKET_SIZE} bytes, got {len(packet)}")
        chunk.append(packet)
        if len(chunk) == per_frame:
            frames.append(b"".join(chunk))
            chunk = []
    if chunk:
        frames.append(b"".join(chunk))
    if len(frames) > RATES[rate_number].frames:
        raise ValueError(f"{len(frames)} frames exceed rate {rate_number}'s {RATES[rate_number].frames}")
    return frames


def from_frame(data: bytes) -> list[bytes]:
    """The 32-byte packets in a received frame (all-zero padding chunks are dropped)."""
    chunks = [data[i : i + PACKET_SIZE] for i in range(0, len(data) - len(data) % PACKET_SIZE, PACKET_SIZE)]
    return [c for c in chunks if any(c)]


@dataclass
class SeenWindow:
    """Exactly-once delivery for vehicle -> shore packets: the same 32 bytes within the last ``size``
    packets from a vehicle is a retransmission (its ACK was lost), not a new packet. Check-points carry
    a time and priority payloads a tick index, so two different packets are never byte-identical."""

    size: int = 512
    recent: list[bytes] = field(default_factory=list)

    def first_time(self, packet: bytes) -> bool:
        if packet in self.recent:
            return False
        self.recent.append(bytes(packet))
        del self.recent[: -self.size]
        return True
