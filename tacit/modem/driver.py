"""The driver: one Micro-Modem on one serial port, its link state, and what keeps it alive.

It composes the transport (``transport``), the command channel (``commands``) and the data cycles
(``cycles``), as goby3 keeps driver, MAC and queue apart. A keep-alive query runs while idle.
``$CAREV ... INIT`` (the modem rebooted) re-sends the configuration and clock. If the port disappears,
the driver reopens it with backoff and configures the modem again; callers see the link state change,
not an exception.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import logging
from collections.abc import Callable, Coroutine
from typing import Any

import serial

from tacit import nmea
from tacit.modem.commands import CommandChannel
from tacit.modem.cycles import Cycles
from tacit.modem.events import (
    DriverSettings,
    Event,
    LineRejected,
    LinkState,
    ModemError,
    ModemReported,
    PortLost,
    StateChanged,
    TransmitResult,
)
from tacit.modem.transport import Transport

log = logging.getLogger("tacit.modem")


class ModemDriver:
    """One Micro-Modem on one serial port."""

    def __init__(self, settings: DriverSettings) -> None:
        self.settings = settings
        self.state = LinkState.CLOSED
        self.revision: nmea.Revision | None = None
        self._listeners: list[Callable[[Event], None]] = []
        self._tasks: set[asyncio.Task[Any]] = set()
        self._reconnecting = False
        self._stopping = False
        self.transport = Transport(settings, self._on_line, self._port_lost)
        self.channel = CommandChannel(settings, self.transport, self._answering, self._silent)
        self.cycles = Cycles(settings, self.channel, self._emit, self._spawn)
        self.rejected = 0

    @property
    def counters(self) -> dict[str, int]:
        return {**self.transport.counters, "rejected": self.rejected, "resends": self.channel.resends}

    @property
    def poll_provider(self) -> Callable[[nmea.DataRequest], bytes | None] | None:
        """What to send when a remote polls us (the vehicle's data)."""
        return self.cycles.poll_provider

    @poll_provider.setter
    def poll_provider(self, provider: Callable[[nmea.DataRequest], bytes | None] | None) -> None:
        self.cycles.poll_provider = provider

    # --- lifecycle ------------------------------------------------------------------------------

    def add_listener(self, listener: Callable[[Event], None]) -> None:
        self._listeners.append(listener)

    async def start(self) -> None:
        """Open the port and configure the modem; if either fails, keep retrying in the background."""
        self._stopping = self.transport.stopping = False
        try:
            self._open()
            await self.configure()
        except (serial.SerialException, OSError, ModemError) as exc:
            log.warning("modem %s: start failed (%s); retrying in the background", self.transport.name, exc)
            self._port_lost(str(exc))
        self._spawn(self._keepalive())

    async def stop(self) -> None:
        self._stopping = self.transport.stopping = True
        for task in list(self._tasks):
            task.cancel()
        for task in list(self._tasks):
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        self.transport.close()
        self._set_state(LinkState.CLOSED)
        self.transport.close_log()

    def _spawn(self, coro: Coroutine[Any, Any, Any]) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _open(self) -> None:
        self._set_state(LinkState.CONNECTING)
        self.transport.open(asyncio.get_running_loop())

    def _set_state(self, state: LinkState, detail: str = "") -> None:
        if state is not self.state:
            log.info("modem %s: %s -> %s %s", self.transport.name, self.state.value, state.value, detail)
            self.state = state
            self._emit(StateChanged(state, detail))

    def _emit(self, event: Event) -> None:
        for listener in list(self._listeners):
            try:
                listener(event)
            except Exception:  # a listener's bug must not stop the driver
                log.exception("modem %s: listener failed on %r", self.transport.name, event)

    def _answering(self) -> None:
        if self.state is LinkState.NOT_RESPONDING:
            self._set_state(LinkState.READY, "answering again")

    def _silent(self, failures: int) -> None:
        if failures >= self.settings.failures_before_down and self.state is LinkState.READY:
            self._set_state(LinkState.NOT_RESPONDING, f"no echo for {failures} commands")

    # --- a lost port ----------------------------------------------------------------------------

    def _port_lost(self, why: str) -> None:
        if self._stopping or self._reconnecting:
            return
        self._reconnecting = True
        self.transport.close()
        self._set_state(LinkState.CONNECTING, why)
        lost = PortLost(why)
        self.channel.fail(lost)
        self.cycles.fail(lost)
        self._spawn(self._reconnect())

    async def _reconnect(self) -> None:
        delay = self.settings.reconnect_min
        try:
            while not self._stopping:
                await asyncio.sleep(delay)
                try:
                    self._open()
                    self._reconnecting = False
                    await self.configure()
                    return
                except (serial.SerialException, OSError, ModemError) as exc:
                    log.info(
                        "modem %s: reconnect failed (%s), next in %.1f s", self.transport.name, exc, delay
                    )
                    self._reconnecting = True
                    self.transport.close()
                    self._set_state(LinkState.CONNECTING, str(exc))
                    delay = min(delay * 2, self.settings.reconnect_max)
        finally:
            self._reconnecting = False

    # --- incoming sentences ---------------------------------------------------------------------

    def _on_line(self, raw: bytes) -> None:
        text = raw.decode("ascii", errors="backslashreplace").strip("\r\n\0 ")
        if not text:
            return
        self.transport.received(text)
        try:
            sentence = nmea.parse(raw)
        except nmea.NmeaError as exc:
            self.rejected += 1
            log.warning("modem %s: rejected line %r: %s", self.transport.name, text[:80], exc)
            self._emit(LineRejected(text, str(exc)))
            return
        log.debug("modem %s < %s", self.transport.name, text)
        self.channel.resolve(sentence)
        self.cycles.handle(sentence)
        if isinstance(sentence, nmea.Message) and sentence.type in nmea.Message.FAILURES:
            log.info("modem %s: %s %s", self.transport.name, sentence.type, sentence.value)
        elif isinstance(sentence, nmea.Revision):
            self._on_rev(sentence)
        elif isinstance(sentence, nmea.Error):
            self._on_err(sentence)

    def _on_rev(self, rev: nmea.Revision) -> None:
        self.revision = rev
        self._emit(ModemReported(rev))
        if rev.ident == "INIT" and self.state in (LinkState.READY, LinkState.NOT_RESPONDING):
            log.warning("modem %s: rebooted (REV INIT); configuring again", self.transport.name)
            self._spawn(self._reconfigure())

    def _on_err(self, err: nmea.Error) -> None:
        # BUSY is routine (our modem still owes an acknowledgement): the caller retries in the next slot
        level = logging.INFO if err.message == "BUSY" else logging.WARNING
        log.log(level, "modem %s: error %s %s %s", self.transport.name, err.module, err.number, err.message)
        self._emit(ModemReported(err))

    # --- commands and cycles --------------------------------------------------------------------

    async def command(self, sentence: nmea.Sentence) -> nmea.Sentence:
        """Send a host command and wait for its echo (``CommandChannel.command``)."""
        return await self.channel.command(sentence)

    async def configure(self) -> None:
        """Send own address, statistics settings and user configuration, then set the clock."""
        self._set_state(LinkState.CONFIGURING)
        await self.command(nmea.Config("SRC", str(self.settings.address)))
        for name, value in self.settings.config.items():
            await self.command(nmea.Config(name, str(value)))
        if self.settings.set_clock:
            now = dt.datetime.now(dt.UTC)
            await self.command(nmea.Clock(now.year, now.month, now.day, now.hour, now.minute, now.second))
        self._set_state(LinkState.READY)

    async def _reconfigure(self) -> None:
        try:
            await self.configure()
        except ModemError as exc:
            log.warning("modem %s: reconfiguration failed: %s", self.transport.name, exc)

    async def _keepalive(self) -> None:
        while not self._stopping:
            await asyncio.sleep(self.settings.keepalive)
            if self.channel.busy or self.cycles.lock.locked() or self._reconnecting:
                continue
            if self.state not in (LinkState.READY, LinkState.NOT_RESPONDING):
                continue
            was_down = self.state is LinkState.NOT_RESPONDING
            try:
                await self.command(nmea.ConfigQuery("SRC"))
                if was_down:
                    await self._reconfigure()
            except ModemError as exc:
                log.info("modem %s: keep-alive failed: %s", self.transport.name, exc)

    async def send(
        self,
        dest: int,
        frames: list[bytes],
        rate: int = 0,
        ack: bool = True,
        ack_timeout: float | None = None,
    ) -> TransmitResult:
        """Run one data cycle to ``dest`` (``Cycles.send``)."""
        return await self.cycles.send(dest, frames, rate, ack, ack_timeout)

    async def poll(self, remote: int, rate: int = 0, ack: bool = False, frames: int = 1) -> None:
        """Third-party poll: ask ``remote`` to send us up to ``frames`` frames of data (``Cycles.poll``)."""
        await self.cycles.poll(remote, rate, ack, frames)

    async def ping(self, dest: int, timeout: float = 10.0) -> float | None:
        """Two-way ping; the one-way travel time in seconds, or None (``Cycles.ping``)."""
        return await self.cycles.ping(dest, timeout)
