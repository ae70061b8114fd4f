"""The link's airtime by use (commands, polls, check-points, priority data) and the bits saved by
compression against sending every sample."""

from __future__ import annotations

from tacit import rates
from tacit.packets import PACKET_SIZE

FRAME_S = rates.data_airtime_s(0, 1)  # one 32-byte rate-0 frame, acquisition included
POLL_S = rates.airtime_s(rates.CYCLE_INIT_BITS, 0)
ACK_S = rates.airtime_s(rates.ACK_BITS, 0)


def by_use(commands_sent: int, polls: int, checkpoints: int, priority: int) -> dict[str, float]:
    """Seconds on the air by use: the link's, or one vehicle's (what was sent to it and what it sent)."""
    return {
        "commands": commands_sent * (FRAME_S + ACK_S),
        "polls": polls * POLL_S,
        "checkpoints": checkpoints * FRAME_S,
        "priority": priority * FRAME_S,
    }


def link_shares(commands_sent: int, polls: int, checkpoints: int, priority: int, samples: int) -> dict:
    """Airtime by use (seconds and shares), and bits saved against sending every sample (16 bits each)."""
    airtime = by_use(commands_sent, polls, checkpoints, priority)
    total = sum(airtime.values())
    raw_bits, sent_bits = samples * 16, priority * PACKET_SIZE * 8
    return {
        "airtime_s": {k: round(v, 1) for k, v in airtime.items()},
        "shares": {k: (round(v / total, 4) if total else 0.0) for k, v in airtime.items()},
        "counts": {"commands": commands_sent, "polls": polls, "checkpoints": checkpoints, "priority": priority,
                   "samples": samples},
        "bits": {"every_sample": raw_bits, "sent": sent_bits,
                 "saved_share": round(1 - sent_bits / raw_bits, 4) if raw_bits else None},
    }  # fmt: skip
