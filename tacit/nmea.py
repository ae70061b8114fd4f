"""WHOI Micro-Modem NMEA sentences: build, parse, checksum.

Framing is ``$<talker><id>,f1,...,fn*CS\\r\\n``; CS is the XOR of every byte between ``$`` and ``*``
as two hex digits. The host talks as ``CC``, the modem answers as ``CA`` (``SN`` for navigation).
Each known sentence is a frozen dataclass; its fields, in order, are the sentence's fields, typed by
annotation (``int``, ``float``, ``str``, ``bool`` as 0/1, ``bytes`` as ASCII hex). A sentence whose
layout differs between host and modem (``TXD``) has one class per direction.

``parse`` raises only ``NmeaError`` subclasses, so a reader loop can report a bad line and go on.
Numeric fields are bounded: an integer field has at most ``MAX_INT_DIGITS`` characters (a 900-digit address
would overflow a database column downstream) and a float field is finite and at most ``MAX_DIGITS``
characters long (a ``nan`` SNR would poison every comparison made with it). Such a line is rejected
like any malformed one, so only that line is skipped, never the batch around it.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from typing import Any, ClassVar, get_type_hints

HOST = "CC"
MODEM = "CA"
NAV = "SN"
MAX_LINE = 1024
MAX_DIGITS = 24  # a numeric field longer than this is garbage, not a Micro-Modem value
MAX_INT_DIGITS = 18  # an integer field's characters: it always fits a 64-bit database column


class NmeaError(ValueError):
    """A line that is not a valid Micro-Modem sentence."""


class FramingError(NmeaError):
    """No ``$``, no ``*CS``, non-ASCII bytes or an over-long line."""


class ChecksumError(NmeaError):
    pass


class FieldError(NmeaError):
    """Wrong field count or a field that does not convert to its type."""


@dataclass(frozen=True)
class Sentence:
    """A sentence with a known layout. ``TALKERS`` are the talkers that may send it."""

    SID: ClassVar[str]
    TALKERS: ClassVar[tuple[str, ...]] = (HOST, MODEM)
    PREFIX: ClassVar[tuple[str, ...]] = ()  # constant leading fields (CYC's deprecated 0)
    OPTIONAL_TAIL: ClassVar[int] = 0  # how many trailing fields may be absent

    def fields_text(self) -> list[str]:
        return list(self.PREFIX) + [_format(getattr(self, f.name)) for f in dataclasses.fields(self)]

    def line(self, talker: str | None = None) -> str:
        """The full sentence with checksum and CRLF."""
        return build(talker or self.TALKERS[0], self.SID, self.fields_text())


@dataclass(frozen=True)
class Raw:
    """A well-framed sentence of a kind this module does not model."""

    talker: str
    sid: str
    fields: tuple[str, ...]

    def line(self, talker: str | None = None) -> str:
        return build(talker or self.talker, self.sid, list(self.fields))


def _format(value: Any) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).hex().upper()
    if isinstance(value, float):
        return f"{value:.4f}".rstrip("0").rstrip(".") if value != int(value) else f"{value:.1f}"
    return str(value)


def checksum(body: str) -> str:
    """Two hex digits: the XOR of every character of ``body`` (the text between ``$`` and ``*``)."""
    value = 0
    for char in body.encode("ascii"):
        value ^= char
    return f"{value:02X}"


def build(talker: str, sid: str, fields: list[str]) -> str:
    body = ",".join([talker + sid, *fields])
    return f"${body}*{checksum(body)}\r\n"


# --- the sentences --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Cycle(Sentence):
    """``$CCCYC`` / ``$CACYC``: start (or report) a data cycle from ``src`` to ``dest``."""

    SID: ClassVar = "CYC"
    PREFIX: ClassVar = ("0",)
    src: int
    dest: int
    rate: int
    ack: bool
    nframes: int


@dataclass(frozen=True)
class DataRequest(Sentence):
    """``$CADRQ``: the modem asks its host for frame ``frame`` of the cycle."""

    SID: ClassVar = "DRQ"
    TALKERS: ClassVar = (MODEM,)
    time: str
    src: int
    dest: int
    ack: bool
    maxbytes: int
    frame: int


@dataclass(frozen=True)
class TxData(Sentence):
    """``$CCTXD``: the host's data for the requested frame (empty = nothing to send)."""

    SID: ClassVar = "TXD"
    TALKERS: ClassVar = (HOST,)
    src: int
    dest: int
    ack: bool
    data: bytes


@dataclass(frozen=True)
class TxDataEcho(Sentence):
    """``$CATXD``: the modem took ``nbytes`` of data."""

    SID: ClassVar = "TXD"
    TALKERS: ClassVar = (MODEM,)
    src: int
    dest: int
    ack: bool
    nbytes: int


@dataclass(frozen=True)
class RxData(Sentence):
    """``$CARXD``: a frame received with a good CRC."""

    SID: ClassVar = "RXD"
    TALKERS: ClassVar = (MODEM,)
    src: int
    dest: int
    ack: bool
    frame: int
    data: bytes


@dataclass(frozen=True)
class Ack(Sentence):
    """``$CAACK``: ``src`` (the acknowledging node) acknowledged frame ``frame`` sent by ``dest``."""

    SID: ClassVar = "ACK"
    TALKERS: ClassVar = (MODEM,)
    src: int
    dest: int
    frame: int
    ack: int = 1
    OPTIONAL_TAIL: ClassVar = 1


@dataclass(frozen=True)
class TxStarted(Sentence):
    """``$CATXP``: transmission of a packet (or its cycle-init) began."""

    SID: ClassVar = "TXP"
    TALKERS: ClassVar = (MODEM,)
    nbytes: int


@dataclass(frozen=True)
class TxFinished(Sentence):
    """``$CATXF``: transmission finished."""

    SID: ClassVar = "TXF"
    TALKERS: ClassVar = (MODEM,)
    nbytes: int


@dataclass(frozen=True)
class RxStarted(Sentence):
    """``$CARXP``: an incoming packet was detected."""

    SID: ClassVar = "RXP"
    TALKERS: ClassVar = (MODEM,)
    nbytes: int


@dataclass(frozen=True)
class Ping(Sentence):
    """``$CCMPC`` / ``$CAMPC``: a two-way ping from ``src`` to ``dest``."""

    SID: ClassVar = "MPC"
    src: int
    dest: int


@dataclass(frozen=True)
class PingHeard(Sentence):
    """``$CAMPA``: this modem heard a ping from ``src``."""

    SID: ClassVar = "MPA"
    TALKERS: ClassVar = (MODEM,)
    src: int
    dest: int


@dataclass(frozen=True)
class PingReply(Sentence):
    """``$CAMPR``: ``src`` replied to our ping; one-way travel time in seconds."""

    SID: ClassVar = "MPR"
    TALKERS: ClassVar = (MODEM,)
    src: int
    dest: int
    travel_time: float


@dataclass(frozen=True)
class MiniPacket(Sentence):
    """``$CCMUC``: send a 13-bit mini-packet (four hex digits)."""

    SID: ClassVar = "MUC"
    TALKERS: ClassVar = (HOST, MODEM)
    src: int
    dest: int
    data: str


@dataclass(frozen=True)
class MiniPacketHeard(Sentence):
    """``$CAMUA``: a mini-packet was received."""

    SID: ClassVar = "MUA"
    TALKERS: ClassVar = (MODEM,)
    src: int
    dest: int
    data: str


@dataclass(frozen=True)
class MiniPacketReply(Sentence):
    """``$CAMUR``: a mini-packet reply (with its travel time when the modem gives one)."""

    SID: ClassVar = "MUR"
    TALKERS: ClassVar = (MODEM,)
    src: int
    dest: int
    travel_time: float = 0.0
    OPTIONAL_TAIL: ClassVar = 1


@dataclass(frozen=True)
class Config(Sentence):
    """``$CCCFG`` / ``$CACFG``: set (or report) configuration ``name`` to ``value``."""

    SID: ClassVar = "CFG"
    name: str
    value: str


@dataclass(frozen=True)
class ConfigQuery(Sentence):
    """``$CCCFQ``: query one parameter, or ``ALL``."""

    SID: ClassVar = "CFQ"
    TALKERS: ClassVar = (HOST,)
    name: str


@dataclass(frozen=True)
class Clock(Sentence):
    """``$CCCLK`` / ``$CACLK``: set or report the modem clock (UTC)."""

    SID: ClassVar = "CLK"
    year: int
    month: int
    day: int
    hour: int
    minute: int
    second: int


@dataclass(frozen=True)
class Sleep(Sentence):
    """``$CCMSC``: sleep for ``minutes``; 0 reboots now."""

    SID: ClassVar = "MSC"
    src: int
    dest: int
    minutes: int


@dataclass(frozen=True)
class Revision(Sentence):
    """``$CAREV``: firmware revision; ``ident`` INIT means the modem has just (re)booted."""

    SID: ClassVar = "REV"
    TALKERS: ClassVar = (MODEM,)
    time: str
    ident: str
    rev: str


@dataclass(frozen=True)
class Error(Sentence):
    """``$CAERR``: the modem reports an error (``NMEA`` module: unknown or malformed command)."""

    SID: ClassVar = "ERR"
    TALKERS: ClassVar = (MODEM,)
    time: str
    module: str
    number: int
    message: str


@dataclass(frozen=True)
class Message(Sentence):
    """``$CAMSG``: ``BAD_CRC``, ``PACKET_TIMEOUT`` and other notices."""

    SID: ClassVar = "MSG"
    TALKERS: ClassVar = (MODEM,)
    FAILURES: ClassVar = ("BAD_CRC", "PACKET_TIMEOUT")  # a frame heard but not decoded, or missed
    type: str
    value: str


@dataclass(frozen=True)
class TxStats(Sentence):
    """``$CAXST``: transmit statistics."""

    SID: ClassVar = "XST"
    TALKERS: ClassVar = (MODEM,)
    date: str
    time: str
    clock_mode: int
    mode: int
    probe_len: int
    bw: int
    carrier: int
    rate: int
    src: int
    dest: int
    ack: bool
    n_expected: int
    n_sent: int
    pkt_type: int
    nbytes: int


@dataclass(frozen=True)
class RxStats(Sentence):
    """``$CACST``: receive statistics; ``mode`` 0 good, 1 bad CRC, 2 timeout."""

    SID: ClassVar = "CST"
    TALKERS: ClassVar = (MODEM,)
    mode: int
    toa: str
    clock_mode: int
    mfd_peak: int
    mfd_pow: int
    mfd_ratio: int
    spl: int
    agn: int
    ainp: int
    ain: int
    mfd_shift: int
    p2b: int
    rate: int
    src: int
    dest: int
    psk_err: int
    pkt_type: int
    nframes: int
    nbad: int
    snr_rss: int
    snr_in: float
    snr_out: float
    snr_sym: float
    mse: float
    dqf: int
    doppler: float
    noise: int
    carrier: int
    bw: int


@dataclass(frozen=True)
class TravelTimes(Sentence):
    """``$SNTTA``: navigation travel times to up to four transponders."""

    SID: ClassVar = "TTA"
    TALKERS: ClassVar = (NAV,)
    ta: str
    tb: str
    tc: str
    td: str
    time: str


SENTENCES: tuple[type[Sentence], ...] = (
    Cycle, DataRequest, TxData, TxDataEcho, RxData, Ack, TxStarted, TxFinished, RxStarted, Ping,
    PingHeard, PingReply, MiniPacket, MiniPacketHeard, MiniPacketReply, Config, ConfigQuery, Clock,
    Sleep, Revision, Error, Message, TxStats, RxStats, TravelTimes,
)  # fmt: skip
_BY_KEY: dict[tuple[str, str], type[Sentence]] = {
    (talker, cls.SID): cls for cls in SENTENCES for talker in cls.TALKERS
}
_HINTS = {cls: get_type_hints(cls) for cls in SENTENCES}
_TALKER_ID = re.compile(r"^[A-Z]{2}[A-Z0-9]{3}$")


def _convert(cls: type[Sentence], name: str, text: str) -> Any:
    kind = _HINTS[cls][name]
    try:
        limit = MAX_INT_DIGITS if kind is int else MAX_DIGITS
        if kind in (int, float) and len(text.strip()) > limit:
            raise ValueError(f"numeric field of {len(text)} characters (at most {limit})")
        if kind is int:
            return int(text)
        if kind is float:
            value = float(text)
            if not math.isfinite(value):
                raise ValueError(f"{text!r} is not a finite number")
            return value
        if kind is bool:
            if text not in ("0", "1"):
                raise ValueError(f"expected 0 or 1, got {text!r}")
            return text == "1"
        if kind is bytes:
            if len(text) % 2:
                raise ValueError("odd number of hex digits")
            return bytes.fromhex(text)
        return text
    except ValueError as exc:
        raise FieldError(f"{cls.SID}.{name}: {exc}") from None


def split(line: str | bytes, require_checksum: bool = True) -> tuple[str, str, list[str]]:
    """Check framing and checksum; return (talker, sentence id, fields)."""
    if isinstance(line, (bytes, bytearray)):
        try:
            line = bytes(line).decode("ascii")
        except UnicodeDecodeError:
            raise FramingError("non-ASCII bytes in line") from None
    line = line.strip("\r\n \t\0")
    if len(line) > MAX_LINE:
        raise FramingError(f"line longer than {MAX_LINE} characters")
    if not line.startswith("$"):
        raise FramingError("line does not start with '$'")
    if not line.isprintable():
        raise FramingError("non-printable characters in line")
    body, star, given = line[1:].partition("*")
    if star:
        if len(given) != 2:
            raise FramingError(f"checksum must be two hex digits, got {given!r}")
        if given.upper() != checksum(body):
            raise ChecksumError(f"checksum {given} does not match {checksum(body)}")
    elif require_checksum:
        raise FramingError("no '*' checksum")
    head, *fields = body.split(",")
    if not _TALKER_ID.match(head):
        raise FramingError(f"bad talker/sentence id {head!r}")
    return head[:2], head[2:], fields


def parse(line: str | bytes, require_checksum: bool = True) -> Sentence | Raw:
    """Parse one line into its sentence class, or ``Raw`` for a well-framed unknown sentence."""
    talker, sid, fields = split(line, require_checksum)
    cls = _BY_KEY.get((talker, sid))
    if cls is None:
        return Raw(talker, sid, tuple(fields))
    if len(fields) < len(cls.PREFIX):
        raise FieldError(f"{talker}{sid}: too few fields")
    fields = fields[len(cls.PREFIX) :]  # deprecated constant fields, whatever their value
    names = [f.name for f in dataclasses.fields(cls)]
    if not len(names) - cls.OPTIONAL_TAIL <= len(fields) <= len(names):
        raise FieldError(f"{talker}{sid}: expected {len(names)} fields, got {len(fields)}")
    return cls(**{n: _convert(cls, n, t) for n, t in zip(names, fields, strict=False)})


def modem_error(sentence: Sentence | Raw) -> str | None:
    """The kind of error a modem sentence reports (``CAERR``, ``BAD_CRC``, ``PACKET_TIMEOUT``), or None."""
    if isinstance(sentence, Error):
        return "CAERR"
    if isinstance(sentence, Message) and sentence.type in Message.FAILURES:
        return sentence.type
    return None


def talker_of(sentence: Sentence | Raw, host: bool) -> str:
    """The talker to use for ``sentence`` when sent by the host (``CC``) or the modem (``CA``)."""
    if isinstance(sentence, Raw):
        return sentence.talker
    want = HOST if host else MODEM
    return want if want in sentence.TALKERS else sentence.TALKERS[0]
