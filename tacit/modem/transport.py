"""The serial transport: a port opened with pyserial's ``serial_for_url`` (device paths, ptys,
``socket://``), a reader thread that splits bytes into lines and hands them to the event loop, and
line writes. A failed read or write is reported once through ``on_lost``; reopening is the driver's
decision."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import Callable

import serial

from tacit import nmea
from tacit.modem.events import DriverSettings, PortLost
from tacit.modemlog import FROM_MODEM, TO_MODEM, ModemLog

log = logging.getLogger("tacit.modem")


class Transport:
    def __init__(
        self, settings: DriverSettings, on_line: Callable[[bytes], None], on_lost: Callable[[str], None]
    ) -> None:
        self.settings = settings
        self.on_line = on_line
        self.on_lost = on_lost
        self.name = f"{settings.address}@{settings.url}"
        self.stopping = False
        self._port: serial.SerialBase | None = None
        self._reader: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._log = ModemLog(settings.log_path) if settings.log_path else None
        self.counters: dict[str, int] = {"lines_in": 0, "lines_out": 0}

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def open(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        port = serial.serial_for_url(self.settings.url, baudrate=self.settings.baudrate, timeout=0.1)
        self._port = port
        self._reader = threading.Thread(target=self._read_loop, args=(port, loop), daemon=True)
        self._reader.start()

    def close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        if self._reader is not None and self._reader is not threading.current_thread():
            self._reader.join(timeout=1.0)
        self._reader = None

    def close_log(self) -> None:
        if self._log:
            self._log.close()

    def _read_loop(self, port: serial.SerialBase, loop: asyncio.AbstractEventLoop) -> None:
        """Reader thread: split bytes into lines and hand them to the event loop."""
        buffer = b""
        try:
            while self._port is not None and self._port is port:
                chunk = port.read(max(1, port.in_waiting))
                if not chunk:
                    continue
                buffer += chunk
                *lines, buffer = buffer.split(b"\n")
                if len(buffer) > nmea.MAX_LINE:
                    lines.append(buffer)
                    buffer = b""
                for line in lines:
                    loop.call_soon_threadsafe(self.on_line, line)
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            if self._port is port and not self.stopping:
                with contextlib.suppress(RuntimeError):
                    loop.call_soon_threadsafe(self.on_lost, f"read failed: {exc}")

    def received(self, text: str) -> None:
        """Count and log a line from the modem (the modem log records every sentence both ways)."""
        self.counters["lines_in"] += 1
        if self._log:
            self._log.write(FROM_MODEM, text)

    def write(self, sentence: nmea.Sentence | nmea.Raw) -> None:
        line = sentence.line(nmea.talker_of(sentence, host=True))
        port = self._port
        if port is None:
            raise PortLost("port is not open")
        try:
            port.write(line.encode("ascii"))
        except (serial.SerialException, OSError) as exc:
            self.on_lost(f"write failed: {exc}")
            raise PortLost(str(exc)) from exc
        self.counters["lines_out"] += 1
        if self._log:
            self._log.write(TO_MODEM, line)
        log.debug("modem %s > %s", self.name, line.rstrip())
