"""What happens to a frame from a vehicle: stored first, then de-duplicated, decoded, applied, published.

A frame is committed before anything about it is acknowledged to anyone or shown (events, API,
command status). Frames that arrive together are stored in one transaction (group commit) and their
events published after it. Decoding problems are stored and published as such; nothing here raises on
bad input from the water.

Authentication (``tacit.auth``). A priority packet is decoded and shown at once, but its packet row
says ``auth = "pending"`` and its telemetry rows ``verified = false`` until a check-point whose MAC
covers it arrives; then they become verified. A check-point is applied (vehicle state, command
statuses) only if its MAC holds under one of the vehicle's keys and it is not older than the last one;
otherwise it is stored as ``forged`` (or ``replayed``) with a link event, and nothing else changes. A
packet whose seq a verified check-point vouched for with other bytes is marked ``forged``.

Restarts. What the shore knows of each vehicle's link (the duplicate window, the hashes of recent
priority packets, the last check-point, whether the sample chains must restart) is saved in
``linkstate`` with every batch, and so are the stream decoders' last states (``SAVED_CHAINS``), in
the same transaction as the packets they decoded. If a packet cannot be decoded because its base
state was never stored (the shore was down while the vehicle's modem was ACKed), the packet is stored
undecoded and the vehicle is asked, in one SYNC control packet (``needs_restart``, sent by the link
engine), to restart its chains; the samples of the packets it sent before that SYNC stay undecoded.
"""

from __future__ import annotations

import base64
import logging
import math
import threading
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import Engine, insert, update
from sqlmodel import Session, col, select

from server.db import writing
from server.events import EventBus
from server.link import keys
from server.models import Command, Frame, LinkEvent, LinkState, Packet, Telemetry, Vehicle, now, saved_id
from server.services import commands
from tacit import auth, packets
from tacit.codec import CodecError, PacketDecoder, StreamSpec, UnknownBase, chain_ids
from tacit.link import SeenWindow, from_frame
from tacit.navigation import Pose
from tacit.packets import CheckpointPacket, CommandStatus, PacketError, PriorityPacket, Stream, unpack_settled

log = logging.getLogger("tacit.server.ingest")

Events = list[tuple[str, dict]]
RECENT_SEQS = 64  # priority packet hashes kept per vehicle for the check-points to come
SAVED_SEEN = 64  # duplicate-window entries saved across a restart (retransmissions come within polls)
SAVED_CHAINS = 4  # decoder states saved per vehicle: the vehicle continues from its last delivered packet,
# almost always the newest; one based on a state not kept raises UnknownBase and the vehicle restarts


@dataclass
class VehicleState:
    """What the shore knows of a vehicle between packets (kept in memory, rebuilt from the DB)."""

    id: int
    name: str
    address: int
    decoder: PacketDecoder  # every stream of the vehicle: they share packets
    seen: SeenWindow = field(default_factory=SeenWindow)
    last_heard: float | None = None
    snr_in: float | None = None
    snr_out: float | None = None
    range_m: float | None = None
    frames: int = 0
    packets: int = 0
    duplicates: int = 0
    bytes_saved: int = 0
    checkpoint: dict | None = None
    checkpoint_time: int = 0  # the last verified check-point's time stamp (older ones are replays)
    recent: dict[int, list[tuple[bytes, int]]] = field(default_factory=dict)  # seq -> [(hash, packet id)]
    needs_restart: bool = False  # the engine should send a SYNC asking the vehicle to restart its chains
    producers: dict[int, int] = field(default_factory=dict)  # chain state id -> the packet row that left it
    forged: int = 0
    verified: int = 0
    decoder_saved: str | None = None  # ``decoder``'s state as saved (base64), None: changed since

    def saved(self) -> dict[str, Any]:
        if self.decoder_saved is None:
            self.decoder_saved = base64.b64encode(self.decoder.to_bytes(SAVED_CHAINS)).decode()
        return {"seen": [p.hex() for p in self.seen.recent[-SAVED_SEEN:]], "checkpoint": self.checkpoint,
                "decoder": self.decoder_saved,
                "checkpoint_time": self.checkpoint_time, "needs_restart": self.needs_restart,
                "producers": {str(k): v for k, v in self.producers.items()},
                "recent": {str(seq): [[h.hex(), pid] for h, pid in items] for seq, items in self.recent.items()}}  # fmt: skip

    def memento(self) -> tuple[Any, ...]:
        """Everything a batch changes in memory, to be put back if its transaction does not commit
        (a retried batch must decode and de-duplicate exactly as the first try would have)."""
        return (list(self.seen.recent), {k: list(v) for k, v in self.recent.items()}, self.checkpoint,
                self.checkpoint_time, self.needs_restart, dict(self.producers), self.decoder.mark(),
                self.decoder_saved)  # fmt: skip

    def rollback(self, memento: tuple[Any, ...]) -> None:
        (
            seen,
            recent,
            self.checkpoint,
            self.checkpoint_time,
            self.needs_restart,
            self.producers,
            decoder,
            saved,
        ) = memento
        self.seen.recent, self.recent, self.decoder_saved = seen, recent, saved
        self.decoder.undo(decoder)

    def restore(self, data: dict[str, Any]) -> None:
        self.seen.recent = [bytes.fromhex(p) for p in data.get("seen", [])]
        self.checkpoint = data.get("checkpoint")
        self.checkpoint_time = int(data.get("checkpoint_time", 0))
        self.needs_restart = bool(data.get("needs_restart", False))
        self.producers = {int(k): int(v) for k, v in data.get("producers", {}).items()}
        self.recent = {int(seq): [(bytes.fromhex(h), int(pid)) for h, pid in items]
                       for seq, items in data.get("recent", {}).items()}  # fmt: skip


@dataclass(frozen=True)
class IncomingFrame:
    src: int
    dest: int
    data: bytes
    rate: int = 0
    snr_in: float | None = None
    snr_out: float | None = None
    stats: dict | None = None
    at: float = field(default_factory=now)


@dataclass
class _Batch:
    """Rows gathered while handling frames, inserted together just before the commit."""

    packets: list[dict] = field(default_factory=list)
    telemetry: list[dict] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)

    def flush(self, s: Session) -> None:
        for table, rows in ((Packet, self.packets), (Telemetry, self.telemetry), (LinkEvent, self.events)):
            if rows:
                s.execute(insert(table), rows)
                rows.clear()


class Ingest:
    def __init__(self, db: Engine, bus: EventBus, streams: dict[Stream, StreamSpec]) -> None:
        self.db = db
        self.bus = bus
        self.streams = streams
        self.vehicles: dict[int, VehicleState] = {}  # by modem address
        self._lock = threading.Lock()
        self.stats = {"frames": 0, "packets": 0, "duplicates": 0, "rejected": 0, "unknown_vehicle": 0,
                      "verified": 0, "forged": 0, "replayed": 0, "unverifiable": 0}  # fmt: skip

    def load_vehicles(self) -> None:
        """The vehicles from the database; one new here gets its saved link state and decoders back."""
        with Session(self.db) as s:
            rows = s.exec(select(Vehicle)).all()
            with self._lock:
                for v in rows:
                    if v.address not in self.vehicles or self.vehicles[v.address].id != v.id:
                        self.vehicles[v.address] = self._resume(s, v)
                for address in set(self.vehicles) - {v.address for v in rows}:
                    del self.vehicles[address]

    def _resume(self, s: Session, v: Vehicle) -> VehicleState:
        """A vehicle's state as the last run left it: the link state and decoder states saved with the
        last batch of frames stored (in the same transaction, so they match the stored packets)."""
        state = VehicleState(saved_id(v), v.name, v.address, PacketDecoder(list(self.streams.values())))
        saved = s.get(LinkState, v.id)
        if saved is not None:
            try:
                state.restore(saved.state)
            except (KeyError, TypeError, ValueError) as exc:
                log.error("vehicle %s: saved link state unreadable (%s): starting afresh", v.name, exc)
            self._load_decoder(state, saved.state.get("decoder"))
        self._last_checkpoint(s, state)
        return state

    @staticmethod
    def _load_decoder(v: VehicleState, saved: str | None) -> None:
        """The decoder states saved for ``v``; without them the vehicle's next packet raises UnknownBase (it
        is stored undecoded) and the vehicle is asked to restart its chains."""
        if saved is None:
            return
        try:
            v.decoder.load(base64.b64decode(saved, validate=True))
        except ValueError as exc:  # a CodecError, or not base64
            log.warning("vehicle %s: saved decoder state not usable (%s): it will be asked to restart its "
                        "chains", v.name, exc)  # fmt: skip
            return
        v.decoder_saved = saved
        log.info("vehicle %s: decoder states restored (%d)", v.name, len(v.decoder.snapshots))

    def _last_checkpoint(self, s: Session, v: VehicleState) -> None:
        """After a restart: the last verified check-point stored (the pose the limits check against, and
        what the screens show with its age) instead of none until the vehicle's next one."""
        row = s.exec(select(Packet).where(Packet.vehicle_id == v.id, Packet.type == "checkpoint",
                                          Packet.auth == "verified").order_by(col(Packet.id).desc())).first()  # fmt: skip
        if row is not None:
            v.last_heard = row.at
            v.checkpoint = v.checkpoint or row.body

    def pose(self, address: int) -> Pose | None:
        """The pose the vehicle at ``address`` last reported (None before its first check-point)."""
        state = self.vehicles.get(address)
        return Pose.from_checkpoint(state.checkpoint if state else None)

    def handle(self, frame: IncomingFrame) -> list[dict]:
        """Store, decode and apply one received frame; returns the events published."""
        return self.handle_batch([frame])

    def handle_batch(self, frames: list[IncomingFrame]) -> list[dict]:
        """Frames that arrived together, in one transaction: nothing is published before the commit."""
        with self._lock:
            mementos = {v.address: v.memento() for f in frames if (v := self.vehicles.get(f.src))}
            try:
                pending = self._commit_batch(frames)
            except BaseException:
                for address, memento in mementos.items():
                    self.vehicles[address].rollback(memento)
                raise
            # after the commit: a subscriber that fails must not roll memory back behind the database
            for kind, data in pending:
                self.bus.publish(kind, **data)
        return [{"kind": kind, **data} for kind, data in pending]

    def _commit_batch(self, frames: list[IncomingFrame]) -> Events:
        pending: Events = []
        with writing(self.db) as s:
            batch = _Batch()
            touched: dict[int, VehicleState] = {}
            for frame in frames:
                pending.extend(self._frame(s, batch, frame))
                if frame.src in self.vehicles:
                    touched[frame.src] = self.vehicles[frame.src]
            batch.flush(s)
            for v in touched.values():  # in the same transaction as the packets it describes
                self._save(s, v)
            s.commit()
        return pending

    def _save(self, s: Session, v: VehicleState) -> None:
        row = s.get(LinkState, v.id)
        if row is None:
            s.add(LinkState(vehicle_id=v.id, state=v.saved()))
        else:
            row.state, row.updated_at = v.saved(), now()
            s.add(row)
        s.flush()

    def _frame(self, s: Session, batch: _Batch, frame: IncomingFrame) -> Events:
        vehicle = self.vehicles.get(frame.src)
        self.stats["frames"] += 1
        if not (0 <= frame.src <= 255 and 0 <= frame.dest <= 255 and 0 <= frame.rate <= 255):
            self.stats["rejected"] += 1  # the modem driver's parser bounds these; never trust it blindly
            log.warning("frame with impossible addresses or rate dropped")
            return []
        row = {"direction": "in", "src": frame.src, "dest": frame.dest, "rate": frame.rate, "data": frame.data,
               "snr_in": _finite(frame.snr_in), "snr_out": _finite(frame.snr_out), "stats": frame.stats,
               "at": frame.at}  # fmt: skip
        frame_id = s.execute(insert(Frame).returning(col(Frame.id)), [row]).scalar_one()
        if vehicle is None:
            self.stats["unknown_vehicle"] += 1
            batch.events.append({"vehicle_id": None, "kind": "unknown_vehicle", "at": frame.at,
                                 "detail": {"address": frame.src}})  # fmt: skip
            log.warning("frame from unknown modem address %d stored, not decoded", frame.src)
            return [("link", {"event": "unknown_vehicle", "address": frame.src})]
        vehicle.frames += 1
        vehicle.last_heard = frame.at
        vehicle.snr_in, vehicle.snr_out = _finite(frame.snr_in), _finite(frame.snr_out)
        out: Events = []
        for chunk in from_frame(frame.data):
            out.extend(self._packet(s, batch, vehicle, frame_id, chunk, frame.at))
        out.append(("link", {"event": "heard", "vehicle": vehicle.name, "address": vehicle.address,
                             "snr_in": frame.snr_in, "snr_out": frame.snr_out}))  # fmt: skip
        return out

    def _packet(
        self, s: Session, batch: _Batch, v: VehicleState, frame_id: int, chunk: bytes, at: float
    ) -> Events:
        if not v.seen.first_time(chunk):
            v.duplicates += 1
            self.stats["duplicates"] += 1
            log.info("vehicle %s: duplicate packet dropped (a retransmission)", v.name)
            return []
        try:
            packet = packets.decode(chunk)
            if isinstance(packet, packets.ControlPacket):
                raise PacketError("a control packet from a vehicle")
        except PacketError as exc:
            self.stats["rejected"] += 1
            batch.events.append({"vehicle_id": v.id, "kind": "bad_packet", "at": at,
                                 "detail": {"error": str(exc), "hex": chunk.hex()}})  # fmt: skip
            log.warning("vehicle %s: undecodable packet: %s", v.name, exc)
            return []
        self.stats["packets"] += 1
        v.packets += 1
        body = packets.as_dict(packet)
        priority = int(getattr(packet, "priority", 0))
        row = {"frame_id": frame_id, "vehicle_id": v.id, "type": body["type"], "seq": packet.seq,
               "priority": priority, "body": body, "at": at, "auth": "pending"}  # fmt: skip
        if isinstance(packet, CheckpointPacket):
            events, row["auth"] = self._checkpoint(s, batch, v, packet, body)
            s.execute(insert(Packet), [row])
        else:
            packet_id = s.execute(insert(Packet).returning(col(Packet.id)), [row]).scalar_one()
            recent = v.recent.setdefault(packet.seq, [])
            recent[:] = [*recent[-3:], (auth.packet_hash(chunk), packet_id)]
            while len(v.recent) > RECENT_SEQS:  # drop the seq furthest behind this one
                del v.recent[max(v.recent, key=lambda q: (packet.seq - q) % 256)]
            events = self._priority(batch, v, packet, body, at, packet_id)
            if body.get("stream_name") or body.get("error"):  # what decoding found (or why it could not)
                s.execute(update(Packet).where(Packet.id == packet_id).values(body=body))
        log.info("vehicle %s: %s packet seq %d stored", v.name, body["type"], packet.seq)
        summary = {"vehicle": v.name, "address": v.address, "type": body["type"], "seq": packet.seq,
                   "priority": priority, "size": len(chunk), "snr": v.snr_in, "body": body, "auth": row["auth"]}  # fmt: skip
        return [("packet", summary), *events]

    # --- check-points -----------------------------------------------------------------------------

    def _checkpoint(self, s: Session, batch: _Batch, v: VehicleState, cp: CheckpointPacket,
                    body: dict) -> tuple[Events, str]:  # fmt: skip
        """Verify, then apply; returns the events and the packet's ``auth``."""
        vehicle = s.get(Vehicle, v.id)
        assert vehicle is not None, "a vehicle with link state is stored"
        seqs = cp.covered_seqs()
        candidates = [[h for h, _ in v.recent.get(seq, [])] for seq in seqs]
        try:
            version, chosen = auth.verify_checkpoint(cp, keys.accepted(vehicle), v.address, candidates)
        except auth.Unverifiable as exc:
            return self._refused(
                batch, v, "unverifiable", f"check-point seq {cp.seq}: {exc}", cp
            ), "unverifiable"
        except auth.BadMac as exc:
            return self._refused(batch, v, "forged", f"check-point seq {cp.seq}: {exc}", cp), "forged"
        if cp.time < v.checkpoint_time:
            return self._refused(batch, v, "replayed", f"check-point seq {cp.seq} is older than the last", cp), (
                "replayed")  # fmt: skip
        v.checkpoint, v.checkpoint_time = body, cp.time
        v.verified += 1
        self.stats["verified"] += 1
        events: Events = [("vehicle", {"vehicle": v.name, "checkpoint": body})]
        events += self._vouch(s, batch, v, seqs, chosen)
        if vehicle is not None and vehicle.previous_key_hex and version == vehicle.key_version:
            s.execute(update(Vehicle).where(col(Vehicle.id) == v.id).values(previous_key_hex=None))
            batch.events.append({"vehicle_id": v.id, "kind": "key_confirmed", "at": now(),
                                 "detail": {"key_version": version}})  # fmt: skip
            events.append(("link", {"event": "key_confirmed", "vehicle": v.name, "key_version": version}))
            log.warning(
                "vehicle %s: key version %d confirmed; commands are signed with it now", v.name, version
            )
        return events + self._statuses(s, v, cp, vehicle), "verified"

    def _refused(
        self, batch: _Batch, v: VehicleState, kind: str, detail: str, cp: CheckpointPacket
    ) -> Events:
        v.forged += kind != "unverifiable"
        self.stats[kind] += 1
        batch.events.append({"vehicle_id": v.id, "kind": f"{kind}_checkpoint", "at": now(),
                             "detail": {"error": detail, "hex": cp.encode().hex()}})  # fmt: skip
        log.warning("vehicle %s: %s check-point ignored: %s", v.name, kind, detail)
        return [("link", {"event": f"{kind}_checkpoint", "vehicle": v.name, "error": detail})]

    def _vouch(
        self, s: Session, batch: _Batch, v: VehicleState, seqs: list[int], chosen: tuple[bytes, ...]
    ) -> Events:
        """The covered packets are verified; another packet received with one of their seqs is forged."""
        good: list[int] = []
        bad: list[int] = []
        for seq, digest in zip(seqs, chosen, strict=True):
            for h, packet_id in v.recent.get(seq, []):
                (good if h == digest else bad).append(packet_id)
            v.recent[seq] = [(h, pid) for h, pid in v.recent.get(seq, []) if h == digest]
        batch.flush(s)  # telemetry of packets in this batch is in the table before it is marked
        if good:
            s.execute(update(Packet).where(col(Packet.id).in_(good)).values(auth="verified"))
            trusted = self._trusted(s, good)
            if trusted:
                s.execute(
                    update(Telemetry).where(col(Telemetry.packet_id).in_(trusted)).values(verified=True)
                )
            if len(trusted) < len(good) and not v.needs_restart:
                v.needs_restart = True  # its chain ran through a packet nobody vouched for: start clean
                log.warning("vehicle %s: %d genuine packet(s) were decoded on a state no check-point vouched "
                            "for, or could not be decoded on it: their data stay unverified; asking for a "
                            "chain restart", v.name, len(good) - len(trusted))  # fmt: skip
        if bad:
            s.execute(update(Packet).where(col(Packet.id).in_(bad)).values(auth="forged"))
            self.stats["forged"] += len(bad)
            log.warning("vehicle %s: %d priority packet(s) not the ones the check-point vouched for: forged",
                        v.name, len(bad))  # fmt: skip
        return [("link", {"event": "verified", "vehicle": v.name, "packets": len(good), "forged": len(bad)})]

    def _trusted(self, s: Session, good: list[int]) -> list[int]:
        """Of packets whose bytes a check-point just vouched for, those whose data can be trusted too: the
        MAC covers a packet's bytes, not the decoder state it was decoded on, so a packet's data are
        verified only if the packet its state came from (its origin) was verified and trusted as well. A
        forged packet slipped into the chain leaves what was decoded after it unverified. A genuine packet
        that could not be decoded (its state was a forged one's, read as garbage) is not trusted either:
        the shore's chain is broken there, and the vehicle must restart it."""
        rows = {p.id: p for p in s.exec(select(Packet).where(col(Packet.id).in_(good))).all()}
        trusted: list[int] = []
        for packet_id in sorted(rows, key=lambda i: i or 0):  # arrival order: an origin comes first
            row = rows[packet_id]
            if row.body.get("error"):
                continue
            origin = row.body.get("origin")
            if origin is None or origin in trusted or self._was_trusted(s, origin):
                trusted.append(saved_id(row))
                row.body = {**row.body, "trusted": True}
                s.add(row)
        return trusted

    @staticmethod
    def _was_trusted(s: Session, packet_id: int) -> bool:
        row = s.get(Packet, packet_id)
        return row is not None and row.auth == "verified" and bool(row.body.get("trusted"))

    def _statuses(self, s: Session, v: VehicleState, cp: CheckpointPacket, vehicle: Vehicle | None) -> Events:
        """Command statuses through the one lifecycle (``server.services.commands``): last_command's,
        with where and when, and the final statuses of the four before it."""
        if not cp.last_command or vehicle is None:
            return []
        latest = vehicle.next_seq - 1  # the check-point names the latest seq with these low 16 bits
        last = latest - ((latest - cp.last_command) % 65536)
        report = commands.report_of(v.checkpoint or {})
        settled: list[tuple[int, CommandStatus | None, dict | None]] = [
            (last - k, status, None) for k, status in enumerate(unpack_settled(cp.settled), start=1)]  # fmt: skip
        updates = [*reversed(settled), (last, cp.command_status, report)]  # oldest first: each in its turn
        events: Events = []
        newest: Command | None = None
        for seq, reported, where in updates:
            status = commands.FROM_CHECKPOINT.get(reported) if reported else None
            if status is None or seq <= 0:
                continue
            command = s.exec(select(Command).where(Command.vehicle_id == v.id, Command.seq == seq)).first()
            reason = cp.reason.name.lower() if where is not None and reported is CommandStatus.REFUSED else ""
            if command is None or not commands.advance(
                s, command, status, reason, reason=reason, report=where
            ):
                continue
            events.append(("command", {"id": command.id, "vehicle": v.name, "seq": command.seq,
                                       "status": status.value, "reason": reason, "report": where}))  # fmt: skip
            if where is not None and status in (commands.Status.EXECUTING, commands.Status.EXECUTED):
                newest = command
        if newest is not None:  # after the settled finals: only what the vehicle left unsettled is superseded
            for old in commands.supersede_older(s, newest):
                events.append(("command", {"id": old.id, "vehicle": v.name, "seq": old.seq,
                                           "status": commands.Status.SUPERSEDED.value, "reason": ""}))  # fmt: skip
        return events

    # --- priority packets ---------------------------------------------------------------------------

    def _priority(self, batch: _Batch, v: VehicleState, pp: PriorityPacket, body: dict, at: float,
                  packet_id: int) -> Events:  # fmt: skip
        try:
            spans = v.decoder.decode(pp.payload, at)
        except CodecError as exc:
            return self._undecodable(batch, v, pp, body, at, exc)
        v.decoder_saved = None
        base, own = chain_ids(pp.payload)
        body["origin"] = v.producers.get(base) if base else None  # the packet whose state this one built on
        v.producers = {own: packet_id} if not base else {**v.producers, own: packet_id}
        events: Events = []
        carried = []
        for span in spans:
            spec = span.spec
            if span.lost:  # the shore cannot vouch for these ticks: stored as uncertain, without values
                batch.telemetry.extend({"vehicle_id": v.id, "stream": spec.name, "tick": k, "time": float(t),
                                        "values": [], "certain": False, "packet_id": packet_id, "verified": False}
                                       for k, t in zip(range(*span.lost), span.lost_times, strict=True))  # fmt: skip
            if not len(span.ticks) and not span.lost:
                continue
            carried.append(spec.name)
            times = [float(t) for t in span.times]
            # an absent channel is stored as absent (None), never as a made-up value
            rows = [[None if x != x else round(float(x), 6) for x in values] for values in span.values]
            batch.telemetry.extend({"vehicle_id": v.id, "stream": spec.name, "tick": int(k),
                                    "time": t, "certain": True, "values": row,
                                    "packet_id": packet_id, "verified": False}
                                   for k, t, row in zip(span.ticks, times, rows, strict=True))  # fmt: skip
            v.bytes_saved += max(0, int((span.values == span.values).sum()) * 2 - packets.PACKET_SIZE)
            events.append(("telemetry", {"vehicle": v.name, "stream": spec.name, "channels": list(spec.channels),
                                         "period": spec.period, "times": times,
                                         "values": [[None if x is None else round(x, 4) for x in row] for row in rows],
                                         "lost": list(span.lost) if span.lost else None, "verified": False}))  # fmt: skip
        main = next((s for s in spans if s.spec.stream == pp.stream and len(s.ticks)), None)
        main = main or next((s for s in spans if len(s.ticks)), spans[0])
        body.update(stream_name=main.spec.name, streams=carried, first_tick=main.first_tick,
                    ticks=sum(len(s.ticks) for s in spans),
                    lost=list(main.lost) if main.lost else None)  # fmt: skip
        return events

    def _undecodable(self, batch: _Batch, v: VehicleState, pp: PriorityPacket, body: dict, at: float,
                     exc: CodecError) -> Events:  # fmt: skip
        stream = pp.stream.name.lower()
        body["error"] = str(exc)
        batch.events.append({"vehicle_id": v.id, "kind": "undecodable", "at": at,
                             "detail": {"stream": stream, "error": str(exc)}})  # fmt: skip
        if isinstance(exc, UnknownBase) and not v.needs_restart:
            v.needs_restart = True  # the engine's next SYNC asks the vehicle to restart its chains
            log.warning(
                "vehicle %s: sample chain state lost: asking the vehicle to restart its chains", v.name
            )
        return [("link", {"event": "undecodable", "vehicle": v.name, "stream": stream, "error": str(exc)})]


def _finite(value: float | None) -> float | None:
    """An SNR as stored and used: None when unknown or not a number."""
    return value if value is not None and math.isfinite(value) else None
