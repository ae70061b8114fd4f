"""What the shore knows of each vehicle's link, as one typed record (``LinkRecord``) with one to/from
JSON: saved every ``state_save_interval`` s in a batch's transaction (``linkstate``), naming the last
stored frame it includes (``frame``: a restart replays the frames after it, ``server.link.ingest``), and
taken as the undo point of a batch whose transaction does not commit.

``VehicleState`` joins the record to what is only kept in memory: the stream decoder (its own cheap
``mark``/``undo``; its states are saved beside the record, base64), receive statistics and counters.
"""

from __future__ import annotations

import base64
import logging
from dataclasses import dataclass, field
from typing import Any

from server.core.db import now
from tacit.codec import CodecError, PacketDecoder
from tacit.link import SeenWindow
from tacit.navigation import Pose
from tacit.packets import VERSION

log = logging.getLogger("tacit.server.ingest")

RECENT_SEQS = 64  # priority packet hashes kept per vehicle for the check-points to come
SAVED_SEEN = 64  # duplicate-window entries saved across a restart (retransmissions come within polls)
ACCEPTED_MACS = 256  # MACs of the last verified check-points: one seen again is a replay, whatever its time
WAITING = 32  # packets kept waiting per vehicle for late ones (their base state, the packets they cover)


@dataclass
class LinkRecord:
    """The link state a restart and an undo must get back."""

    seen: SeenWindow = field(default_factory=SeenWindow)  # exactly-once: the last packets' bytes
    checkpoint: dict[str, Any] | None = None  # the last verified check-point
    checkpoint_time: int = 0  # the replay floor: check-points stamped before it are replays
    accepted_macs: list[bytes] = field(default_factory=list)  # the last ACCEPTED_MACS check-points' MACs
    needs_restart: bool = False  # the engine should send a SYNC asking the vehicle to restart its chains
    sync_counter: int = 0  # the last SYNC's counter (saved before it is sent: it only grows)
    echo: bytes | None = None  # the MAC of an unsynced check-point the next SYNC answers
    producers: dict[int, int] = field(default_factory=dict)  # chain state id -> the packet row that left it
    recent: dict[int, list[tuple[bytes, int]]] = field(default_factory=dict)  # seq -> [(hash, packet id)]
    frame: int | None = None  # the last stored frame this record includes (None: saved before it was kept)
    made: dict[int, float] = field(
        default_factory=dict
    )  # chain state id -> when the packet leaving it was heard
    waiting: list[tuple[int, bytes, float]] = field(default_factory=list)  # (packet id, bytes, heard at)

    def to_json(self, seen: int | None = None) -> dict[str, Any]:
        """JSON of the record (the last ``seen`` entries of the duplicate window; all when None)."""
        window = self.seen.recent if seen is None else self.seen.recent[-seen:]
        return {
            "seen": [p.hex() for p in window],
            "checkpoint": self.checkpoint,
            "checkpoint_time": self.checkpoint_time,
            "accepted_macs": [m.hex() for m in self.accepted_macs],
            "needs_restart": self.needs_restart,
            "sync_counter": self.sync_counter,
            "echo": self.echo.hex() if self.echo else None,
            "producers": {str(k): v for k, v in self.producers.items()},
            "recent": {str(seq): [[h.hex(), pid] for h, pid in items] for seq, items in self.recent.items()},
            "frame": self.frame,
            "made": {str(k): at for k, at in self.made.items()},
            "waiting": [[pid, data.hex(), at] for pid, data, at in self.waiting],
        }

    def accept(self, checkpoint: dict[str, Any], floor: int, mac: bytes) -> None:
        """A verified check-point is the vehicle's latest and ``floor`` the replay floor after it; its MAC
        is remembered, so the same check-point replayed later (after the duplicate window forgot its
        bytes, within the same second) is refused."""
        self.checkpoint, self.checkpoint_time = checkpoint, floor
        self.remember(mac)

    def remember(self, mac: bytes) -> None:
        """A verified check-point's MAC (applied, or late): the same bytes again are a replay."""
        self.accepted_macs = [*self.accepted_macs[-(ACCEPTED_MACS - 1) :], mac]

    def wait(self, packet_id: int, data: bytes, at: float) -> None:
        """A packet stored before what it needs came (a priority packet's base state, a check-point's
        covered packets, coming late through another gateway): taken again when a late packet comes."""
        self.waiting = [*self.waiting[-(WAITING - 1) :], (packet_id, data, at)]

    def candidates(self) -> set[int]:
        """The packets (ids) a check-point may vouch for next, and those their states came from."""
        return {pid for items in self.recent.values() for _, pid in items} | set(self.producers.values())

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> LinkRecord:
        """The record ``to_json`` wrote; raises KeyError, TypeError or ValueError on a damaged one."""
        return cls(
            seen=SeenWindow(recent=[bytes.fromhex(p) for p in data.get("seen", [])]),
            checkpoint=data.get("checkpoint"),
            checkpoint_time=int(data.get("checkpoint_time", 0)),
            accepted_macs=[bytes.fromhex(m) for m in data.get("accepted_macs", [])],
            needs_restart=bool(data.get("needs_restart", False)),
            sync_counter=int(data.get("sync_counter", 0)),
            echo=bytes.fromhex(data["echo"]) if data.get("echo") else None,
            producers={int(k): int(v) for k, v in data.get("producers", {}).items()},
            recent={int(seq): [(bytes.fromhex(h), int(pid)) for h, pid in items]
                    for seq, items in data.get("recent", {}).items()},
            frame=None if data.get("frame") is None else int(data["frame"]),
            made={int(k): float(at) for k, at in data.get("made", {}).items()},
            waiting=[(int(pid), bytes.fromhex(h), float(at)) for pid, h, at in data.get("waiting", [])],
        )  # fmt: skip


@dataclass(frozen=True)
class Undo:
    """A batch's undo point: the record as JSON, the decoder's mark, its saved form then."""

    record: dict[str, Any]
    decoder: object
    decoder_saved: str | None


@dataclass
class VehicleState:
    """One vehicle's link: the saved record, its decoder, and what is only counted in memory."""

    id: int
    name: str
    address: int
    decoder: PacketDecoder  # every stream of the vehicle: they share packets
    link: LinkRecord = field(default_factory=LinkRecord)
    last_heard: float | None = None
    snr_in: float | None = None
    snr_out: float | None = None
    range_m: float | None = None
    frames: int = 0
    packets: int = 0
    duplicates: int = 0
    bytes_saved: int = 0
    forged: int = 0
    verified: int = 0
    old_protocol: int = 0  # packets refused for another protocol version than its own (logged once)
    decoder_saved: str | None = None  # ``decoder``'s states as saved (base64); None: changed since
    share: float = 1.0  # its weight in the MAC's schedule (``server.link.schedule``), as registered
    urgent: bool = False  # it reported time-sensitive data since it was last polled
    restart_raised: float = -1e18  # when an unknown base last asked for a chain restart (shore clock)
    protocol: int = VERSION  # the protocol version it is registered as speaking (``tacit.packets``)

    def saved(self) -> dict[str, Any]:
        """What ``linkstate`` holds: the record and the decoder's last states."""
        if self.decoder_saved is None:
            # the states the vehicle may continue from (``PacketDecoder.keep``); one based on a state not
            # kept raises UnknownBase and the vehicle restarts its chains
            self.decoder_saved = base64.b64encode(self.decoder.to_bytes(self.decoder.keep)).decode()
        return {**self.link.to_json(SAVED_SEEN), "decoder": self.decoder_saved}

    def undo_point(self) -> Undo:
        return Undo(self.link.to_json(), self.decoder.mark(), self.decoder_saved)

    def undo(self, point: Undo) -> None:
        """Everything a batch changed in memory, put back (a retried batch must decode and de-duplicate
        exactly as the first try would have)."""
        self.link = LinkRecord.from_json(point.record)
        self.decoder.undo(point.decoder)  # type: ignore[arg-type]
        self.decoder_saved = point.decoder_saved

    def restore(self, data: dict[str, Any]) -> None:
        """The state a previous run saved; a damaged record starts afresh, a damaged decoder state is
        dropped (the vehicle's next packet then raises UnknownBase and it is asked to restart)."""
        try:
            self.link = LinkRecord.from_json(data)
        except (KeyError, TypeError, ValueError) as exc:
            log.error("vehicle %s: saved link state unreadable (%s): starting afresh", self.name, exc)
        saved = data.get("decoder")
        if saved is None:
            return
        try:
            self.decoder.load(base64.b64decode(saved, validate=True))
        except (CodecError, ValueError) as exc:
            log.warning(
                "vehicle %s: saved decoder state not usable (%s): it will be asked to restart its chains",
                self.name,
                exc,
            )
            return
        self.decoder_saved = saved
        log.info("vehicle %s: decoder states restored (%d)", self.name, len(self.decoder.snapshots))

    def pose(self) -> Pose | None:
        """The pose the vehicle last reported (None before its first check-point)."""
        return Pose.from_checkpoint(self.link.checkpoint)


@dataclass(frozen=True)
class IncomingFrame:
    src: int
    dest: int
    data: bytes
    rate: int = 0
    snr_in: float | None = None
    snr_out: float | None = None
    stats: dict[str, Any] | None = None
    at: float = field(default_factory=now)
    gateway: str = ""  # the gateway whose modem heard it (empty: this shore's own modem)
