"""Async driver for a WHOI Micro-Modem over a serial port (pyserial ``serial_for_url``).

It behaves as the mature host drivers do (goby3's ``mm_driver``): one command outstanding until the
modem echoes it, resent after ``echo_timeout``, skipped after ``tries``; repeated failures declare
the modem not responding. A keep-alive query runs while idle. ``$CAREV ... INIT`` (the modem
rebooted) re-sends the configuration and clock. If the port disappears, the driver reopens it with
backoff and configures the modem again; callers see the link state change, not an exception.

Received frames are delivered to listeners with the receive statistics (``$CACST``) that follow
them. A reader thread does the blocking serial I/O and hands lines to the event loop, so any URL
pyserial accepts works (device paths, ptys, ``socket://``).
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import enum
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import serial

from tacit import nmea
from tacit.modemlog import FROM_MODEM, TO_MODEM, ModemLog

log = logging.getLogger("tacit.modem")


class LinkState(enum.Enum):
    CLOSED = "closed"
    CONNECTING = "connecting"
    CONFIGURING = "configuring"
    READY = "ready"
    NOT_RESPONDING = "not_responding"


class ModemError(RuntimeError):
    """A command the modem did not carry out."""


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


# The echo that completes each host command: (sentence id of the echo, fields that must match).
_ECHO: dict[type[nmea.Sentence], str] = {
    nmea.Cycle: "CYC", nmea.TxData: "TXD", nmea.Config: "CFG", nmea.ConfigQuery: "CFG",
    nmea.Clock: "CLK", nmea.Ping: "MPC", nmea.MiniPacket: "MUC", nmea.Sleep: "MSC",
}  # fmt: skip


@dataclass
class _Transmission:
    dest: int
    frames: list[bytes]
    ack: bool
    finished: asyncio.Event = field(default_factory=asyncio.Event)
    acked: set[int] = field(default_factory=set)
    all_acked: asyncio.Event = field(default_factory=asyncio.Event)
    requested: asyncio.Event = field(default_factory=asyncio.Event)


class ModemDriver:
    """One Micro-Modem on one serial port."""

    def __init__(self, settings: DriverSettings) -> None:
        self.settings = settings
        self.state = LinkState.CLOSED
        self.revision: nmea.Revision | None = None
        self.poll_provider: Callable[[nmea.DataRequest], bytes | None] | None = None
        self._listeners: list[Callable[[Event], None]] = []
        self._port: serial.SerialBase | None = None
        self._reader: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._pending: tuple[str, nmea.Sentence, asyncio.Future[nmea.Sentence]] | None = None
        self._command_lock = asyncio.Lock()
        self._cycle_lock = asyncio.Lock()
        self._tx: _Transmission | None = None
        self._rx_buffer: list[nmea.RxData] = []
        self._rx_flush: asyncio.TimerHandle | None = None
        self._ping_waiters: dict[int, asyncio.Future[float]] = {}
        self._failures = 0
        self._tasks: set[asyncio.Task[None]] = set()
        self._reconnecting = False
        self._stopping = False
        self._log = ModemLog(settings.log_path) if settings.log_path else None
        self.counters: dict[str, int] = {"lines_in": 0, "lines_out": 0, "rejected": 0, "resends": 0}

    # --- lifecycle ------------------------------------------------------------------------------

    def add_listener(self, listener: Callable[[Event], None]) -> None:
        self._listeners.append(listener)

    async def start(self) -> None:
        """Open the port and configure the modem; if either fails, keep retrying in the background."""
        self._loop = asyncio.get_running_loop()
        self._stopping = False
        try:
            self._open()
            await self.configure()
        except (serial.SerialException, OSError, ModemError) as exc:
            log.warning("modem %s: start failed (%s); retrying in the background", self._name, exc)
            self._port_lost(str(exc))
        self._spawn(self._keepalive())

    async def stop(self) -> None:
        self._stopping = True
        for task in list(self._tasks):
            task.cancel()
        for task in list(self._tasks):
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        self._close()
        self._set_state(LinkState.CLOSED)
        if self._log:
            self._log.close()

    @property
    def _name(self) -> str:
        return f"{self.settings.address}@{self.settings.url}"

    def _spawn(self, coro) -> None:  # noqa: ANN001 - a coroutine
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _open(self) -> None:
        self._set_state(LinkState.CONNECTING)
        port = serial.serial_for_url(self.settings.url, baudrate=self.settings.baudrate, timeout=0.1)
        self._port = port
        self._reader = threading.Thread(target=self._read_loop, args=(port,), daemon=True)
        self._reader.start()

    def _close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        if self._reader is not None and self._reader is not threading.current_thread():
            self._reader.join(timeout=1.0)
        self._reader = None

    def _set_state(self, state: LinkState, detail: str = "") -> None:
        if state is not self.state:
            log.info("modem %s: %s -> %s %s", self._name, self.state.value, state.value, detail)
            self.state = state
            self._emit(StateChanged(state, detail))

    def _emit(self, event: Event) -> None:
        for listener in list(self._listeners):
            try:
                listener(event)
            except Exception:  # a listener's bug must not stop the driver
                log.exception("modem %s: listener failed on %r", self._name, event)

    # --- serial I/O -----------------------------------------------------------------------------

    def _read_loop(self, port: serial.SerialBase) -> None:
        """Reader thread: split bytes into lines and hand them to the event loop."""
        buffer = b""
        loop = self._loop
        assert loop is not None
        try:
            while self._port is port:
                chunk = port.read(max(1, port.in_waiting))
                if not chunk:
                    continue
                buffer += chunk
                *lines, buffer = buffer.split(b"\n")
                if len(buffer) > nmea.MAX_LINE:
                    lines.append(buffer)
                    buffer = b""
                for line in lines:
                    loop.call_soon_threadsafe(self._on_line, line)
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            if self._port is port and not self._stopping:
                with contextlib.suppress(RuntimeError):
                    loop.call_soon_threadsafe(self._port_lost, f"read failed: {exc}")

    def _write(self, sentence: nmea.Sentence | nmea.Raw) -> None:
        line = sentence.line(nmea.talker_of(sentence, host=True))
        port = self._port
        if port is None:
            raise PortLost("port is not open")
        try:
            port.write(line.encode("ascii"))
        except (serial.SerialException, OSError) as exc:
            self._port_lost(f"write failed: {exc}")
            raise PortLost(str(exc)) from exc
        self.counters["lines_out"] += 1
        if self._log:
            self._log.write(TO_MODEM, line)
        log.debug("modem %s > %s", self._name, line.rstrip())

    def _port_lost(self, why: str) -> None:
        if self._stopping or self._reconnecting:
            return
        self._reconnecting = True
        self._close()
        self._set_state(LinkState.CONNECTING, why)
        self._fail_pending(PortLost(why))
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
                    log.info("modem %s: reconnect failed (%s), next in %.1f s", self._name, exc, delay)
                    self._reconnecting = True
                    self._close()
                    self._set_state(LinkState.CONNECTING, str(exc))
                    delay = min(delay * 2, self.settings.reconnect_max)
        finally:
            self._reconnecting = False

    def _fail_pending(self, exc: Exception) -> None:
        if self._pending and not self._pending[2].done():
            self._pending[2].set_exception(exc)
        for waiter in self._ping_waiters.values():
            if not waiter.done():
                waiter.set_exception(exc)
        if self._tx:
            self._tx.finished.set()
            self._tx.all_acked.set()
            self._tx.requested.set()

    # --- incoming sentences ---------------------------------------------------------------------

    def _on_line(self, raw: bytes) -> None:
        text = raw.decode("ascii", errors="backslashreplace").strip("\r\n\0 ")
        if not text:
            return
        self.counters["lines_in"] += 1
        if self._log:
            self._log.write(FROM_MODEM, text)
        try:
            sentence = nmea.parse(raw)
        except nmea.NmeaError as exc:
            self.counters["rejected"] += 1
            log.warning("modem %s: rejected line %r: %s", self._name, text[:80], exc)
            self._emit(LineRejected(text, str(exc)))
            return
        log.debug("modem %s < %s", self._name, text)
        self._resolve_echo(sentence)
        handler = self._HANDLERS.get(type(sentence))
        if handler is not None:
            handler(self, sentence)

    def _resolve_echo(self, sentence: nmea.Sentence | nmea.Raw) -> None:
        if self._pending is None or isinstance(sentence, nmea.Raw):
            return
        sid, sent, future = self._pending
        if future.done():
            return
        if isinstance(sentence, nmea.Error) and sentence.module in ("NMEA", sent.SID):
            future.set_exception(ModemError(f"modem refused {sent.SID}: {sentence.message}"))
        elif sentence.SID == sid and nmea.MODEM in sentence.TALKERS and _echo_matches(sent, sentence):
            future.set_result(sentence)

    def _on_drq(self, drq: nmea.DataRequest) -> None:
        self._spawn(self._answer_drq(drq))

    async def _answer_drq(self, drq: nmea.DataRequest) -> None:
        tx = self._tx
        if tx is not None and drq.dest == tx.dest and drq.src == self.settings.address:
            data = tx.frames[drq.frame - 1] if 0 < drq.frame <= len(tx.frames) else b""
            tx.requested.set()
        else:
            data = (self.poll_provider(drq) if self.poll_provider else None) or b""
        try:
            await self.command(nmea.TxData(drq.src, drq.dest, drq.ack, data[: drq.maxbytes]))
        except ModemError as exc:
            log.warning(
                "modem %s: could not answer data request for frame %d: %s", self._name, drq.frame, exc
            )

    def _on_txf(self, txf: nmea.TxFinished) -> None:
        if self._tx is not None and txf.nbytes > 0:
            self._tx.finished.set()

    def _on_xst(self, xst: nmea.TxStats) -> None:
        if self._tx is not None:
            self._tx.finished.set()

    def _on_ack(self, ack: nmea.Ack) -> None:
        now = time.time()
        tx = self._tx
        if tx is not None and ack.src == tx.dest and ack.dest == self.settings.address:
            tx.acked.add(ack.frame)
            if len(tx.acked) >= len(tx.frames):
                tx.all_acked.set()
        self._emit(AckReceived(ack.src, ack.frame, now))

    def _on_rxd(self, rxd: nmea.RxData) -> None:
        self._rx_buffer.append(rxd)
        if self._rx_flush is None and self._loop is not None:
            self._rx_flush = self._loop.call_later(self.settings.stats_grace, self._flush_rx, None)

    def _on_cst(self, cst: nmea.RxStats) -> None:
        if cst.mode != 0 and not self._rx_buffer:
            reason = "bad_crc" if cst.mode == 1 else "timeout"
            self._emit(FrameBad(reason, time.time()))
        self._flush_rx(cst)

    def _flush_rx(self, stats: nmea.RxStats | None) -> None:
        if self._rx_flush is not None:
            self._rx_flush.cancel()
            self._rx_flush = None
        frames, self._rx_buffer = self._rx_buffer, []
        now = time.time()
        for rxd in frames:
            self._emit(ReceivedFrame(rxd.src, rxd.dest, rxd.ack, rxd.frame, rxd.data, stats, now))

    def _on_msg(self, msg: nmea.Message) -> None:
        if msg.type in ("BAD_CRC", "PACKET_TIMEOUT"):
            log.info("modem %s: %s %s", self._name, msg.type, msg.value)

    def _on_ping_reply(self, reply: nmea.PingReply) -> None:
        waiter = self._ping_waiters.get(reply.src)
        if waiter is not None and not waiter.done() and reply.dest == self.settings.address:
            waiter.set_result(abs(reply.travel_time))

    def _on_rev(self, rev: nmea.Revision) -> None:
        self.revision = rev
        self._emit(ModemReported(rev))
        if rev.ident == "INIT" and self.state in (LinkState.READY, LinkState.NOT_RESPONDING):
            log.warning("modem %s: rebooted (REV INIT); configuring again", self._name)
            self._spawn(self._reconfigure())

    def _on_err(self, err: nmea.Error) -> None:
        # BUSY is routine (our modem still owes an acknowledgement): the caller retries in the next slot
        level = logging.INFO if err.message == "BUSY" else logging.WARNING
        log.log(level, "modem %s: error %s %s %s", self._name, err.module, err.number, err.message)
        self._emit(ModemReported(err))

    _HANDLERS: dict[type, Callable[[ModemDriver, nmea.Sentence], None]] = {
        nmea.DataRequest: _on_drq, nmea.TxFinished: _on_txf, nmea.TxStats: _on_xst, nmea.Ack: _on_ack,
        nmea.RxData: _on_rxd, nmea.RxStats: _on_cst, nmea.Message: _on_msg, nmea.PingReply: _on_ping_reply,
        nmea.Revision: _on_rev, nmea.Error: _on_err,
    }  # fmt: skip

    # --- commands -------------------------------------------------------------------------------

    async def command(self, sentence: nmea.Sentence) -> nmea.Sentence:
        """Send a host command and wait for its echo; resend on timeout; raise after ``tries``."""
        sid = _ECHO.get(type(sentence))
        if sid is None:
            raise ValueError(f"{type(sentence).__name__} is not a host command with an echo")
        async with self._command_lock:
            for attempt in range(1, self.settings.tries + 1):
                future: asyncio.Future[nmea.Sentence] = asyncio.get_running_loop().create_future()
                self._pending = (sid, sentence, future)
                try:
                    self._write(sentence)
                except PortLost:
                    if future.done():
                        future.exception()  # mark retrieved: the caller gets PortLost directly
                    self._pending = None
                    raise
                try:
                    echo = await asyncio.wait_for(future, self.settings.echo_timeout)
                except TimeoutError:
                    self.counters["resends"] += attempt < self.settings.tries
                    log.info("modem %s: no echo for CC%s (try %d/%d)", self._name, sentence.SID, attempt,
                             self.settings.tries)  # fmt: skip
                    continue
                finally:
                    self._pending = None
                self._failures = 0
                if self.state is LinkState.NOT_RESPONDING:
                    self._set_state(LinkState.READY, "answering again")
                return echo
        self._failures += 1
        if self._failures >= self.settings.failures_before_down and self.state is LinkState.READY:
            self._set_state(LinkState.NOT_RESPONDING, f"no echo for {self._failures} commands")
        raise ModemTimeout(f"no echo for CC{sentence.SID} after {self.settings.tries} tries")

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
            log.warning("modem %s: reconfiguration failed: %s", self._name, exc)

    async def _keepalive(self) -> None:
        while not self._stopping:
            await asyncio.sleep(self.settings.keepalive)
            if self._command_lock.locked() or self._cycle_lock.locked() or self._reconnecting:
                continue
            if self.state not in (LinkState.READY, LinkState.NOT_RESPONDING):
                continue
            was_down = self.state is LinkState.NOT_RESPONDING
            try:
                await self.command(nmea.ConfigQuery("SRC"))
                if was_down:
                    await self._reconfigure()
            except ModemError as exc:
                log.info("modem %s: keep-alive failed: %s", self._name, exc)

    async def send(self, dest: int, frames: list[bytes], rate: int = 0, ack: bool = True,
                   ack_timeout: float | None = None) -> TransmitResult:  # fmt: skip
        """Run one data cycle to ``dest``: cycle-init, answer the data requests, await ACKs."""
        if not frames:
            raise ValueError("a data cycle needs at least one frame")
        async with self._cycle_lock:
            tx = _Transmission(dest, list(frames), ack)
            self._tx = tx
            try:
                return await self._run_cycle(tx, rate, ack_timeout or self.settings.ack_timeout)
            finally:
                self._tx = None

    async def _run_cycle(self, tx: _Transmission, rate: int, ack_timeout: float) -> TransmitResult:
        result = TransmitResult(tx.dest, len(tx.frames), transmitted=False)
        try:
            await self.command(nmea.Cycle(self.settings.address, tx.dest, rate, tx.ack, len(tx.frames)))
            await asyncio.wait_for(tx.requested.wait(), self.settings.drq_timeout)
            await asyncio.wait_for(tx.finished.wait(), self.settings.transmit_timeout)
        except (TimeoutError, ModemError) as exc:
            return replace(result, error=str(exc) or "timed out waiting for the modem")
        if self._port is None:
            return replace(result, error="port lost during the cycle")
        result = replace(result, transmitted=True)
        if tx.ack:
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(tx.all_acked.wait(), ack_timeout)
            result = replace(result, acked=frozenset(tx.acked))
            if not result.all_acked:
                result = replace(result, error="no acknowledgement")
        return result

    async def poll(self, remote: int, rate: int = 0, ack: bool = False) -> None:
        """Third-party poll: ask ``remote`` to send us its data (it arrives as received frames)."""
        async with self._cycle_lock:
            await self.command(nmea.Cycle(remote, self.settings.address, rate, ack, 1))

    async def ping(self, dest: int, timeout: float = 10.0) -> float | None:
        """Two-way ping; the one-way travel time in seconds, or None if no reply came."""
        async with self._cycle_lock:
            waiter: asyncio.Future[float] = asyncio.get_running_loop().create_future()
            self._ping_waiters[dest] = waiter
            try:
                await self.command(nmea.Ping(self.settings.address, dest))
                return await asyncio.wait_for(waiter, timeout)
            except (TimeoutError, ModemError):
                return None
            finally:
                self._ping_waiters.pop(dest, None)


def _echo_matches(sent: nmea.Sentence, echo: nmea.Sentence) -> bool:
    """An echo answers the command it names (CFG of the same parameter, CYC of the same pair)."""
    if isinstance(sent, (nmea.Config, nmea.ConfigQuery)) and isinstance(echo, nmea.Config):
        return sent.name.upper() in (echo.name.upper(), "ALL")
    if isinstance(sent, (nmea.Cycle, nmea.TxData)):
        return (echo.src, echo.dest) == (sent.src, sent.dest)  # type: ignore[attr-defined]
    return True
