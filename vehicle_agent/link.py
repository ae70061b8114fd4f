"""The vehicle's half of the link: answer the shore's polls, take its control packets.

Outgoing packets wait in a queue (time-sensitive first, then in order). When the shore polls, the
modem asks for data (``$CADRQ``) and gets as many queued packets as the frame holds. A packet is
delivered when the shore modem's ACK for its frame comes back (``$CAACK``); one still unacknowledged
at the next poll goes out again, byte for byte, and the shore drops the copy (exactly once). After
``attempts`` tries it is reported lost, so the compressor can re-base its chain.

Incoming control frames pass the MAC and replay window of ``tacit.auth`` before anyone sees them;
forged, bit-flipped, replayed and stale packets are logged and dropped. Time stamps are checked
against the local clock plus ``offset`` (the correction the shore's authenticated SYNC time gave).

A poll ($CADRQ) is answered whoever sent it (the Micro-Modem's poll carries no data to authenticate),
but it is only counted, never taken as a sign of the shore: only authentic control packets are.
``pending()`` lists what is queued or unacknowledged, for the agent to persist across a SIGKILL.
``capacity`` is how many packets the shore's last poll could carry (its frames' size, and how many
frames its modem asked for): the compressor keeps that many in flight.
"""

from __future__ import annotations

import itertools
import logging
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass, field

from tacit import auth, modem, nmea
from tacit.link import from_frame
from tacit.packets import (
    PACKET_SIZE,
    Command,
    ControlPacket,
    PacketError,
    PacketType,
    decode_control,
    packet_type,
)

log = logging.getLogger("tacit.agent.link")


@dataclass(order=True)
class Outgoing:
    urgency: int  # 0 = time-sensitive, 1 = normal: lower goes first
    order: int
    data: bytes = field(compare=False)
    on_result: Callable[[bool], None] | None = field(default=None, compare=False)
    tries: int = field(default=0, compare=False)


class VehicleLink:
    def __init__(
        self,
        driver: modem.ModemDriver,
        receiver: auth.ControlReceiver,
        shore_address: int | Collection[int] = 1,
        attempts: int = 4,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.driver = driver
        self.receiver = receiver
        # the shore's modem, or every gateway's of a split shore (docs/backhaul.md): polls, ACKs and
        # control frames from these only
        self.shore = frozenset([shore_address] if isinstance(shore_address, int) else shore_address)
        self.attempts = attempts
        self.clock = clock
        self.offset = 0.0
        self.queue: list[Outgoing] = []
        self.in_flight: dict[int, list[Outgoing]] = {}  # by frame number of the last poll answer
        self.on_control: Callable[[ControlPacket], None] = lambda packet: None
        self.on_repeat: Callable[[int], None] = lambda seq: None  # a genuine command seen before
        self._order = itertools.count()
        self._poll = (1, 1)  # the last poll: packets per frame, frames asked for
        self.counters = {
            "polls": 0,
            "sent": 0,
            "delivered": 0,
            "lost": 0,
            "resent": 0,
            "controls": 0,
            "rejected": 0,
        }
        driver.poll_provider = self._answer_poll
        driver.add_listener(self._on_event)

    def send(
        self, packet: bytes, urgent: bool = False, on_result: Callable[[bool], None] | None = None
    ) -> None:
        """Queue a 32-byte packet for the next poll; ``on_result(delivered)`` is called once."""
        if len(packet) != PACKET_SIZE:
            raise ValueError(f"a packet is {PACKET_SIZE} bytes")
        self.queue.append(Outgoing(0 if urgent else 1, next(self._order), bytes(packet), on_result))
        self.queue.sort()

    def pending(self) -> list[tuple[bool, bytes]]:
        """(urgent, packet) for everything not yet delivered, in sending order."""
        items = sorted([*self.queue, *(i for v in self.in_flight.values() for i in v)])
        return [(item.urgency == 0, item.data) for item in items]

    @property
    def capacity(self) -> int:
        """How many packets the shore's last poll could carry (at least as many frames as its modem
        asked for: one more than were filled, unless all were)."""
        return self._poll[0] * self._poll[1]

    def withdraw(self, packets: Collection[bytes]) -> None:
        """Take these packets back, queued or awaiting their ACK, without reporting them (their sender
        replaced them)."""
        gone = set(packets)
        self.queue = [item for item in self.queue if item.data not in gone]
        for frame, items in list(self.in_flight.items()):
            self.in_flight[frame] = [item for item in items if item.data not in gone]

    @property
    def backlog(self) -> int:
        return len(self.queue) + sum(len(v) for v in self.in_flight.values())

    def _answer_poll(self, drq: nmea.DataRequest) -> bytes | None:
        if drq.dest not in self.shore:
            return None
        if drq.frame == 1:
            self.counters["polls"] += 1
            self._requeue_unacknowledged()
        room = max(1, drq.maxbytes // PACKET_SIZE)
        self._poll = (room, drq.frame)
        chosen, self.queue = self.queue[:room], self.queue[room:]
        if not chosen:
            return None
        for item in chosen:
            item.tries += 1
        self.in_flight[drq.frame] = chosen
        self.counters["sent"] += len(chosen)
        return b"".join(item.data for item in chosen)

    def _requeue_unacknowledged(self) -> None:
        for items in self.in_flight.values():
            for item in items:
                if item.tries >= self.attempts:
                    self.counters["lost"] += 1
                    log.warning("packet lost after %d tries", item.tries)
                    if item.on_result:
                        item.on_result(False)
                else:
                    self.counters["resent"] += 1
                    self.queue.append(item)
        self.in_flight.clear()
        self.queue.sort()

    def _on_event(self, event: modem.Event) -> None:
        if isinstance(event, modem.AckReceived) and event.src in self.shore:
            for item in self.in_flight.pop(event.frame, []):
                self.counters["delivered"] += 1
                if item.on_result:
                    item.on_result(True)
        elif isinstance(event, modem.ReceivedFrame) and event.src in self.shore:
            for chunk in from_frame(event.data):
                self._control(chunk)

    def _control(self, frame: bytes) -> None:
        try:
            if packet_type(frame) is not PacketType.CONTROL:
                raise PacketError("not a control packet")
            packet = self.receiver.accept(frame, self.clock(), self.offset)
        except auth.Replayed as exc:  # genuine (the MAC held) but seen before: never executed twice
            self.counters["rejected"] += 1
            log.warning("control frame rejected: %s (%s)", exc, type(exc).__name__)
            repeated = decode_control(frame)
            if repeated.command is not Command.SYNC:
                self.on_repeat(repeated.seq)
            return
        except PacketError as exc:
            self.counters["rejected"] += 1
            log.warning("control frame rejected: %s (%s)", exc, type(exc).__name__)
            return
        self.counters["controls"] += 1
        if packet.command is Command.SYNC:  # a heartbeat, not a command: its counter is not a command seq
            log.info("SYNC %d accepted (shore time %d)", packet.seq, packet.time)
        else:
            log.info("control seq %d accepted: %s", packet.seq, packet.command.name)
        self.on_control(packet)
