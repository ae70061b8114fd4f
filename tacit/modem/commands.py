"""The command channel: one host command outstanding until the modem echoes it, resent after
``echo_timeout``, given up after ``tries`` (as goby3's ``mm_driver`` does). Repeated failures tell the
driver the modem is not responding; the next echo tells it the modem answers again."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from tacit import nmea
from tacit.modem.events import DriverSettings, ModemBusy, ModemError, ModemTimeout, PortLost
from tacit.modem.transport import Transport

log = logging.getLogger("tacit.modem")

# The echo that completes each host command: (sentence id of the echo, fields that must match).
_ECHO: dict[type[nmea.Sentence], str] = {
    nmea.Cycle: "CYC", nmea.TxData: "TXD", nmea.Config: "CFG", nmea.ConfigQuery: "CFG",
    nmea.Clock: "CLK", nmea.Ping: "MPC", nmea.MiniPacket: "MUC", nmea.Sleep: "MSC",
}  # fmt: skip


class CommandChannel:
    def __init__(
        self,
        settings: DriverSettings,
        transport: Transport,
        on_answering: Callable[[], None],
        on_silent: Callable[[int], None],
    ) -> None:
        self.settings = settings
        self.transport = transport
        self.on_answering = on_answering  # an echo came: the modem answers
        self.on_silent = on_silent  # a command got no echo at all: how many in a row
        self._pending: tuple[str, nmea.Sentence, asyncio.Future[nmea.Sentence]] | None = None
        self._lock = asyncio.Lock()
        self._failures = 0
        self.resends = 0

    @property
    def busy(self) -> bool:
        return self._lock.locked()

    async def command(self, sentence: nmea.Sentence) -> nmea.Sentence:
        """Send a host command and wait for its echo; resend on timeout; raise after ``tries``."""
        sid = _ECHO.get(type(sentence))
        if sid is None:
            raise ValueError(f"{type(sentence).__name__} is not a host command with an echo")
        async with self._lock:
            for attempt in range(1, self.settings.tries + 1):
                echo = await self._attempt(sid, sentence, attempt)
                if echo is not None:
                    self._failures = 0
                    self.on_answering()
                    return echo
        self._failures += 1
        self.on_silent(self._failures)
        raise ModemTimeout(f"no echo for CC{sentence.SID} after {self.settings.tries} tries")

    async def _attempt(self, sid: str, sentence: nmea.Sentence, attempt: int) -> nmea.Sentence | None:
        future: asyncio.Future[nmea.Sentence] = asyncio.get_running_loop().create_future()
        self._pending = (sid, sentence, future)
        try:
            self.transport.write(sentence)
        except PortLost:
            if future.done():
                future.exception()  # mark retrieved: the caller gets PortLost directly
            self._pending = None
            raise
        try:
            return await asyncio.wait_for(future, self.settings.echo_timeout)
        except TimeoutError:
            self.resends += attempt < self.settings.tries
            log.info(
                "modem %s: no echo for CC%s (try %d/%d)",
                self.transport.name,
                sentence.SID,
                attempt,
                self.settings.tries,
            )
            return None
        finally:
            self._pending = None

    def resolve(self, sentence: nmea.Sentence | nmea.Raw) -> None:
        """A sentence from the modem: the echo (or the refusal) of the outstanding command, if it is one."""
        if self._pending is None or isinstance(sentence, nmea.Raw):
            return
        sid, sent, future = self._pending
        if future.done():
            return
        if isinstance(sentence, nmea.Error) and sentence.module in ("NMEA", sent.SID):
            refused = ModemBusy if sentence.message == "BUSY" else ModemError
            future.set_exception(refused(f"modem refused {sent.SID}: {sentence.message}"))
        elif sentence.SID == sid and nmea.MODEM in sentence.TALKERS and _echo_matches(sent, sentence):
            future.set_result(sentence)

    def fail(self, exc: Exception) -> None:
        if self._pending and not self._pending[2].done():
            self._pending[2].set_exception(exc)


def _echo_matches(sent: nmea.Sentence, echo: nmea.Sentence) -> bool:
    """An echo answers the command it names (CFG of the same parameter, CYC of the same pair)."""
    if isinstance(sent, (nmea.Config, nmea.ConfigQuery)) and isinstance(echo, nmea.Config):
        return sent.name.upper() in (echo.name.upper(), "ALL")
    if isinstance(sent, (nmea.Cycle, nmea.TxData)):
        return (echo.src, echo.dest) == (sent.src, sent.dest)  # type: ignore[attr-defined]
    return True
