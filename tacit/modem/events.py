"""What the Micro-Modem driver reports and how it is configured: link states, errors, events, settings."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any

from tacit import nmea


class LinkState(enum.Enum):
    CLOSED = "closed"
    CONNECTING = "connecting"
    CONFIGURING = "configuring"
    READY = "ready"
    NOT_RESPONDING = "not_responding"


class ModemError(RuntimeError):
    """A command the modem did not carry out."""


class ModemBusy(ModemError):
    """The modem refused a command because it is still busy with a cycle (owes an ACK, say)."""


class ModemTimeout(ModemError):
    pass


class PortLost(ModemError):
    pass


@dataclass(frozen=True)
class ReceivedFrame:
    src: int
    dest: int
    ack: bool
    frame: int
    data: bytes
    stats: nmea.RxStats | None
    time: float

    def reception(self) -> tuple[int, float | None, float | None, dict[str, Any] | None]:
        """How it was heard, as the shore stores it: rate, SNR in and out, every statistic (0 and None
        when the modem reported none)."""
        stats = self.stats
        if stats is None:
            return 0, None, None, None
        return stats.rate, stats.snr_in, stats.snr_out, vars(stats)


@dataclass(frozen=True)
class FrameBad:
    """A frame the modem heard but could not decode (``BAD_CRC``) or expected but missed."""

    reason: str
    time: float


@dataclass(frozen=True)
class AckReceived:
    src: int
    frame: int
    time: float


@dataclass(frozen=True)
class StateChanged:
    state: LinkState
    detail: str = ""


@dataclass(frozen=True)
class LineRejected:
    line: str
    error: str


@dataclass(frozen=True)
class ModemReported:
    """A sentence the modem volunteered that callers may care about (``$CAERR``, ``$CAREV``)."""

    sentence: nmea.Sentence


Event = ReceivedFrame | FrameBad | AckReceived | StateChanged | LineRejected | ModemReported


@dataclass(frozen=True)
class TransmitResult:
    dest: int
    frames: int
    transmitted: bool
    acked: frozenset[int] = frozenset()
    error: str = ""

    @property
    def all_acked(self) -> bool:
        return len(self.acked) == self.frames


@dataclass
class DriverSettings:
    url: str
    address: int
    baudrate: int = 19200
    echo_timeout: float = 5.0
    tries: int = 3
    failures_before_down: int = 2
    keepalive: float = 10.0
    drq_timeout: float = 10.0
    transmit_timeout: float = 30.0
    ack_timeout: float = 20.0
    stats_grace: float = 0.5
    reconnect_min: float = 0.2
    reconnect_max: float = 10.0
    config: dict[str, str] = field(default_factory=lambda: {"CST": "1", "XST": "1", "REV": "1"})
    set_clock: bool = True
    log_path: str | None = None
