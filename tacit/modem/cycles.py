"""Data cycles: what the modem does on the air. A cycle-init, the data requests answered with our
frames, the ACKs collected; third-party polls; two-way pings; and the frames received, delivered with
the receive statistics (``$CACST``) that follow them. One cycle at a time (the modem is half duplex)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from tacit import nmea
from tacit.modem.commands import CommandChannel
from tacit.modem.events import (
    AckReceived,
    DriverSettings,
    Event,
    FrameBad,
    ModemError,
    ReceivedFrame,
    TransmitResult,
)

log = logging.getLogger("tacit.modem")


@dataclass
class _Transmission:
    dest: int
    frames: list[bytes]
    ack: bool
    finished: asyncio.Event = field(default_factory=asyncio.Event)
    acked: set[int] = field(default_factory=set)
    all_acked: asyncio.Event = field(default_factory=asyncio.Event)
    requested: asyncio.Event = field(default_factory=asyncio.Event)


class Cycles:
    def __init__(
        self,
        settings: DriverSettings,
        channel: CommandChannel,
        emit: Callable[[Event], None],
        spawn: Callable[..., None],
    ) -> None:
        self.settings = settings
        self.channel = channel
        self.emit = emit
        self.spawn = spawn
        self.poll_provider: Callable[[nmea.DataRequest], bytes | None] | None = None
        self.lock = asyncio.Lock()
        self._tx: _Transmission | None = None
        self._rx_buffer: list[nmea.RxData] = []
        self._rx_flush: asyncio.TimerHandle | None = None
        self._ping_waiters: dict[int, asyncio.Future[float]] = {}

    # --- what we start ----------------------------------------------------------------------------

    async def send(
        self,
        dest: int,
        frames: list[bytes],
        rate: int = 0,
        ack: bool = True,
        ack_timeout: float | None = None,
    ) -> TransmitResult:
        """Run one data cycle to ``dest``: cycle-init, answer the data requests, await ACKs."""
        if not frames:
            raise ValueError("a data cycle needs at least one frame")
        async with self.lock:
            tx = _Transmission(dest, list(frames), ack)
            self._tx = tx
            try:
                return await self._run(tx, rate, ack_timeout or self.settings.ack_timeout)
            finally:
                self._tx = None

    async def _run(self, tx: _Transmission, rate: int, ack_timeout: float) -> TransmitResult:
        result = TransmitResult(tx.dest, len(tx.frames), transmitted=False)
        try:
            await self.channel.command(
                nmea.Cycle(self.settings.address, tx.dest, rate, tx.ack, len(tx.frames))
            )
            await asyncio.wait_for(tx.requested.wait(), self.settings.drq_timeout)
            await asyncio.wait_for(tx.finished.wait(), self.settings.transmit_timeout)
        except (TimeoutError, ModemError) as exc:
            return replace(result, error=str(exc) or "timed out waiting for the modem")
        if not self.channel.transport.is_open:
            return replace(result, error="port lost during the cycle")
        result = replace(result, transmitted=True)
        if tx.ack:
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(tx.all_acked.wait(), ack_timeout)
            result = replace(result, acked=frozenset(tx.acked))
            if not result.all_acked:
                result = replace(result, error="no acknowledgement")
        return result

    async def poll(self, remote: int, rate: int = 0, ack: bool = False, frames: int = 1) -> None:
        """Third-party poll: ask ``remote`` to send us up to ``frames`` frames of its data (they arrive
        as received frames)."""
        async with self.lock:
            await self.channel.command(nmea.Cycle(remote, self.settings.address, rate, ack, frames))

    async def ping(self, dest: int, timeout: float = 10.0) -> float | None:
        """Two-way ping; the one-way travel time in seconds, or None if no reply came."""
        async with self.lock:
            waiter: asyncio.Future[float] = asyncio.get_running_loop().create_future()
            self._ping_waiters[dest] = waiter
            try:
                await self.channel.command(nmea.Ping(self.settings.address, dest))
                return await asyncio.wait_for(waiter, timeout)
            except (TimeoutError, ModemError):
                return None
            finally:
                self._ping_waiters.pop(dest, None)

    def fail(self, exc: Exception) -> None:
        """The port is gone: nothing under way will complete."""
        for waiter in self._ping_waiters.values():
            if not waiter.done():
                waiter.set_exception(exc)
        if self._tx:
            self._tx.finished.set()
            self._tx.all_acked.set()
            self._tx.requested.set()

    # --- what the modem says ------------------------------------------------------------------------

    def handle(self, sentence: nmea.Sentence | nmea.Raw) -> None:
        match sentence:
            case nmea.DataRequest():
                self._on_drq(sentence)
            case nmea.TxFinished():
                self._on_txf(sentence)
            case nmea.TxStats():
                self._on_xst(sentence)
            case nmea.Ack():
                self._on_ack(sentence)
            case nmea.RxData():
                self._on_rxd(sentence)
            case nmea.RxStats():
                self._on_cst(sentence)
            case nmea.PingReply():
                self._on_ping_reply(sentence)

    def _on_drq(self, drq: nmea.DataRequest) -> None:
        self.spawn(self._answer_drq(drq))

    async def _answer_drq(self, drq: nmea.DataRequest) -> None:
        tx = self._tx
        if tx is not None and drq.dest == tx.dest and drq.src == self.settings.address:
            data = tx.frames[drq.frame - 1] if 0 < drq.frame <= len(tx.frames) else b""
            tx.requested.set()
        else:
            data = (self.poll_provider(drq) if self.poll_provider else None) or b""
        try:
            await self.channel.command(nmea.TxData(drq.src, drq.dest, drq.ack, data[: drq.maxbytes]))
        except ModemError as exc:
            log.warning(
                "modem %s: could not answer data request for frame %d: %s",
                self.channel.transport.name,
                drq.frame,
                exc,
            )

    def _on_txf(self, txf: nmea.TxFinished) -> None:
        if self._tx is not None and txf.nbytes > 0:
            self._tx.finished.set()

    def _on_xst(self, _xst: nmea.TxStats) -> None:
        if self._tx is not None:
            self._tx.finished.set()

    def _on_ack(self, ack: nmea.Ack) -> None:
        now = time.time()
        tx = self._tx
        if tx is not None and ack.src == tx.dest and ack.dest == self.settings.address:
            tx.acked.add(ack.frame)
            if len(tx.acked) >= len(tx.frames):
                tx.all_acked.set()
        self.emit(AckReceived(ack.src, ack.frame, now))

    def _on_rxd(self, rxd: nmea.RxData) -> None:
        self._rx_buffer.append(rxd)
        if self._rx_flush is None:
            loop = asyncio.get_running_loop()
            self._rx_flush = loop.call_later(self.settings.stats_grace, self._flush_rx, None)

    def _on_cst(self, cst: nmea.RxStats) -> None:
        if cst.mode != 0 and not self._rx_buffer:
            reason = "bad_crc" if cst.mode == 1 else "timeout"
            self.emit(FrameBad(reason, time.time()))
        self._flush_rx(cst)

    def _flush_rx(self, stats: nmea.RxStats | None) -> None:
        if self._rx_flush is not None:
            self._rx_flush.cancel()
            self._rx_flush = None
        frames, self._rx_buffer = self._rx_buffer, []
        now = time.time()
        for rxd in frames:
            self.emit(ReceivedFrame(rxd.src, rxd.dest, rxd.ack, rxd.frame, rxd.data, stats, now))

    def _on_ping_reply(self, reply: nmea.PingReply) -> None:
        waiter = self._ping_waiters.get(reply.src)
        if waiter is not None and not waiter.done() and reply.dest == self.settings.address:
            waiter.set_result(abs(reply.travel_time))
