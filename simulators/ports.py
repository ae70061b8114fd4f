"""Host-facing ports of an emulated modem: a real pty (and optionally a TCP port).

The pty's slave path is what a host opens, exactly as it would open ``/dev/ttyUSB0``; a stable symlink
can point at it (as socat's ``link=`` does). Output is written non-blocking: a host that stops
reading loses lines (counted), it never stalls the simulation.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import tty
from collections.abc import Callable
from pathlib import Path

from tacit import nmea

log = logging.getLogger("simulators.ports")


class LineSplitter:
    """Bytes in, complete lines out; an over-long line without newline is passed on to be rejected."""

    def __init__(self, on_line: Callable[[bytes], None]) -> None:
        self.on_line = on_line
        self._buffer = b""

    def feed(self, data: bytes) -> None:
        self._buffer += data
        *lines, self._buffer = self._buffer.split(b"\n")
        if len(self._buffer) > nmea.MAX_LINE:
            lines.append(self._buffer)
            self._buffer = b""
        for line in lines:
            if line.strip(b"\r\0 "):
                self.on_line(line.rstrip(b"\r"))


class PtyPort:
    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        on_line: Callable[[bytes], None],
        link: str | Path | None = None,
    ) -> None:
        self.loop = loop
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line discipline: bytes as a serial port carries them
        os.set_blocking(self.master, False)
        self.tty = os.ttyname(self._slave)
        self.link = Path(link) if link else None
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()
            self.link.symlink_to(self.tty)
        self.path = str(self.link or self.tty)
        self.dropped = 0
        self._splitter = LineSplitter(on_line)
        loop.add_reader(self.master, self._readable)

    def _readable(self) -> None:
        try:
            data = os.read(self.master, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            return
        if data:
            self._splitter.feed(data)

    def write(self, line: str) -> None:
        try:
            os.write(self.master, line.encode("ascii"))
        except BlockingIOError:
            self.dropped += 1
        except OSError as exc:
            self.dropped += 1
            log.debug("pty %s: write failed: %s", self.tty, exc)

    def close(self) -> None:
        self.loop.remove_reader(self.master)
        for fd in (self.master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()


class TcpPort:
    """The same dialect on a TCP port (pyserial ``socket://host:port``); every client sees all output."""

    def __init__(self, on_line: Callable[[bytes], None]) -> None:
        self.on_line = on_line
        self.writers: set[asyncio.StreamWriter] = set()
        self.server: asyncio.base_events.Server | None = None
        self.port = 0

    async def start(self, host: str = "127.0.0.1", port: int = 0) -> None:
        self.server = await asyncio.start_server(self._client, host, port)
        self.port = self.server.sockets[0].getsockname()[1]

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.writers.add(writer)
        splitter = LineSplitter(self.on_line)
        try:
            while data := await reader.read(4096):
                splitter.feed(data)
        except ConnectionError:
            pass
        finally:
            self.writers.discard(writer)
            writer.close()

    def write(self, line: str) -> None:
        for writer in list(self.writers):
            if writer.transport.get_write_buffer_size() < 65536:
                writer.write(line.encode("ascii"))

    def close(self) -> None:
        for writer in list(self.writers):
            writer.close()
        if self.server is not None:
            self.server.close()
