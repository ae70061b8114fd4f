"""What a batch of frames writes, gathered while it is handled and written just before its commit: one
statement per table, whatever the number of frames.

A frame or packet row gets its id when it is gathered (ids reserved in the batch's transaction,
``telemetry.reserve_ids``), so that packets, samples, events and the link state can name it before any
row is inserted. Trust given to packets while the batch runs (a check-point vouching for them) is
applied to the rows of this batch before they are inserted, and to older packets with one update per
trust at the end; reads of a packet's trust (``packet_states``) see both.

``Replay`` is the same interface over frames stored already: it hands out their stored ids and writes
nothing, so that the pipeline rebuilds a vehicle's memory from them (``Ingest.replay``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Self

from server.core.db import Tx
from server.link import repository as link
from server.telemetry import repository as telemetry
from server.telemetry.models import Frame, Packet, PacketTrust
from server.vehicles import repository as vehicles
from server.vehicles.models import Vehicle


class ReplayMismatch(Exception):
    """A replayed frame yields a packet the store does not hold: the replay stops there."""


@dataclass
class Batch:
    live = True  # frames as they come (a ``Replay`` is not)
    frame_ids: list[int] = field(default_factory=list)  # reserved, not yet handed out
    packet_ids: list[int] = field(default_factory=list)
    frames: list[dict[str, Any]] = field(default_factory=list)
    packets: dict[int, dict[str, Any]] = field(default_factory=dict)  # by id, in arrival order
    samples: list[dict[str, Any]] = field(default_factory=list)  # telemetry rows
    events: list[dict[str, Any]] = field(default_factory=list)  # link event rows
    trust: dict[int, PacketTrust] = field(default_factory=dict)  # older packets' new trust
    trusted: set[int] = field(default_factory=set)  # older packets whose data became trusted
    vehicles: dict[int, Vehicle] = field(default_factory=dict)  # the batch's vehicles, read once
    stored: dict[int, dict[str, Any]] = field(default_factory=dict)  # older packets' states as read
    redecoded: dict[int, dict[str, Any]] = field(default_factory=dict)  # older packets decoded now
    verified: set[int] = field(default_factory=set)  # frames with a first-heard packet whose tag or MAC held

    @classmethod
    def open(cls, s: Tx, frames: int, packets: int) -> Self:
        """A batch of at most ``frames`` frames holding at most ``packets`` packets."""
        return cls(telemetry.reserve_ids(s, Frame, frames), telemetry.reserve_ids(s, Packet, packets))

    def vehicle(self, s: Tx, vehicle_id: int) -> Vehicle:
        vehicle = self.vehicles.get(vehicle_id) or vehicles.get(s, vehicle_id)
        assert vehicle is not None, "a vehicle with link state is stored"
        return vehicle

    def add_frame(self, row: dict[str, Any]) -> int:
        frame_id = self.frame_ids.pop(0)
        self.frames.append({**row, "id": frame_id})
        return frame_id

    def add_packet(self, row: dict[str, Any]) -> int:
        """The packet's id; ``row`` stays the batch's until the flush (decoding completes its body)."""
        packet_id = self.packet_ids.pop(0)
        row.update(id=packet_id, origin=row.get("origin"), trusted=False)
        row.setdefault("auth", PacketTrust.PENDING.value)
        self.packets[packet_id] = row
        return packet_id

    def set_trust(self, packet_ids: Iterable[int], trust: PacketTrust) -> None:
        for packet_id in packet_ids:
            if packet_id in self.packets:
                self.packets[packet_id]["auth"] = trust.value
            else:
                self.trust[packet_id] = trust

    def trust_data(self, packet_ids: Iterable[int]) -> None:
        """The packets' data (their rows and their samples) may be believed."""
        for packet_id in packet_ids:
            if packet_id in self.packets:
                self.packets[packet_id]["trusted"] = True
            else:
                self.trusted.add(packet_id)

    def decoded(self, s: Tx, packet_id: int, body: dict[str, Any], origin: int | None) -> None:
        """A packet stored undecoded (it waited for its base state) decoded now: its body and origin."""
        row = self.packets.get(packet_id) or self.redecoded.get(packet_id)
        if row is None:
            stored = self.packet_states(s, [packet_id]).get(packet_id)
            if stored is None:
                return
            row = self.redecoded[packet_id] = {"id": packet_id, "body": dict(stored["body"])}
        row["body"] = {**{k: x for k, x in row["body"].items() if k != "error"}, **body}
        row["origin"] = origin

    def packet_states(self, s: Tx, packet_ids: Sequence[int]) -> dict[int, dict[str, Any]]:
        """Each packet's ``body``, ``origin``, ``auth`` and ``trusted`` as this batch leaves them."""
        states = {i: self.packets[i] for i in packet_ids if i in self.packets}
        self.read(s, [i for i in packet_ids if i not in states])
        for packet_id in (i for i in packet_ids if i in self.stored and i not in states):
            state = self.stored[packet_id]
            states[packet_id] = {
                **state,
                "auth": self.trust.get(packet_id, state["auth"]),
                "trusted": state["trusted"] or packet_id in self.trusted,
            }
        return states

    def read(self, s: Tx, packet_ids: Iterable[int]) -> None:
        """Older packets' states read in one query (those the batch's check-points may vouch for)."""
        missing = [i for i in packet_ids if i not in self.stored and i not in self.packets]
        self.stored.update(telemetry.packet_states(s, missing))

    def flush(self, s: Tx) -> None:
        """Everything gathered, inserted and updated: a statement per table and per trust."""
        verified = {i for i, row in self.packets.items() if row["trusted"]}
        for sample in self.samples:
            sample["verified"] = sample["verified"] or sample["packet_id"] in verified
        telemetry.add_frame_rows(s, self.frames)
        telemetry.add_packet_rows(s, list(self.packets.values()))
        telemetry.decoded_later(s, list(self.redecoded.values()))
        telemetry.add_samples(s, self.samples)
        link.add_events(s, self.events)
        for trust in set(self.trust.values()):
            telemetry.set_trust(s, [i for i, t in self.trust.items() if t is trust], trust)
        telemetry.trust_data(s, sorted(self.trusted))


@dataclass
class Replay(Batch):
    """Stored frames handled again to rebuild memory: their stored ids, nothing written."""

    live = False
    kept: dict[tuple[int, int, str], int] = field(default_factory=dict)  # (frame, seq, type) -> packet id
    current: int = 0  # the stored frame being handled

    def add_frame(self, row: dict[str, Any]) -> int:
        return self.current

    def add_packet(self, row: dict[str, Any]) -> int:
        key = (row["frame_id"], row["seq"], row["type"])
        if key not in self.kept:
            raise ReplayMismatch(f"frame {key[0]}: no stored {key[2]} packet seq {key[1]}")
        return self.kept[key]

    def set_trust(self, packet_ids: Iterable[int], trust: PacketTrust) -> None:
        """Stored already."""

    def trust_data(self, packet_ids: Iterable[int]) -> None:
        """Stored already."""

    def decoded(self, s: Tx, packet_id: int, body: dict[str, Any], origin: int | None) -> None:
        """Stored already."""

    def flush(self, s: Tx) -> None:
        """Stored already."""
