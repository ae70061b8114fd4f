"""The backhaul's wire: subject names, stream names and the messages' payloads (JSON, versioned).

Subjects (docs/backhaul.md has the table other tools subscribe by):

* ``tacit.v1.frames.<gateway>``: up, a frame the gateway's modem received (``FrameMessage``);
* ``tacit.v1.commands.<gateway>``: down, a signed command frame for the gateway to send (``CommandMessage``);
* ``tacit.v1.events.<gateway>``: up, what the gateway reports: attempt outcomes, modem states, its
  heartbeat (``EventMessage``);
* ``tacit.v1.schedule.<gateway>``: down, the gateway's transmit slots in the TDMA frame the center
  hands the gateways sharing the band (``ScheduleMessage``; the stream keeps the last per gateway).

Every message carries an ``id`` unique across the system, which is also its ``Nats-Msg-Id`` header
(JetStream's de-duplication within the stream's ``duplicate_window``). Payloads are JSON objects with
``"v": 1``; a reader ignores fields it does not know and refuses another major version.

Standard library only: the gateway imports it.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass, field
from typing import Any

VERSION = 1
PREFIX = f"tacit.v{VERSION}"
FRAMES_STREAM = "TACIT_FRAMES"
COMMANDS_STREAM = "TACIT_COMMANDS"
EVENTS_STREAM = "TACIT_EVENTS"
SCHEDULE_STREAM = "TACIT_SCHEDULE"
DUPLICATE_WINDOW = 120.0  # s: JetStream drops a message whose id it stored this recently
COMMAND_MAX_AGE = 600.0  # s: a signed command frame is acceptable to the vehicle for its max_age
EVENTS_MAX_AGE = 86400.0  # s: events are kept a day for late subscribers
HEARTBEAT = 10.0  # s between a gateway's heartbeats
MSG_ID = "Nats-Msg-Id"
_TOKEN = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


class PayloadError(ValueError):
    """A message that is not a payload of this version."""


def gateway_name(name: str) -> str:
    """``name`` if it can be one token of a subject (letters, digits, ``_``, ``-``); raises ValueError."""
    if not _TOKEN.match(name):
        raise ValueError(f"a gateway name is 1-64 letters, digits, '_' or '-': {name!r}")
    return name


def frames(gateway: str = "*") -> str:
    return f"{PREFIX}.frames.{gateway}"


def commands(gateway: str = "*") -> str:
    return f"{PREFIX}.commands.{gateway}"


def events(gateway: str = "*") -> str:
    return f"{PREFIX}.events.{gateway}"


def schedule(gateway: str = "*") -> str:
    return f"{PREFIX}.schedule.{gateway}"


def _load(data: bytes) -> dict[str, Any]:
    try:
        body = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PayloadError(f"not JSON: {exc}") from exc
    if not isinstance(body, dict) or body.get("v") != VERSION:
        raise PayloadError(f"not a version {VERSION} payload")
    return body


def _dump(body: dict[str, Any]) -> bytes:
    return json.dumps({"v": VERSION, **body}, separators=(",", ":")).encode()


@dataclass(frozen=True)
class FrameMessage:
    """A frame a gateway's modem received, as it heard it; ``at`` is the gateway's clock (UNIX s)."""

    id: str  # "<gateway>-<outbox incarnation>-<counter>"
    gateway: str
    src: int
    dest: int
    data: bytes
    rate: int = 0
    snr_in: float | None = None
    snr_out: float | None = None
    stats: dict[str, Any] | None = None
    at: float = 0.0

    def encode(self) -> bytes:
        return _dump({**asdict(self), "data": self.data.hex()})

    @classmethod
    def decode(cls, data: bytes) -> FrameMessage:
        body = _load(data)
        try:
            return cls(
                id=str(body["id"]),
                gateway=str(body["gateway"]),
                src=int(body["src"]),
                dest=int(body["dest"]),
                data=bytes.fromhex(body["data"]),
                rate=int(body.get("rate", 0)),
                snr_in=_number(body.get("snr_in")),
                snr_out=_number(body.get("snr_out")),
                stats=body.get("stats"),
                at=float(body["at"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise PayloadError(f"a frame without {exc}") from exc


@dataclass(frozen=True)
class CommandMessage:
    """A command frame the center signed, for the gateway to send to ``address``: ``attempts`` times at
    most, each waiting ``ack_timeout`` s for the modem's ACK, not after ``expires_at`` (UNIX s), and not
    at all if it reaches the gateway after ``start_by`` (the center has sent it through another gateway
    by then; 0: no such limit)."""

    id: str  # "cmd-<command id>-<dispatch>": the center's, one per gateway it tries
    gateway: str
    address: int
    data: bytes
    attempts: int = 3
    ack_timeout: float = 20.0
    expires_at: float = 0.0
    start_by: float = 0.0

    def encode(self) -> bytes:
        return _dump({**asdict(self), "data": self.data.hex()})

    @classmethod
    def decode(cls, data: bytes) -> CommandMessage:
        body = _load(data)
        try:
            return cls(
                id=str(body["id"]),
                gateway=str(body["gateway"]),
                address=int(body["address"]),
                data=bytes.fromhex(body["data"]),
                attempts=int(body.get("attempts", 3)),
                ack_timeout=float(body.get("ack_timeout", 20.0)),
                expires_at=float(body.get("expires_at", 0.0)),
                start_by=float(body.get("start_by", 0.0)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise PayloadError(f"a command without {exc}") from exc


@dataclass(frozen=True)
class ScheduleMessage:
    """The TDMA frame of the gateways sharing one band (``server.backhaul.slots.SlotPlan``): slot ``k``
    begins at ``epoch + k * slot`` (UNIX s) and belongs to ``order[k % len(order)]``; a gateway starts a
    transmission ``guard`` s after its slot begins at the earliest and has it answered ``guard`` s before
    the slot ends. ``poll``: the vehicles' modem addresses the gateway polls in its slots, in turn."""

    id: str
    gateway: str
    epoch: float
    slot: float
    guard: float
    order: tuple[str, ...]
    poll: tuple[int, ...] = ()

    def encode(self) -> bytes:
        return _dump({**asdict(self), "order": list(self.order), "poll": list(self.poll)})

    @classmethod
    def decode(cls, data: bytes) -> ScheduleMessage:
        body = _load(data)
        try:
            return cls(
                id=str(body["id"]),
                gateway=str(body["gateway"]),
                epoch=float(body["epoch"]),
                slot=float(body["slot"]),
                guard=float(body["guard"]),
                order=tuple(str(name) for name in body["order"]),
                poll=tuple(int(address) for address in body.get("poll", ())),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise PayloadError(f"a schedule without {exc}") from exc


@dataclass(frozen=True)
class EventMessage:
    """What a gateway reports. ``kind``: ``attempt`` (detail: command id, outcome ``stored``/``sent``/
    ``acked``/``failed``/``expired``, attempt number; the last one of a command has ``final``: true and
    its outcome is ``acked``, ``failed`` (no ACK after its attempts) or ``expired``), ``modem`` (detail: state), ``heartbeat`` (detail:
    backhaul state, outbox depth: frames and events not yet published)."""

    id: str
    gateway: str
    kind: str
    at: float
    detail: dict[str, Any] = field(default_factory=dict)

    def encode(self) -> bytes:
        return _dump(asdict(self))

    @classmethod
    def decode(cls, data: bytes) -> EventMessage:
        body = _load(data)
        try:
            return cls(
                id=str(body["id"]),
                gateway=str(body["gateway"]),
                kind=str(body["kind"]),
                at=float(body["at"]),
                detail=dict(body.get("detail") or {}),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise PayloadError(f"an event without {exc}") from exc


def _number(value: Any) -> float | None:
    return None if value is None else float(value)
