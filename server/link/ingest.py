"""What happens to a frame from a vehicle: stored first, then de-duplicated, decoded, applied, published.

A frame is committed before anything about it is acknowledged to anyone or shown (events, API,
command status). Frames that arrive together are stored in one transaction (group commit) and their
events published after it. Decoding problems are stored and published as such; nothing here raises on
bad input from the water.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field

from sqlalchemy import Engine, insert
from sqlmodel import Session, select

from server.db import writing
from server.events import EventBus
from server.models import Command, Frame, LinkEvent, Packet, Telemetry, Vehicle, now
from server.services import commands
from tacit import packets
from tacit.codec import CodecError, StreamDecoder, StreamSpec
from tacit.link import SeenWindow, from_frame
from tacit.navigation import Pose
from tacit.packets import CheckpointPacket, CommandStatus, PacketError, PriorityPacket, Stream

log = logging.getLogger("tacit.server.ingest")

Events = list[tuple[str, dict]]


@dataclass
class VehicleState:
    """What the shore knows of a vehicle between packets (kept in memory, rebuilt from the DB)."""

    id: int
    name: str
    address: int
    decoders: dict[Stream, StreamDecoder]
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


class Ingest:
    def __init__(self, db: Engine, bus: EventBus, streams: dict[Stream, StreamSpec]) -> None:
        self.db = db
        self.bus = bus
        self.streams = streams
        self.vehicles: dict[int, VehicleState] = {}  # by modem address
        self._lock = threading.Lock()
        self.stats = {"frames": 0, "packets": 0, "duplicates": 0, "rejected": 0, "unknown_vehicle": 0}

    def load_vehicles(self) -> None:
        with Session(self.db) as s:
            rows = s.exec(select(Vehicle)).all()
        with self._lock:
            for v in rows:
                if v.address not in self.vehicles or self.vehicles[v.address].id != v.id:
                    decoders = {k: StreamDecoder(spec) for k, spec in self.streams.items()}
                    self.vehicles[v.address] = VehicleState(v.id, v.name, v.address, decoders)  # type: ignore[arg-type]
                    self._last_checkpoint(self.vehicles[v.address])
            for address in set(self.vehicles) - {v.address for v in rows}:
                del self.vehicles[address]

    def _last_checkpoint(self, v: VehicleState) -> None:
        """After a restart: the last check-point stored (the pose the limits check against, and what the
        screens show with its age) instead of none until the vehicle's next one."""
        with Session(self.db) as s:
            row = s.exec(select(Packet).where(Packet.vehicle_id == v.id, Packet.type == "checkpoint")
                         .order_by(Packet.id.desc())).first()  # type: ignore[union-attr]  # fmt: skip
        if row is not None:
            v.checkpoint, v.last_heard = row.body, row.at

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
            pending: Events = []
            with writing(self.db) as s:
                batch = _Batch()
                for frame in frames:
                    pending.extend(self._frame(s, batch, frame))
                batch.flush(s)
                s.commit()
        for kind, data in pending:
            self.bus.publish(kind, **data)
        return [{"kind": kind, **data} for kind, data in pending]

    def _frame(self, s: Session, batch: _Batch, frame: IncomingFrame) -> Events:
        vehicle = self.vehicles.get(frame.src)
        self.stats["frames"] += 1
        row = {"direction": "in", "src": frame.src, "dest": frame.dest, "rate": frame.rate, "data": frame.data,
               "snr_in": frame.snr_in, "snr_out": frame.snr_out, "stats": frame.stats, "at": frame.at}  # fmt: skip
        frame_id = s.execute(insert(Frame).returning(Frame.id), [row]).scalar_one()
        if vehicle is None:
            self.stats["unknown_vehicle"] += 1
            batch.events.append({"vehicle_id": None, "kind": "unknown_vehicle", "at": frame.at,
                                 "detail": {"address": frame.src}})  # fmt: skip
            log.warning("frame from unknown modem address %d stored, not decoded", frame.src)
            return [("link", {"event": "unknown_vehicle", "address": frame.src})]
        vehicle.frames += 1
        vehicle.last_heard = frame.at
        vehicle.snr_in, vehicle.snr_out = frame.snr_in, frame.snr_out
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
        if isinstance(packet, CheckpointPacket):
            events = self._checkpoint(s, v, packet, body)
        else:
            events = self._priority(batch, v, packet, body, at)
        priority = int(getattr(packet, "priority", 0))
        batch.packets.append({"frame_id": frame_id, "vehicle_id": v.id, "type": body["type"], "seq": packet.seq,
                              "priority": priority, "body": body, "at": at})  # fmt: skip
        log.info("vehicle %s: %s packet seq %d stored", v.name, body["type"], packet.seq)
        summary = {"vehicle": v.name, "address": v.address, "type": body["type"], "seq": packet.seq,
                   "priority": priority, "size": len(chunk), "snr": v.snr_in, "body": body}  # fmt: skip
        return [("packet", summary), *events]

    def _checkpoint(self, s: Session, v: VehicleState, cp: CheckpointPacket, body: dict) -> Events:
        v.checkpoint = body
        events: Events = [("vehicle", {"vehicle": v.name, "checkpoint": body})]
        status = commands.FROM_CHECKPOINT.get(cp.command_status)
        if not status or not cp.last_command:
            return events
        query = select(Command).where(Command.vehicle_id == v.id, Command.seq == cp.last_command)
        command = s.exec(query).first()
        reason = cp.reason.name.lower() if cp.command_status is CommandStatus.REFUSED else ""
        if command and commands.advance(s, command, status, reason, reason=reason):
            events.append(("command", {"id": command.id, "vehicle": v.name, "seq": command.seq,
                                       "status": status.value, "reason": reason}))  # fmt: skip
        return events

    def _priority(self, batch: _Batch, v: VehicleState, pp: PriorityPacket, body: dict, at: float) -> Events:
        spec = self.streams.get(pp.stream)
        if spec is None:
            body["error"] = f"no stream {pp.stream.name}"
            return []
        try:
            span = v.decoders[pp.stream].decode(pp.payload, at)
        except CodecError as exc:
            body["error"] = str(exc)
            batch.events.append({"vehicle_id": v.id, "kind": "undecodable", "at": at,
                                 "detail": {"stream": spec.name, "error": str(exc)}})  # fmt: skip
            return [
                ("link", {"event": "undecodable", "vehicle": v.name, "stream": spec.name, "error": str(exc)})
            ]
        if span.lost:  # the shore cannot vouch for these ticks: stored as uncertain, without values
            batch.telemetry.extend({"vehicle_id": v.id, "stream": spec.name, "tick": k, "time": k * spec.period,
                                    "values": [], "certain": False} for k in range(*span.lost))  # fmt: skip
        batch.telemetry.extend({"vehicle_id": v.id, "stream": spec.name, "tick": span.first_tick + i,
                                "time": (span.first_tick + i) * spec.period, "certain": True,
                                "values": [round(float(x), 6) for x in values]}
                               for i, values in enumerate(span.values))  # fmt: skip
        v.bytes_saved += max(0, span.values.size * 2 - packets.PACKET_SIZE)
        body.update(stream_name=spec.name, first_tick=span.first_tick, ticks=len(span.values),
                    lost=list(span.lost) if span.lost else None)  # fmt: skip
        return [("telemetry", {"vehicle": v.name, "stream": spec.name, "channels": list(spec.channels),
                               "first_time": span.first_tick * spec.period, "period": spec.period,
                               "values": [[round(float(x), 4) for x in row] for row in span.values],
                               "lost": list(span.lost) if span.lost else None})]  # fmt: skip
