"""In-process publish/subscribe of typed events, for the live event stream (SSE) and the map.

Each event is a frozen dataclass with its ``kind`` (the SSE event name); ``as_dict`` is its JSON.
Publishing is thread-safe (the ingest worker publishes from its thread). Each subscriber has a bounded
queue: a slow browser loses its oldest events, it never slows the link engine.
"""

from __future__ import annotations

import asyncio
import json
import logging
import queue as queues
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

log = logging.getLogger("tacit.server.events")


@dataclass(frozen=True, kw_only=True)
class Event:
    kind: ClassVar[str]
    at: float = field(default_factory=time.time)

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind}
        for f in fields(self):
            out[f.name] = getattr(self, f.name)
        return out


@dataclass(frozen=True, kw_only=True)
class PacketHeard(Event):
    """A vehicle packet was stored as packet ``id`` of frame ``frame_id`` (``auth``: its trust,
    ``server.telemetry.models.PacketTrust``; a priority packet's is pending until a check-point settles it:
    ``PacketsSettled``). Another gateway's copy of the frame is a ``LinkNotice`` ``heard_again``."""

    kind: ClassVar[str] = "packet"
    id: int
    frame_id: int
    gateway: str | None  # the gateway whose copy of the frame came first (None: the shore's own modem)
    vehicle: str
    address: int
    type: str
    seq: int
    priority: int
    size: int
    snr: float | None
    body: dict[str, Any]
    auth: str


@dataclass(frozen=True)
class CommandChanged(Event):
    """A command moved to ``status`` (``server.commands.models.CommandState``)."""

    kind: ClassVar[str] = "command"
    id: int
    seq: int
    status: str
    vehicle: str = ""
    command: str = ""
    detail: str = ""
    reason: str = ""
    report: dict[str, Any] | None = None


@dataclass(frozen=True, kw_only=True)
class VehicleReported(Event):
    """A verified check-point: the vehicle's state and pose."""

    kind: ClassVar[str] = "vehicle"
    vehicle: str
    checkpoint: dict[str, Any]


@dataclass(frozen=True, kw_only=True)
class TelemetryDecoded(Event):
    """Samples of one stream decoded from priority packet ``packet_id`` (``lost``: a span the shore cannot
    vouch for). They are not verified when decoded: ``PacketsSettled`` says when they are."""

    kind: ClassVar[str] = "telemetry"
    packet_id: int
    vehicle: str
    stream: str
    channels: list[str]
    period: float
    times: list[float]
    values: list[list[float | None]]
    lost: list[int] | None
    verified: bool = False


@dataclass(frozen=True, kw_only=True)
class PacketsSettled(Event):
    """A verified check-point settled the priority packets it covers (packet ids): their bytes are
    ``verified`` or ``forged`` (another packet with a vouched-for seq); of the verified, the ``trusted``
    ones' samples may be believed (decoded along a chain of trusted packets: ``server.link.verify``);
    pending ones it left behind, out of reach of any later check-point, are ``unverifiable``."""

    kind: ClassVar[str] = "settled"
    vehicle: str
    verified: list[int]
    forged: list[int]
    trusted: list[int]
    unverifiable: list[int] = field(default_factory=list)  # out of every later check-point's reach


@dataclass(frozen=True, kw_only=True)
class LinkNotice(Event):
    """Something about the link: ``event`` names it (heard, modem, range, undecodable,
    key_confirmed, forged_checkpoint, ...), ``detail`` says the rest."""

    kind: ClassVar[str] = "link"
    event: str
    vehicle: str | None = None
    detail: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        out = super().as_dict()
        return {**out.pop("detail"), **out}


@dataclass(frozen=True, kw_only=True)
class Relayed(Event):
    """An event another center process published, as its ``as_dict`` (``server.backhaul.live``): shown
    to this process's browsers (``Bus.show``), handled by nothing here."""

    kind: ClassVar[str] = "relayed"
    body: dict[str, Any]

    def as_dict(self) -> dict[str, Any]:
        return self.body


@dataclass(frozen=True, kw_only=True)
class SeparationWarning(Event):
    """Two vehicles' predicted positions came within the separation plus both their uncertainties
    (``active``), or are no longer that close (``active`` false): ``server.safety``."""

    kind: ClassVar[str] = "separation"
    vehicles: list[str]
    distance_m: float
    limit_m: float
    active: bool


@dataclass(frozen=True, kw_only=True)
class TeamChanged(Event):
    """A team mission moved on: ``what`` is ``started``, ``aborted``, a member's new state (``running``:
    its next leg is queued, ``done``, ``stopped``), ``proposal`` (new work proposed), ``applied`` or
    ``dismissed``; ``detail`` says the rest."""

    kind: ClassVar[str] = "team"
    team_id: int
    what: str
    detail: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, kw_only=True)
class StreamEnded(Event):
    """The last event of a live event stream whose token no longer holds (``detail``: revoked or expired,
    and when). Sent to that stream only, never published on the bus."""

    kind: ClassVar[str] = "end"
    detail: str


@dataclass(frozen=True, kw_only=True)
class GatewayChanged(Event):
    """A gateway's heartbeat came (its state, outbox, modem, place), or a vehicle's gateway changed
    (``what``: ``heartbeat``, ``assignment``, ``pin``, ``unpin``; ``vehicle`` names it): the screens read
    the gateways again (``GET /api/v1/gateways``)."""

    kind: ClassVar[str] = "gateway"
    gateway: str
    what: str
    vehicle: str | None = None


class Bus:
    def __init__(self, queue_size: int = 1000) -> None:
        self.queue_size = queue_size
        self._subscribers: set[asyncio.Queue[Event]] = set()
        self._callbacks: list[Callable[[Event], None]] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self.published = 0

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    def subscribe(self) -> asyncio.Queue[Event]:
        queue: asyncio.Queue[Event] = asyncio.Queue(self.queue_size)
        self._subscribers.add(queue)
        return queue

    def unsubscribe(self, queue: asyncio.Queue[Event]) -> None:
        self._subscribers.discard(queue)

    def on_event(self, callback: Callable[[Event], None]) -> None:
        """Also call ``callback`` (from the event loop) for every event: the map uses this."""
        self._callbacks.append(callback)

    def publish(self, event: Event) -> None:
        self.published += 1
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop:
            self._deliver(event)
        else:
            loop.call_soon_threadsafe(self._deliver, event)

    def _deliver(self, event: Event) -> None:
        self.show(event)
        for callback in self._callbacks:
            callback(event)

    def show(self, event: Event) -> None:
        """To the subscribers (the browsers' event streams), from the event loop; alone for an event
        another center process published, which that process's handlers have handled."""
        for queue in list(self._subscribers):
            if queue.full():
                queue.get_nowait()
            queue.put_nowait(event)

    @staticmethod
    def sse(event: Event) -> str:
        body = event.as_dict()
        return f"event: {body['kind']}\ndata: {json.dumps(body)}\n\n"


class Watcher:
    """Runs the handlers of bus events, and handlers due every ``interval`` s, on a thread of its own: off
    the event loop (they read and write the database) and one at a time (a team's legs advance in order).
    A failing handler is logged; it never stops the others."""

    def __init__(self, bus: Bus, interval: float, queue_size: int = 10000) -> None:
        self.interval = interval
        self._queue: queues.Queue[Event | None] = queues.Queue(queue_size)
        self._handlers: list[Callable[[Event], None]] = []
        self._ticks: list[Callable[[], None]] = []
        self._thread: threading.Thread | None = None
        bus.on_event(self._put)

    def on_event(self, handler: Callable[[Event], None]) -> None:
        self._handlers.append(handler)

    def every(self, handler: Callable[[], None]) -> None:
        self._ticks.append(handler)

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="tacit-watcher", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join(timeout=10)
            self._thread = None

    def _put(self, event: Event) -> None:
        if self._thread is None:
            return
        try:
            self._queue.put_nowait(event)
        except queues.Full:
            log.warning("watcher behind: %s event dropped", event.kind)

    def _run(self) -> None:
        due = time.monotonic() + self.interval
        while True:
            try:
                event = self._queue.get(timeout=max(0.0, due - time.monotonic()))
                if event is None:
                    return
                self._call(self._handlers, (event,))
            except queues.Empty:
                pass
            if time.monotonic() >= due:
                due = time.monotonic() + self.interval
                self._call(self._ticks, ())

    @staticmethod
    def _call(handlers: list[Callable[..., None]], args: tuple[Any, ...]) -> None:
        for handler in handlers:
            try:
                handler(*args)
            except Exception:
                log.exception("watcher handler %s failed", getattr(handler, "__qualname__", handler))
