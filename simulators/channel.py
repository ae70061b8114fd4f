"""The simulated acoustic channel: nodes, propagation, loss, half duplex and collisions.

A transmission occupies [start, start + airtime] at its sender and arrives at every other node over
[start + d, start + d + airtime], d = range / c. When an arrival ends, the receiver's outcome is
decided: lost whole if the receiver was transmitting during it (half duplex) or another arrival
overlapped it there (collision); otherwise each frame survives with probability 1 - FER(SNR), then
the configured extra loss, then the sender's and the receiver's own (a modem taken out of range at run
time). Random draws come from one seeded generator in event order, so the same seed gives the same
outcome.
"""

from __future__ import annotations

import enum
import functools
import math
import random
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from simulators.acoustics import ChannelParameters, frame_error_rate
from simulators.clock import Scheduler

Position = tuple[float, float, float]  # north, east, depth (m)
NO_LOSS = 0.0


class Kind(enum.Enum):
    CYCLE_INIT = "cycle_init"
    DATA = "data"
    ACK = "ack"
    PING = "ping"
    PING_REPLY = "ping_reply"
    MINI = "mini"


@dataclass
class Transmission:
    kind: Kind
    src: int  # the modem address that sent it
    dest: int
    rate: int
    airtime: float
    frames: list[bytes] = field(default_factory=list)
    ack: bool = False
    # The kind's own fields: a cycle-init's src/dest/rate/ack/nframes, an ack's frame numbers, a mini-packet's data.
    info: Mapping[str, Any] = field(default_factory=dict)
    start: float = 0.0
    sender: str = ""

    @property
    def addressee(self) -> int:
        """The modem address it is for. A poll is a cycle-init its sender addresses to itself (the data is
        for the poller): it is for the polled modem, the data's source."""
        if self.kind is Kind.CYCLE_INIT and self.dest == self.src:
            return int(self.info["src"])
        return self.dest


@dataclass
class Reception:
    transmission: Transmission
    frames_ok: list[bool]
    snr_db: float
    range_m: float
    collided: bool = False

    @property
    def heard(self) -> bool:
        """Anything intelligible arrived (a lost cycle-init, ACK or ping is simply not heard)."""
        return any(self.frames_ok) if self.frames_ok else False


@dataclass
class Node:
    name: str
    position: Callable[[], Position]
    on_receive: Callable[[Reception], None]
    sends: list[tuple[float, float]] = field(default_factory=list)
    arrivals: list[tuple[float, float, Transmission]] = field(default_factory=list)
    #: probability (0..1, read at each arrival) that a frame to or from this node is lost, on top of the
    #: channel's: a modem taken out of range at run time (``SIM_MODEM_LOSS`` on its vehicle)
    loss: Callable[[], float] = lambda: NO_LOSS
    address: int | None = None  # the modem's address: a transmission for it is counted apart


class Channel:
    def __init__(self, scheduler: Scheduler, params: ChannelParameters | None = None) -> None:
        self.scheduler = scheduler
        self.params = params or ChannelParameters()
        self.rng = random.Random(self.params.seed)
        self.nodes: dict[str, Node] = {}
        self.log: list[dict[str, object]] = []
        self.stats = {"transmissions": 0, "receptions": 0, "lost": 0, "collisions": 0, "half_duplex": 0}
        # in frames (a transmission without frames counts as one), at the modem each transmission is for
        # (lost = collided + while it transmitted + to noise and range) and at every other modem
        self.stats |= dict.fromkeys(
            ("addressed", "addressed_lost", "addressed_collided", "addressed_deaf"), 0
        )
        self.stats |= dict.fromkeys(("overheard", "overheard_lost"), 0)

    def add_node(
        self,
        name: str,
        position: Callable[[], Position],
        on_receive: Callable[[Reception], None],
        loss: Callable[[], float] = lambda: NO_LOSS,
        address: int | None = None,
    ) -> Node:
        node = Node(name, position, on_receive, loss=loss, address=address)
        self.nodes[name] = node
        return node

    def range_m(self, a: str, b: str) -> float:
        pa, pb = self.nodes[a].position(), self.nodes[b].position()
        return math.dist(pa, pb)

    def busy(self, name: str) -> bool:
        now = self.scheduler.now()
        return any(start <= now < end for start, end in self.nodes[name].sends)

    def transmit(self, sender: str, tx: Transmission) -> float:
        """Start a transmission now; returns the simulated time it ends at the sender."""
        now = self.scheduler.now()
        tx.start, tx.sender = now, sender
        node = self.nodes[sender]
        node.sends = [s for s in node.sends if s[1] > now - 120.0] + [(now, now + tx.airtime)]
        self.stats["transmissions"] += 1
        for name, other in self.nodes.items():
            if name == sender:
                continue
            distance = self.range_m(sender, name)
            begin = now + self.params.delay_s(distance)
            end = begin + tx.airtime
            other.arrivals.append((begin, end, tx))
            self.scheduler.call_later(
                end - now, functools.partial(self._arrive, other, tx, begin, end, distance)
            )
        return now + tx.airtime

    def _arrive(self, node: Node, tx: Transmission, begin: float, end: float, distance: float) -> None:
        others = [a for a in node.arrivals if a[2] is not tx and a[0] < end and a[1] > begin]
        collided = bool(others)
        deaf = any(start < end and stop > begin for start, stop in node.sends)
        snr = self.params.mean_snr_db(distance) + self.rng.gauss(0.0, self.params.fading_sigma_db)
        count = max(1, len(tx.frames))
        if collided or deaf:
            frames_ok = [False] * count
        else:
            fer = frame_error_rate(snr, tx.rate, self.params.fer_width_db)
            extra = self.params.extra_loss_by_kind.get(tx.kind.value, self.params.extra_loss)
            isolated = max(node.loss(), self.nodes[tx.sender].loss())  # no draw when 0: same seed, same run
            frames_ok = [
                self.rng.random() >= fer
                and self.rng.random() >= extra
                and (isolated <= 0 or self.rng.random() >= isolated)
                for _ in range(count)
            ]
        self.stats["receptions"] += 1
        self.stats["collisions"] += collided
        self.stats["half_duplex"] += deaf
        self.stats["lost"] += frames_ok.count(False)
        self._count(node, tx, frames_ok, collided, deaf)
        self.log.append(
            {
                "time": round(end, 6),
                "kind": tx.kind.value,
                "from": tx.sender,
                "to": node.name,
                "range_m": round(distance, 2),
                "snr_db": round(snr, 1),
                "frames_ok": frames_ok,
                "collided": collided,
                "half_duplex": deaf,
            }
        )
        horizon = end - 120.0
        node.arrivals = [a for a in node.arrivals if a[1] > horizon]
        node.on_receive(Reception(tx, frames_ok, snr, distance, collided or deaf))

    def _count(self, node: Node, tx: Transmission, frames_ok: list[bool], collided: bool, deaf: bool) -> None:
        frames, lost = len(frames_ok), frames_ok.count(False)
        if node.address is None or node.address != tx.addressee:
            self.stats["overheard"] += frames
            self.stats["overheard_lost"] += lost
            return
        self.stats["addressed"] += frames
        self.stats["addressed_lost"] += lost
        self.stats["addressed_collided"] += frames if collided else 0
        self.stats["addressed_deaf"] += frames if deaf and not collided else 0
