"""Async driver for a WHOI Micro-Modem over a serial port (pyserial ``serial_for_url``).

It behaves as the mature host drivers do (goby3's ``mm_driver``), in three parts: the serial transport
(``transport``: the port and a reader thread, so any URL pyserial accepts works), the command channel
(``commands``: one command outstanding until echoed, resent, given up), and the data cycles
(``cycles``: cycle-init, data requests, ACKs, polls, pings, received frames with their statistics).
``driver`` composes them and keeps the link alive (keep-alive, reboot, reconnect).
"""

from tacit.modem.driver import ModemDriver
from tacit.modem.events import (
    AckReceived,
    DriverSettings,
    Event,
    FrameBad,
    LineRejected,
    LinkState,
    ModemBusy,
    ModemError,
    ModemReported,
    ModemTimeout,
    PortLost,
    ReceivedFrame,
    StateChanged,
    TransmitResult,
)

__all__ = [
    "AckReceived", "DriverSettings", "Event", "FrameBad", "LineRejected", "LinkState", "ModemDriver",
    "ModemBusy", "ModemError", "ModemReported", "ModemTimeout", "PortLost", "ReceivedFrame", "StateChanged",
    "TransmitResult",
]  # fmt: skip
