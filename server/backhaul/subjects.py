"""The backhaul's wire: subject names, stream names and the messages' payloads (JSON, versioned).

Subjects (docs/backhaul.md has the table other tools subscribe by):

* ``tacit.v1.frames.<gateway>.<partition>``: up, a frame the gateway's modem received (``FrameMessage``);
  ``<partition>`` is its source modem address modulo ``PARTITIONS`` (``partition``), so that the
  center's processes can share the vehicles, each partition decoded by one of them at a time
  (``server.backhaul.leases``);
* ``tacit.v1.commands.<gateway>``: down, a signed command frame for the gateway to send (``CommandMessage``),
  or the withdrawal of one it holds (``WithdrawMessage``; ``down`` reads either);
* ``tacit.v1.events.<gateway>``: up, what the gateway reports: attempt outcomes, modem states, its
  heartbeat (``EventMessage``);
* ``tacit.v1.schedule.<gateway>``: down, the gateway's transmit slots in the TDMA frame the center
  hands the gateways sharing the band (``ScheduleMessage``; the stream keeps the last per gateway);
* ``tacit.v1.live.<center>``: between the center's processes (core NATS, not a stream), the live events
  each one's browsers are shown (``server.backhaul.live``).
* ``tacit.v1.syncs.<gateway>.<address>``: down, the SYNCs the center pre-signed for the vehicle at
  ``address`` while the gateway serves it, or their withdrawal (``SyncBudgetMessage``; the stream keeps
  the last per gateway and vehicle).

Every message carries an ``id`` unique across the system, which is also its ``Nats-Msg-Id`` header
(JetStream's de-duplication within the stream's ``duplicate_window``). Payloads are JSON objects with
``"v": 1``; a reader ignores fields it does not know and refuses another major version.

Standard library and the gateway wing's queue (``FrameKind``): the gateway imports it.
"""

from __future__ import annotations

import enum
import json
import math
import re
from dataclasses import asdict, dataclass, field
from typing import Any

from gateway.queue import FrameKind

VERSION = 1
PREFIX = f"tacit.v{VERSION}"
FRAMES_STREAM = "TACIT_FRAMES"
COMMANDS_STREAM = "TACIT_COMMANDS"
EVENTS_STREAM = "TACIT_EVENTS"
SCHEDULE_STREAM = "TACIT_SCHEDULE"
SYNCS_STREAM = "TACIT_SYNCS"
DUPLICATE_WINDOW = 120.0  # s: JetStream drops a message whose id it stored this recently
COMMAND_MAX_AGE = 600.0  # s: a signed command frame is acceptable to the vehicle for its max_age
EVENTS_MAX_AGE = 86400.0  # s: events are kept a day for late subscribers
HEARTBEAT = 10.0  # s between a gateway's heartbeats
# Frame subjects' partitions. Part of the wire, not a setting: a gateway and the center that disagreed on
# it would put one vehicle's frames in two partitions (two processes decoding it) or strand them.
PARTITIONS = 16
MSG_ID = "Nats-Msg-Id"
_TOKEN = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


class PayloadError(ValueError):
    """A message that is not a payload of this version."""


def gateway_name(name: str) -> str:
    """``name`` if it can be one token of a subject (letters, digits, ``_``, ``-``); raises ValueError."""
    if not _TOKEN.match(name):
        raise ValueError(f"a gateway name is 1-64 letters, digits, '_' or '-': {name!r}")
    return name


def partition(address: int) -> int:
    """The frames partition of a vehicle's modem address."""
    return address % PARTITIONS


def frames(gateway: str = "*", part: int | str = "*") -> str:
    """A frame subject: ``frames(g, partition(src))``; ``frames(">")`` every frame, ``frames(g)`` every
    partition of one gateway, ``frames("*", p)`` one partition of every gateway."""
    return f"{PREFIX}.frames.{gateway}" if gateway == ">" else f"{PREFIX}.frames.{gateway}.{part}"


def commands(gateway: str = "*") -> str:
    return f"{PREFIX}.commands.{gateway}"


def events(gateway: str = "*") -> str:
    return f"{PREFIX}.events.{gateway}"


def schedule(gateway: str = "*") -> str:
    return f"{PREFIX}.schedule.{gateway}"


def live(center: str = "*") -> str:
    return f"{PREFIX}.live.{center}"


def syncs(gateway: str = "*", address: int | str = "*") -> str:
    """A vehicle's SYNC budget at a gateway (``*``: any); ``syncs(">")``: every one."""
    return f"{PREFIX}.syncs.>" if gateway == ">" else f"{PREFIX}.syncs.{gateway}.{address}"


def sync_id(address: int, counter: int) -> str:
    """The command id of a SYNC to the vehicle at ``address`` (the center's, or one of a budget)."""
    return f"sync-{address}-{counter}"


@dataclass(frozen=True)
class Deployment:
    """One split shore's names on a broker that others may share. ``name`` (a subject token; "", the
    default: none) prefixes every subject (``<name>.tacit.v1.frames.ship.3``) and every stream, consumer
    and bucket name (``<name>-TACIT_FRAMES``), so two deployments on one broker, even in one account,
    share none (JetStream refuses two streams of overlapping subjects in one account). The code speaks
    of the subjects without it (``frames``, ``commands``, ...): the broker's clients add it to what they
    publish and subscribe to (``subject``) and take it off what they receive (``local``)."""

    name: str = ""

    def __post_init__(self) -> None:
        if self.name and not _TOKEN.match(self.name):
            raise ValueError(f"a deployment name is 1-64 letters, digits, '_' or '-': {self.name!r}")

    def subject(self, subject: str) -> str:
        """A subject of the wire as it is on this deployment's broker."""
        return f"{self.name}.{subject}" if self.name else subject

    def local(self, subject: str) -> str:
        """A subject received from the broker, as the wire names it (without the deployment)."""
        return subject.removeprefix(f"{self.name}.") if self.name else subject

    def named(self, name: str) -> str:
        """A stream's, consumer's or bucket's name on this deployment's broker."""
        return f"{self.name}-{name}" if self.name else name


UNNAMED = Deployment()  # the default: the wire's subjects and names as they are


def is_sync(command_id: str) -> bool:
    """Whether a command id is a SYNC's: its outcome is not a command's (the next check-point says
    whether it arrived)."""
    return command_id.startswith("sync-")


class WithdrawReason(enum.StrEnum):
    """Why the center takes back a frame a gateway holds."""

    SUPERSEDED = "superseded"  # the center signed the command anew (or the vehicle would refuse the frame)
    ACKNOWLEDGED = "acknowledged"  # the vehicle's modem acknowledged it through another gateway
    CANCELLED = "cancelled"  # an operator cancelled the command


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
    kind: FrameKind = FrameKind.COMMAND  # a stop goes before every other command; a SYNC at its stamp
    rank: int = 0  # among one vehicle's commands of a kind, the lower first (the center's queue order)
    stamp: float = 0.0  # UNIX s the frame is signed for (a SYNC: its slot's opening; 0: none)

    def encode(self) -> bytes:
        return _dump({**asdict(self), "data": self.data.hex(), "kind": self.kind.value})

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
                kind=FrameKind(
                    body.get("kind", FrameKind.SYNC if is_sync(str(body["id"])) else FrameKind.COMMAND)
                ),
                rank=int(body.get("rank", 0)),
                stamp=float(body.get("stamp", 0.0)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise PayloadError(f"a command without {exc}") from exc


@dataclass(frozen=True)
class WithdrawMessage:
    """The center takes back the frame of command message ``command`` that ``gateway`` holds: the gateway
    sends it no more (reported ``withdrawn``, final). It rides the gateway's commands subject, so it comes
    after the frame it withdraws; one for a frame the gateway never held or already finished is kept as a
    refusal of that frame should it come later (a redelivery)."""

    id: str  # "withdraw-<command message id>"
    gateway: str
    command: str  # the ``CommandMessage.id`` taken back
    reason: WithdrawReason

    def encode(self) -> bytes:
        return _dump({"type": "withdraw", **asdict(self), "reason": self.reason.value})

    @classmethod
    def decode(cls, data: bytes) -> WithdrawMessage:
        body = _load(data)
        try:
            if body.get("type") != "withdraw":
                raise ValueError("type")
            return cls(
                id=str(body["id"]),
                gateway=str(body["gateway"]),
                command=str(body["command"]),
                reason=WithdrawReason(body["reason"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise PayloadError(f"a withdrawal without {exc}") from exc


def withdraw_id(command_id: str) -> str:
    """The id of the withdrawal of command message ``command_id`` (one per frame: the broker keeps one)."""
    return f"withdraw-{command_id}"


def down(data: bytes) -> CommandMessage | WithdrawMessage:
    """A message of a gateway's commands subject: a frame to send, or the withdrawal of one."""
    return (
        WithdrawMessage.decode(data) if _load(data).get("type") == "withdraw" else CommandMessage.decode(data)
    )


@dataclass(frozen=True)
class ScheduleMessage:
    """The TDMA frame of the gateways sharing one band (``gateway.slots.SlotPlan``): slot ``k``
    begins at ``epoch + k * slot`` (UNIX s) and belongs to ``order[k % len(order)]``; a gateway starts a
    transmission ``guard`` s after its slot begins at the earliest and has it answered ``guard`` s before
    the slot ends. ``poll``: the vehicles' modem addresses the gateway polls in its slots, each by its share
    (``shares``: the vehicles the center routes through this gateway weigh more: their own gateway polls
    them more often than the others do)."""

    id: str
    gateway: str
    epoch: float
    slot: float
    guard: float
    order: tuple[str, ...]
    poll: tuple[int, ...] = ()
    shares: tuple[tuple[int, float], ...] = ()  # (address, share) of the polled vehicles; 1 when not said

    def encode(self) -> bytes:
        body = {**asdict(self), "order": list(self.order), "poll": list(self.poll)}
        return _dump({**body, "shares": {str(a): share for a, share in self.shares}})

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
                shares=tuple(
                    (int(a), _positive(share)) for a, share in dict(body.get("shares") or {}).items()
                ),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise PayloadError(f"a schedule without {exc}") from exc


@dataclass(frozen=True)
class SyncBudgetMessage:
    """The SYNCs the center pre-signed for the vehicle at ``address`` while ``gateway`` serves it (each
    frame a scheduled SYNC whose counter is its time, one every ``step`` s), replacing any the gateway
    held for it; none: withdrawn. The gateway sends one when the center's own SYNCs for the vehicle have
    stopped for two ``interval`` s (a backhaul outage), then one per ``interval``: the newest whose time
    has come, if it is less than ``step`` old, with one attempt waiting ``ack_timeout`` s for the ACK."""

    id: str
    gateway: str
    address: int
    syncs: tuple[bytes, ...] = ()
    interval: float = 60.0
    step: float = 60.0
    ack_timeout: float = 20.0

    def encode(self) -> bytes:
        return _dump({**asdict(self), "syncs": [frame.hex() for frame in self.syncs]})

    @classmethod
    def decode(cls, data: bytes) -> SyncBudgetMessage:
        body = _load(data)
        try:
            message = cls(
                id=str(body["id"]),
                gateway=str(body["gateway"]),
                address=int(body["address"]),
                syncs=tuple(bytes.fromhex(frame) for frame in body.get("syncs", ())),
                interval=float(body["interval"]),
                step=float(body["step"]),
                ack_timeout=float(body["ack_timeout"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise PayloadError(f"a SYNC budget without {exc}") from exc
        if not all(math.isfinite(v) and v > 0 for v in (message.interval, message.step, message.ack_timeout)):
            raise PayloadError("a SYNC budget's interval, step and ACK wait are positive numbers")
        return message


@dataclass(frozen=True)
class EventMessage:
    """What a gateway reports. ``kind``: ``attempt`` (detail: command id, outcome ``stored``/``sent``/
    ``acked``/``failed``/``expired``, attempt number; the last one of a command has ``final``: true and
    its outcome is ``acked``, ``failed`` (no ACK after its attempts) or ``expired``), ``modem`` (detail: state), ``heartbeat`` (detail:
    ``GatewayState``)."""

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


@dataclass(frozen=True)
class Place:
    """Where a gateway's modem is, as every position in the fleet: metres north and east of the fleet's
    one origin (``TACIT_ORIGIN`` gives it in latitude and longitude), and its depth (m)."""

    north: float
    east: float
    depth: float = 0.0

    @classmethod
    def parse(cls, text: str) -> Place:
        """``NORTH,EAST[,DEPTH]`` (m); raises ValueError."""
        try:
            values = [_finite(x) for x in text.split(",")]
        except ValueError:
            values = []
        if len(values) not in (2, 3):
            raise ValueError(f"a place is NORTH,EAST[,DEPTH] in metres: {text!r}")
        return cls(*values)


@dataclass(frozen=True)
class Outage:
    """A backhaul outage the gateway lived through: how long (s), when it ended (UNIX s, its clock), and
    the messages its outbox held when the backhaul came back (the backlog it then sent)."""

    lasted: float
    ended: float
    backlog: int


@dataclass(frozen=True)
class GatewayState:
    """A heartbeat's detail, what a gateway says of itself: its outbox's incarnation, its backhaul (``up``:
    it is sent only while connected), the messages not yet published (``outbox``), its modem's address and
    state, its place (None: not told), its last outage (None: none since it started) and its MAC's status
    (None: no modem)."""

    incarnation: str
    outbox: int
    modem: str
    address: int | None = None
    place: Place | None = None
    outage: Outage | None = None
    backhaul: str = "up"
    link: dict[str, Any] | None = None  # its MAC's status (``gateway.mac.MacStatus.detail``)

    def detail(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def of(cls, detail: dict[str, Any]) -> GatewayState:
        """The heartbeat in an event's detail; raises PayloadError (a field missing or of the wrong type)."""
        try:
            place, outage = detail.get("place"), detail.get("outage")
            address = detail.get("address")
            return cls(
                incarnation=str(detail["incarnation"]),
                outbox=int(detail["outbox"]),
                modem=str(detail.get("modem", "")),
                address=None if address is None else int(address),
                place=None if place is None else Place(*(_finite(place[k]) for k in ("north", "east", "depth"))),
                outage=None if outage is None else Outage(
                    _finite(outage["lasted"]), _finite(outage["ended"]), int(outage["backlog"])
                ),
                backhaul=str(detail.get("backhaul", "up")),
                link=dict(detail["link"]) if isinstance(detail.get("link"), dict) else None,
            )  # fmt: skip
        except (KeyError, TypeError, ValueError) as exc:
            raise PayloadError(f"a heartbeat without {exc}") from exc


def _number(value: Any) -> float | None:
    return None if value is None else float(value)


def _finite(value: Any) -> float:
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"a number: {value!r}")
    return number


def _positive(value: Any) -> float:
    number = _finite(value)
    if number <= 0:
        raise ValueError(f"a positive number: {value!r}")
    return number
