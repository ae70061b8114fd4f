"""What happens to a frame from a vehicle, as a short pipeline over the domains: store the frame
(telemetry), drop duplicates (the link record's window), decode the packet, then by type: verify and
apply a check-point (``server.link.verify``, the commands' lifecycle), or decode a priority packet's
samples (``server.link.decoding``); then publish.

A frame is committed before anything about it is acknowledged to anyone or shown (events, API,
command status). Frames that arrive together are stored in one transaction (group commit) and their
events published after it; if the transaction fails, every vehicle's link state is put back
(``VehicleState.undo``). Nothing here raises on bad input from the water.

Restarts: each vehicle's link record and decoder states (``server.link.state``) are saved in a batch's
transaction, naming the last stored frame they include (``LinkRecord.frame``); at start they are loaded
and the vehicle's frames stored after that one are handed through the pipeline again (``replay``:
stored ids, nothing written) to rebuild what the saved state does not hold. So the state need not be
saved with every batch (serialising the decoder's chains was a fifth of the center's time): it is
saved every ``state_save_interval`` s, with a vehicle's first batch (the frame its replay starts
after), before a SYNC leaves (its counter only grows) and at shutdown (``save_states``). A crash loses
no state, only replay time: at most ``state_save_interval`` s of frames.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

from sqlalchemy import Engine
from sqlalchemy.exc import SQLAlchemyError

from server.commands import service as commands
from server.core.config import Settings
from server.core.db import Tx, now, reading, saved_id, writing
from server.core.events import Bus, Event, LinkNotice, PacketHeard, VehicleReported
from server.link import repository as link_repo
from server.link.batch import Batch, Replay
from server.link.decoding import decode
from server.link.state import RECENT_SEQS, IncomingFrame, VehicleState
from server.link.verify import Verifier
from server.telemetry import repository as telemetry
from server.telemetry.models import Frame, PacketTrust
from server.vehicles import keys
from server.vehicles import repository as vehicles
from server.vehicles.models import Vehicle
from tacit import auth, packets
from tacit.codec import PacketDecoder, StreamSpec, chain_ids
from tacit.link import from_frame
from tacit.navigation import Pose
from tacit.packets import CheckpointPacket, PacketError, Priority, PriorityPacket, Stream

log = logging.getLogger("tacit.server.ingest")


class Ingest:
    relayed = False  # frames come from the shore's own modem (a center's come from its gateways)

    def __init__(self, db: Engine, bus: Bus, streams: dict[Stream, StreamSpec], settings: Settings) -> None:
        self.db = db
        self.bus = bus
        self.streams = streams
        self.settings = settings
        self.strangers = {
            "kept": 0,
            "dropped": 0,
        }  # frames from unknown addresses stored / deleted since start
        self._stranger_floor = 0  # frame id: strangers' frames up to it are deleted already
        self.vehicles: dict[int, VehicleState] = {}  # by modem address; changed only under both locks
        # the modem addresses whose vehicles this process decodes: all, unless several center processes
        # share them (``own``); ``known``: every registered vehicle's, whoever decodes it
        self.mine: Callable[[int], bool] = lambda address: True
        self.known: list[int] = []
        self._lock = threading.Lock()  # held by a batch from its first frame to its commit
        self._roster = (
            threading.Lock()
        )  # held only while ``vehicles`` changes or is copied: never waits on the database
        self.stats = {
            "frames": 0,
            "packets": 0,
            "duplicates": 0,
            "rejected": 0,
            "unknown_vehicle": 0,
            "verified": 0,
            "forged": 0,
            "replayed": 0,
            "late": 0,
            "waited": 0,
            "unverifiable": 0,
            "old_protocol": 0,
        }
        self.verifier = Verifier(self.stats, settings.max_skew)
        self._unsaved: set[int] = set()  # addresses whose state changed since it was last saved
        self._fresh: set[int] = set()  # addresses with no saved state naming its last frame
        self._saved_at = time.monotonic()

    # --- the vehicles' link states ------------------------------------------------------------------

    def load_vehicles(self) -> None:
        """The vehicles from the database (those ``mine`` accepts); one new here gets its saved link state
        and decoders back."""
        with reading(self.db) as s:
            every = vehicles.every(s)
            rows = [v for v in every if self.mine(v.address)]
            with self._lock:
                fresh = {
                    v.address: self._resume(s, v)
                    for v in rows
                    if v.address not in self.vehicles or self.vehicles[v.address].id != v.id
                }
                with self._roster:
                    self.vehicles.update(fresh)
                    for address in set(self.vehicles) - {v.address for v in rows}:
                        self._forget(address)
                self.known = [v.address for v in every]
                self.strangers["kept"] = telemetry.count_strangers(s, self.known)

    def own(self, mine: Callable[[int], bool], taking: Callable[[int], bool] = lambda a: False) -> None:
        """Decode from now on the vehicles whose modem addresses ``mine`` accepts (a center process's
        partitions, ``server.backhaul.center``). Those it leaves are forgotten (``save_states`` first,
        unless another process may hold them already). Those ``taking`` accepts (taken over from another
        process; what this process held of them is stale) and those new here: read from the store, their
        saved states and the frames stored since replayed, as at start."""
        with self._lock, self._roster:
            for address in [a for a in self.vehicles if taking(a) or not mine(a)]:
                self._forget(address)
        self.mine = mine
        self.load_vehicles()

    def _forget(self, address: int) -> None:
        del self.vehicles[address]
        self._unsaved.discard(address)
        self._fresh.discard(address)

    def _resume(self, s: Tx, v: Vehicle) -> VehicleState:
        """A vehicle's state as the last run left it, and its last verified check-point (the pose the limits
        check against, and what the screens show with its age) instead of none until its next one."""
        decoder = PacketDecoder(list(self.streams.values()), v.protocol)
        state = VehicleState(v.id or 0, v.name, v.address, decoder, share=v.share, protocol=v.protocol)
        saved = link_repo.saved_state(s, state.id)
        if saved is not None:
            state.restore(saved)
        if state.link.frame is None:  # never saved, or saved with every batch (before frames were named)
            state.link.frame = telemetry.last_frame_id(s)
            self._fresh.add(state.address)
        else:
            self._replay(s, state)
        last = telemetry.checkpoints(s, state.id)
        if last:
            state.last_heard = last[0].at
            state.link.checkpoint = state.link.checkpoint or last[0].body
        return state

    def _replay(self, s: Tx, state: VehicleState) -> None:
        """The vehicle's frames stored after its saved state, through the pipeline again: its memory as it
        was after the last of them. A frame failing here is skipped, as it was when it came (it was
        stored undecoded, memory left as it was); counters keep counting from this start."""
        frames = telemetry.frames_from(s, state.address, state.link.frame or 0)
        replay = Replay(kept=telemetry.packets_of_frames(s, [saved_id(f) for f in frames]))
        stats = dict(self.stats)
        for row in frames:
            replay.current = saved_id(row)
            point = state.undo_point()
            try:
                self._apply(s, replay, state, stored_frame(row), replay.current)
            except Exception as exc:
                state.undo(point)
                log.warning("vehicle %s: stored frame %d not replayed: %s", state.name, replay.current, exc)
        self.stats.update(stats)
        state.frames = state.packets = state.duplicates = state.bytes_saved = state.forged = (
            state.verified
        ) = 0
        log.info("vehicle %s: %d frames after its saved state replayed", state.name, len(frames))

    def save_states(self, which: Callable[[int], bool] = lambda address: True) -> None:
        """Every vehicle's state (of those ``which`` accepts) this process changed and did not save (at
        shutdown: a restart then replays nothing). Only those: a process that only serves the API must
        not write its stale states over a center's. A database that fails here is logged, not raised:
        the next start replays."""
        if not any(which(a) for a in self._unsaved):
            return
        try:
            with self._lock, writing(self.db) as s:
                due = {a for a in self._unsaved if which(a)}
                self._save(s, due)
                s.commit()
                self._saved(due, set(), due == self._unsaved)
        except SQLAlchemyError as exc:
            log.warning("link states not saved (%s): the next start replays their frames", exc)

    def _save(self, s: Tx, addresses: set[int]) -> None:
        saving = [self.vehicles[a] for a in addresses & set(self.vehicles)]
        link_repo.save_states(s, {v.id: v.saved() for v in saving})

    def _saved(self, due: set[int], touched: set[int], full: bool) -> None:
        """After a commit: ``touched`` changed, ``due`` saved (all that changed when ``full``)."""
        self._unsaved = (self._unsaved | touched) - due
        self._fresh -= due
        self._saved_at = time.monotonic() if full else self._saved_at

    def next_sync(self, v: VehicleState, floor: int = 0) -> int:
        """The vehicle's next SYNC counter, at least ``floor``, saved before the SYNC leaves (a vehicle
        refuses a counter it has seen, across a shore restart too); under the batch lock, so no batch's
        undo takes it back."""
        with self._lock, writing(self.db) as s:
            v.link.sync_counter = max(v.link.sync_counter + 1, floor)
            link_repo.save_state(s, v.id, v.saved())
            s.commit()
            return v.link.sync_counter

    def states(self) -> list[VehicleState]:
        """The states of the vehicles this process decodes (a copy of the list, taken without waiting for a
        batch in progress)."""
        with self._roster:
            return [v for v in self.vehicles.values() if self.mine(v.address)]

    def pose(self, address: int) -> Pose | None:
        """The pose the vehicle at ``address`` last reported (None before its first check-point); of a
        vehicle another center process decodes, its last verified check-point's, from the store."""
        with self._roster:
            state = self.vehicles.get(address)
        if state is not None or self.mine(address):
            return state.pose() if state else None
        with reading(self.db) as s:
            vehicle = vehicles.by_address(s, address)
            last = telemetry.checkpoints(s, vehicle.id) if vehicle and vehicle.id else []
        return Pose.from_checkpoint(last[0].body) if last else None

    # --- the pipeline -------------------------------------------------------------------------------

    def handle(self, frame: IncomingFrame) -> list[Event]:
        """Store, decode and apply one received frame; returns the events published."""
        return self.handle_batch([frame])

    def handle_batch(self, frames: list[IncomingFrame]) -> list[Event]:
        """Frames that arrived together, in one transaction: nothing is published before the commit."""
        with self._lock:
            batch = {v.address: v for f in frames if (v := self.vehicles.get(f.src))}  # each vehicle once
            undo = {address: v.undo_point() for address, v in batch.items()}
            strangers = dict(self.strangers), self._stranger_floor
            try:
                events = self._commit(frames)
            except BaseException:
                for address, point in undo.items():
                    self.vehicles[address].undo(point)
                self.strangers, self._stranger_floor = strangers  # their deletion was rolled back too
                raise
            for event in events:  # after the commit: a failing subscriber must not set memory back
                self.bus.publish(event)
        return events

    def _commit(self, frames: list[IncomingFrame]) -> list[Event]:
        events: list[Event] = []
        with writing(self.db) as s:
            batch = self._open(s, frames)
            for frame in frames:
                events += self._frame(s, batch, frame)
            batch.flush(s)
            if self.strangers["kept"] > self.settings.stranger_frames_kept:
                self._drop_strangers(s)
            touched = {f.src for f in frames if f.src in self.vehicles}
            full = time.monotonic() - self._saved_at >= self.settings.state_save_interval
            due = self._unsaved | touched if full else touched & self._fresh  # fresh: where replays start
            self._save(s, due)  # in the same transaction as the packets it includes
            s.commit()
        self._saved(due, touched, full)
        return events

    def _open(self, s: Tx, frames: list[IncomingFrame]) -> Batch:
        """The batch's rows, ids reserved for as many frames and packets as ``frames`` can hold; its
        vehicles, and the states of the packets their check-points may vouch for, read in one query each."""
        batch = Batch.open(s, len(frames), sum(len(from_frame(f.data)) for f in frames))
        mine = {v.address: v for f in frames if (v := self.vehicles.get(f.src))}.values()
        batch.vehicles = vehicles.many(s, [v.id for v in mine])
        batch.read(s, sorted({i for v in mine for i in v.link.candidates()}))
        return batch

    def _frame(self, s: Tx, batch: Batch, frame: IncomingFrame) -> list[Event]:
        self.stats["frames"] += 1
        if not (0 <= frame.src <= 255 and 0 <= frame.dest <= 255 and 0 <= frame.rate <= 255):
            self.stats["rejected"] += 1  # the modem driver's parser bounds these; never trust it blindly
            log.warning("frame with impossible addresses or rate dropped")
            return []
        frame_id = batch.add_frame(frame_row(frame))
        self._stored(s, batch, frame, frame_id)
        v = self.vehicles.get(frame.src)
        if v is None:
            self.stats["unknown_vehicle"] += 1
            self.strangers["kept"] += 1
            batch.events.append(
                {
                    "vehicle_id": None,
                    "kind": "unknown_vehicle",
                    "at": frame.at,
                    "detail": {"address": frame.src},
                }
            )
            log.warning("frame from unknown modem address %d stored, not decoded", frame.src)
            return [LinkNotice(event="unknown_vehicle", detail={"address": frame.src})]
        return self._apply(s, batch, v, frame, frame_id)

    def _apply(
        self, s: Tx, batch: Batch, v: VehicleState, frame: IncomingFrame, frame_id: int
    ) -> list[Event]:
        """A stored frame from a known vehicle: its packets, in order. Only a frame that carried a packet
        heard for the first time whose tag or check-point MAC held moves when the vehicle was last heard
        and its shown SNRs (random bytes or a replay at a claimed SNR move nothing)."""
        v.frames += 1
        v.link.frame = frame_id
        events: list[Event] = []
        for chunk in from_frame(frame.data):
            events += self._packet(s, batch, v, frame_id, chunk, frame.at, frame.gateway)
        if frame_id not in batch.verified:  # not the vehicle's word: nothing says it was heard
            return events
        v.last_heard = frame.at if v.last_heard is None else max(v.last_heard, frame.at)  # late: not back
        v.snr_in, v.snr_out = _finite(frame.snr_in), _finite(frame.snr_out)
        heard = {"address": v.address, "snr_in": frame.snr_in, "snr_out": frame.snr_out}
        return [*events, LinkNotice(event="heard", vehicle=v.name, detail=heard)]

    def _stored(self, s: Tx, batch: Batch, frame: IncomingFrame, frame_id: int) -> None:
        """The frame's row is in the batch (a hook: the center records there which backhaul message it
        came from, ``server.backhaul.relay``)."""

    def _packet(
        self, s: Tx, batch: Batch, v: VehicleState, frame_id: int, chunk: bytes, at: float, gateway: str = ""
    ) -> list[Event]:
        if not v.link.seen.first_time(chunk):
            v.duplicates += 1
            self.stats["duplicates"] += 1
            log.info("vehicle %s: duplicate packet dropped (a retransmission)", v.name)
            return []
        try:
            packet = packets.decode(chunk)
            if isinstance(packet, packets.ControlPacket):
                raise PacketError("a control packet from a vehicle")
        except packets.OldVersion as exc:
            return self._old_version(batch, v, chunk, at, exc)
        except PacketError as exc:
            self.stats["rejected"] += 1
            batch.events.append(
                {
                    "vehicle_id": v.id,
                    "kind": "bad_packet",
                    "at": at,
                    "detail": {"error": str(exc), "hex": chunk.hex()},
                }
            )
            log.warning("vehicle %s: undecodable packet: %s", v.name, exc)
            return []
        self.stats["packets"] += 1
        v.packets += 1
        body = packets.as_dict(packet)
        kind, priority = packet.TYPE.name.lower(), int(getattr(packet, "priority", 0))
        row = {
            "frame_id": frame_id,
            "vehicle_id": v.id,
            "type": kind,
            "seq": packet.seq,
            "priority": priority,
            "body": body,
            "at": at,
        }
        if isinstance(packet, CheckpointPacket):
            trust, events = self._checkpoint(s, batch, v, packet, body)
            packet_id = batch.add_packet({**row, "auth": trust.value})
            if trust is PacketTrust.UNVERIFIABLE:  # the packets it covers may come late
                v.link.wait(packet_id, chunk, at)
        elif not self._tagged(s, batch, v, chunk):
            trust, (packet_id, events) = PacketTrust.FORGED, self._forged(s, batch, v, packet, row)
        else:
            trust, (packet_id, events) = PacketTrust.PENDING, self._priority(s, batch, v, packet, chunk, row)
            v.urgent = v.urgent or priority == Priority.TIME_SENSITIVE  # the MAC polls it sooner
        if trust in (PacketTrust.VERIFIED, PacketTrust.PENDING):  # its MAC, or its tag, held
            batch.verified.add(frame_id)
        log.info("vehicle %s: %s packet seq %d stored (%s)", v.name, kind, packet.seq, trust.value)
        heard = PacketHeard(
            id=packet_id,
            frame_id=frame_id,
            gateway=gateway or None,
            vehicle=v.name,
            address=v.address,
            type=kind,
            seq=packet.seq,
            priority=priority,
            size=len(chunk),
            snr=v.snr_in,
            body=body,
            auth=trust.value,
        )
        return [heard, *events]

    def _old_version(
        self, batch: Batch, v: VehicleState, chunk: bytes, at: float, exc: packets.PacketError
    ) -> list[Event]:
        """A packet of the previous protocol version: refused and counted; logged (and a ``bad_packet``
        event stored) once per vehicle, since an old agent sends nothing else until it is updated."""
        self.stats["rejected"] += 1
        return self._other_version(batch, v, chunk, at, exc)

    def _other_version(
        self, batch: Batch, v: VehicleState, chunk: bytes, at: float, exc: packets.PacketError
    ) -> list[Event]:
        """Counted, and logged (a ``bad_packet`` event stored) once per vehicle: a packet of version 2,
        or samples in another version than the vehicle's registered one (stored, not decoded: the
        agent's protocol and the registration must agree)."""
        self.stats["old_protocol"] += 1
        v.old_protocol += 1
        if v.old_protocol > 1:
            return []
        detail = {"error": str(exc), "hex": chunk.hex()}
        batch.events.append({"vehicle_id": v.id, "kind": "bad_packet", "at": at, "detail": detail})
        log.warning("vehicle %s: %s (logged once; GET /api/v1/link counts them)", v.name, exc)
        return [LinkNotice(event="bad_packet", vehicle=v.name, detail={"error": str(exc)})]

    def _drop_strangers(self, s: Tx) -> None:
        """Frames from unknown modem addresses are kept to the newest ``stranger_frames_kept`` (a stranger's modem
        must not fill the disk), with their ``unknown_vehicle`` events (one per frame)."""
        excess = self.strangers["kept"] - self.settings.stranger_frames_kept
        dropped = telemetry.drop_strangers(s, self.known, excess, self._stranger_floor)
        link_repo.drop_events(s, "unknown_vehicle", len(dropped))
        self._stranger_floor = max([self._stranger_floor, *dropped])
        self.strangers["kept"] -= len(dropped)
        self.strangers["dropped"] += len(dropped)

    def _checkpoint(
        self, s: Tx, batch: Batch, v: VehicleState, cp: CheckpointPacket, body: dict
    ) -> tuple[PacketTrust, list[Event]]:
        """Verify, then apply: the vehicle's state, its key's confirmation, its commands' statuses."""
        vehicle = batch.vehicle(s, v.id)
        verdict = self.verifier.checkpoint(
            batch, v, vehicle, cp, lambda: vehicles.every(s),
            lambda: batch.live and telemetry.checkpoint_stored(s, v.id, body),
        )  # fmt: skip
        if verdict.trust is not PacketTrust.VERIFIED:
            return verdict.trust, verdict.events
        if verdict.late:  # it vouches; the newer check-points set the state, the key and the commands
            v.link.remember(cp.mac)
            return PacketTrust.VERIFIED, self.verifier.vouch(s, batch, v, cp.seq, verdict.covered)
        v.link.accept(body, verdict.floor, cp.mac)
        v.link.echo = cp.mac if cp.unsynced else None  # answered at its next slot; none: synced
        events: list[Event] = [VehicleReported(vehicle=v.name, checkpoint=body)]
        events += self.verifier.vouch(s, batch, v, cp.seq, verdict.covered)
        if not batch.live:  # a replay: the key and the commands were stored when it came
            return PacketTrust.VERIFIED, events
        if vehicle.previous_key_hex and verdict.version == vehicle.key_version:
            events.append(self._key_confirmed(s, batch, v, vehicle.key_version))
        elif keys.pending(vehicle) and cp.holds_next_key != vehicle.next_key_held:
            events.append(self._next_key_held(s, batch, v, vehicle.key_version, cp.holds_next_key))
        return PacketTrust.VERIFIED, events + list(commands.apply_checkpoint(s, vehicle, cp, body))

    @staticmethod
    def _key_confirmed(s: Tx, batch: Batch, v: VehicleState, version: int) -> Event:
        vehicles.confirm_key(s, v.id)
        batch.events.append(
            {"vehicle_id": v.id, "kind": "key_confirmed", "at": now(), "detail": {"key_version": version}}
        )
        log.warning("vehicle %s: key version %d confirmed; commands are signed with it now", v.name, version)
        return LinkNotice(event="key_confirmed", vehicle=v.name, detail={"key_version": version})

    @staticmethod
    def _next_key_held(s: Tx, batch: Batch, v: VehicleState, version: int, held: bool) -> Event:
        """A check-point signed with the confirmed key says whether the vehicle holds the staged key:
        commands and SYNCs follow it (``server.vehicles.keys``)."""
        vehicles.hold_next_key(s, v.id, held)
        detail = {"key_version": version, "held": held}
        batch.events.append({"vehicle_id": v.id, "kind": "next_key_held", "at": now(), "detail": detail})
        log.warning(
            "vehicle %s: %s key version %d; commands and SYNCs are signed with version %d",
            v.name,
            "holds" if held else "does not hold",
            version,
            version if held else version - 1,
        )
        return LinkNotice(event="next_key_held", vehicle=v.name, detail=detail)

    @staticmethod
    def _tagged(s: Tx, batch: Batch, v: VehicleState, chunk: bytes) -> bool:
        vehicle = batch.vehicle(s, v.id)
        return auth.tag_matches(chunk, keys.accepted(vehicle), v.address)

    def _forged(
        self, s: Tx, batch: Batch, v: VehicleState, pp: PriorityPacket, row: dict
    ) -> tuple[int, list[Event]]:
        """A priority packet whose tag fails: stored as forged, never decoded (its state never enters the
        chain) and never a candidate for a check-point's MAC; its id and the events."""
        packet_id = batch.add_packet({**row, "auth": PacketTrust.FORGED.value})
        v.forged += 1
        self.stats["forged"] += 1
        detail = {"error": f"priority packet seq {pp.seq}: its tag does not match"}
        batch.events.append(
            {"vehicle_id": v.id, "kind": "forged_priority", "at": row["at"], "detail": detail}
        )
        log.warning("vehicle %s: forged priority packet ignored: %s", v.name, detail["error"])
        return packet_id, [LinkNotice(event="forged_priority", vehicle=v.name, detail=detail)]

    def _priority(
        self, s: Tx, batch: Batch, v: VehicleState, pp: PriorityPacket, chunk: bytes, row: dict
    ) -> tuple[int, list[Event]]:
        """Store and decode a priority packet: its id and the events."""
        packet_id = batch.add_packet(row)
        recent = v.link.recent.setdefault(pp.seq, [])
        recent[:] = [*recent[-3:], (auth.packet_hash(chunk), packet_id)]
        newest = _newest(v.link.recent, pp.seq)  # this one's, unless it came late
        while len(v.link.recent) > RECENT_SEQS:  # drop the seq furthest behind the newest
            del v.link.recent[max(v.link.recent, key=lambda q: (newest - q) % 256)]
        restart_every = self.settings.restart_min_interval / self.settings.time_scale
        late = v.last_heard is not None and row["at"] < v.last_heard  # heard before a frame stored already
        if pp.version != v.protocol:  # stored and taken as any priority packet, its samples not decoded
            error = PacketError(
                f"protocol version {pp.version}: {v.name} is registered as speaking version {v.protocol} "
                "(its agent's protocol and its registration must agree)"
            )
            events = self._other_version(batch, v, chunk, row["at"], error)
            row["body"].update({"error": str(error)})
            return packet_id, events
        decoded = decode(batch, v, pp, row["at"], packet_id, restart_every, late)
        row["body"].update(decoded.body)  # what decoding found (or why it could not)
        row["origin"] = decoded.origin
        window = v.decoder.coding.window and "error" not in decoded.body  # it may be what others wait for
        if (late or window) and v.link.waiting:
            return packet_id, decoded.events + self._unblocked(s, batch, v)
        return packet_id, decoded.events

    def _unblocked(self, s: Tx, batch: Batch, v: VehicleState) -> list[Event]:
        """The waiting packets a late one unblocked, taken again (until none more is): a priority packet
        whose base state is now held is decoded, a check-point whose covered packets have all come is
        verified (and applied, unless newer ones were)."""
        events: list[Event] = []
        ready = next((w for w in v.link.waiting if self._placeable(v, w[1], w[2])), None)
        while ready is not None:
            v.link.waiting.remove(ready)
            events += self._again(s, batch, v, *ready)
            ready = next((w for w in v.link.waiting if self._placeable(v, w[1], w[2])), None)
        return events

    @staticmethod
    def _placeable(v: VehicleState, data: bytes, at: float) -> bool:
        packet = packets.decode(data)
        if isinstance(packet, CheckpointPacket):
            return all(v.link.recent.get(q) for q in packet.covered_seqs())
        if not isinstance(packet, PriorityPacket):
            return False
        base = chain_ids(packet.payload, packet.seq)[0]
        named_once = v.decoder.coding.window  # version 4: a state held under its name is its packet's
        return base in v.decoder.snapshots and (named_once or v.link.made.get(base, -math.inf) <= at)

    def _again(
        self, s: Tx, batch: Batch, v: VehicleState, packet_id: int, data: bytes, at: float
    ) -> list[Event]:
        """A waiting packet, decoded or verified now; its stored row updated."""
        packet = packets.decode(data)
        self.stats["waited"] += 1
        log.info("vehicle %s: %s packet seq %d taken again: what it waited for came late",
                 v.name, packet.TYPE.name.lower(), packet.seq)  # fmt: skip
        if isinstance(packet, CheckpointPacket):
            trust, events = self._checkpoint(s, batch, v, packet, packets.as_dict(packet))
            batch.set_trust([packet_id], trust)
            return events
        assert isinstance(packet, PriorityPacket)
        restart_every = self.settings.restart_min_interval / self.settings.time_scale
        decoded = decode(batch, v, packet, at, packet_id, restart_every, late=True)
        batch.decoded(s, packet_id, decoded.body, decoded.origin)
        return decoded.events


def _newest(seqs: Iterable[int], seq: int) -> int:
    """Of packet seqs on the ring of 256 (``seq`` among them, none more than half the ring apart), the
    newest: the one furthest ahead of ``seq``."""
    return (seq + max(((q - seq) % 256 for q in seqs if (q - seq) % 256 < 128), default=0)) % 256


def frame_row(frame: IncomingFrame) -> dict[str, Any]:
    """A received frame's row in the ``frame`` table."""
    return {
        "direction": "in",
        "src": frame.src,
        "dest": frame.dest,
        "rate": frame.rate,
        "data": frame.data,
        "snr_in": _finite(frame.snr_in),
        "snr_out": _finite(frame.snr_out),
        "stats": frame.stats,
        "at": frame.at,
    }


def stored_frame(row: Frame) -> IncomingFrame:
    """A stored received frame as it came."""
    return IncomingFrame(row.src, row.dest, row.data, row.rate, row.snr_in, row.snr_out, row.stats, row.at)


def _finite(value: float | None) -> float | None:
    """An SNR as stored and used: None when unknown or not a number."""
    return value if value is not None and math.isfinite(value) else None
