"""What happens to a frame from a vehicle: stored first, then de-duplicated, decoded, applied, published.

A frame is committed before anything about it is acknowledged to anyone or shown (events, API,
command status). Decoding problems are stored and published as such; nothing here raises on bad
input from the water.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field

from sqlalchemy import Engine, insert, update
from sqlmodel import Session, select

from server.db import writing
from server.events import EventBus
from server.models import Command, CommandEvent, Frame, LinkEvent, Packet, Telemetry, Vehicle, now
from tacit import packets
from tacit.codec import CodecError, StreamDecoder, StreamSpec
from tacit.link import SeenWindow, from_frame
from tacit.packets import CheckpointPacket, CommandStatus, PacketError, PriorityPacket, Stream

log = logging.getLogger("tacit.server.ingest")

STATUS_FOR = {CommandStatus.EXECUTING: "executing", CommandStatus.EXECUTED: "executed",
              CommandStatus.REFUSED: "refused", CommandStatus.SUPERSEDED: "superseded"}  # fmt: skip
ORDER = ["queued", "sent", "acknowledged", "executing", "executed", "refused", "superseded", "failed"]


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
                    self.vehicles[v.address] = VehicleState(
                        v.id, v.name, v.address, {k: StreamDecoder(spec) for k, spec in self.streams.items()}
                    )  # type: ignore[arg-type]
            for address in set(self.vehicles) - {v.address for v in rows}:
                del self.vehicles[address]

    def handle(self, frame: IncomingFrame) -> list[dict]:
        """Store, decode and apply one received frame; returns the events published."""
        with self._lock:
            return self._handle(frame)

    def _handle(self, frame: IncomingFrame) -> list[dict]:
        vehicle = self.vehicles.get(frame.src)
        self.stats["frames"] += 1
        with writing(self.db) as s:
            row = Frame(direction="in", src=frame.src, dest=frame.dest, rate=frame.rate, data=frame.data,
                        snr_in=frame.snr_in, snr_out=frame.snr_out, stats=frame.stats, at=frame.at)  # fmt: skip
            s.add(row)
            if vehicle is None:
                self.stats["unknown_vehicle"] += 1
                s.add(LinkEvent(kind="unknown_vehicle", detail={"address": frame.src}, at=frame.at))
                s.commit()
                log.warning("frame from unknown modem address %d stored, not decoded", frame.src)
                self.bus.publish("link", event="unknown_vehicle", address=frame.src)
                return []
            s.flush()
            vehicle.frames += 1
            vehicle.last_heard = frame.at
            vehicle.snr_in, vehicle.snr_out = frame.snr_in, frame.snr_out
            pending: list[tuple[str, dict]] = []
            for chunk in from_frame(frame.data):
                pending.extend(self._packet(s, vehicle, row, chunk, frame.at))
            s.commit()  # the frame and all it carried are on disk before anything is published
        out = []
        for kind, data in pending:
            self.bus.publish(kind, **data)
            out.append({"kind": kind, **data})
        self.bus.publish("link", event="heard", vehicle=vehicle.name, address=vehicle.address,
                         snr_in=frame.snr_in, snr_out=frame.snr_out)  # fmt: skip
        return out

    def _packet(
        self, s: Session, v: VehicleState, frame: Frame, chunk: bytes, at: float
    ) -> list[tuple[str, dict]]:
        if not v.seen.first_time(chunk):
            v.duplicates += 1
            self.stats["duplicates"] += 1
            log.info("vehicle %s: duplicate packet dropped (a retransmission)", v.name)
            return []
        try:
            packet = packets.decode(chunk)
        except PacketError as exc:
            self.stats["rejected"] += 1
            s.add(
                LinkEvent(
                    vehicle_id=v.id, kind="bad_packet", detail={"error": str(exc), "hex": chunk.hex()}, at=at
                )
            )
            log.warning("vehicle %s: undecodable packet: %s", v.name, exc)
            return []
        if isinstance(packet, packets.ControlPacket):
            s.add(
                LinkEvent(
                    vehicle_id=v.id,
                    kind="bad_packet",
                    detail={"error": "control packet from a vehicle"},
                    at=at,
                )
            )
            return []
        self.stats["packets"] += 1
        v.packets += 1
        body = packets.as_dict(packet)
        if isinstance(packet, CheckpointPacket):
            events = self._checkpoint(s, v, packet, body)
        else:
            events = self._priority(s, v, packet, body, at)
        row = Packet(frame_id=frame.id, vehicle_id=v.id, type=body["type"], seq=packet.seq,  # type: ignore[arg-type]
                     priority=int(getattr(packet, "priority", 0)), body=body, at=at)  # fmt: skip
        s.add(row)
        log.info("vehicle %s: %s packet seq %d stored", v.name, body["type"], packet.seq)
        summary = {"vehicle": v.name, "address": v.address, "type": body["type"], "seq": packet.seq,
                   "priority": row.priority, "size": len(chunk), "snr": v.snr_in, "body": body}  # fmt: skip
        return [("packet", summary), *events]

    def _checkpoint(
        self, s: Session, v: VehicleState, cp: CheckpointPacket, body: dict
    ) -> list[tuple[str, dict]]:
        v.checkpoint = body
        events: list[tuple[str, dict]] = [("vehicle", {"vehicle": v.name, "checkpoint": body})]
        status = STATUS_FOR.get(cp.command_status)
        if status and cp.last_command:
            command = s.exec(
                select(Command).where(Command.vehicle_id == v.id, Command.seq == cp.last_command)
            ).first()
            if command and ORDER.index(status) > ORDER.index(command.status):
                reason = cp.reason.name.lower() if cp.command_status is CommandStatus.REFUSED else ""
                s.exec(update(Command).where(Command.id == command.id).values(status=status, reason=reason,
                                                                             updated_at=now()))  # fmt: skip
                s.add(CommandEvent(command_id=command.id, status=status, detail=reason))  # type: ignore[arg-type]
                events.append(("command", {"id": command.id, "vehicle": v.name, "seq": command.seq,
                                           "status": status, "reason": reason}))  # fmt: skip
        return events

    def _priority(
        self, s: Session, v: VehicleState, pp: PriorityPacket, body: dict, at: float
    ) -> list[tuple[str, dict]]:
        spec = self.streams.get(pp.stream)
        if spec is None:
            body["error"] = f"no stream {pp.stream.name}"
            return []
        try:
            span = v.decoders[pp.stream].decode(pp.payload, at)
        except CodecError as exc:
            body["error"] = str(exc)
            s.add(
                LinkEvent(
                    vehicle_id=v.id,
                    kind="undecodable",
                    detail={"stream": spec.name, "error": str(exc)},
                    at=at,
                )
            )
            return [
                ("link", {"event": "undecodable", "vehicle": v.name, "stream": spec.name, "error": str(exc)})
            ]
        rows = []
        if span.lost:
            first, end = span.lost
            rows += [{"vehicle_id": v.id, "stream": spec.name, "tick": k, "time": k * spec.period, "values": [],
                      "certain": False} for k in range(first, end)]  # fmt: skip
        rows += [{"vehicle_id": v.id, "stream": spec.name, "tick": span.first_tick + i,
                  "time": (span.first_tick + i) * spec.period, "values": [round(float(x), 6) for x in values],
                  "certain": True} for i, values in enumerate(span.values)]  # fmt: skip
        s.execute(insert(Telemetry), rows)
        v.bytes_saved += max(0, span.values.size * 2 - packets.PACKET_SIZE)
        body.update(stream_name=spec.name, first_tick=span.first_tick, ticks=len(span.values),
                    lost=list(span.lost) if span.lost else None)  # fmt: skip
        return [("telemetry", {"vehicle": v.name, "stream": spec.name, "channels": list(spec.channels),
                               "first_time": span.first_tick * spec.period, "period": spec.period,
                               "values": [[round(float(x), 4) for x in row] for row in span.values],
                               "lost": list(span.lost) if span.lost else None})]  # fmt: skip
