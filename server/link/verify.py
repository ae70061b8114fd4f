"""Trust in what a vehicle sends (``tacit.auth``): a check-point is applied only if its MAC holds under
one of the vehicle's keys and it is not a replay (its MAC among the last accepted, or its bytes stored
before); otherwise it is stored as forged, replayed or unverifiable with a link event, and nothing
else changes. One stamped below the replay floor whose bytes were never stored is *late*, not a replay:
it came after newer ones (through a gateway behind a backhaul outage), so it is verified and vouches for
the packets it covers, but it is not applied (the vehicle's state, clock, key and commands stay as the
newer ones left them). A replay by an attacker is the same bytes again, refused by its MAC or the store;
a genuine check-point the shore never got, sent again by someone, is late: it can only vouch. The floor
follows the shore's clock as much as the vehicle's (``raised_floor``): a clock that was wrong once must
not lock the vehicle's reports out for as long as it was wrong. A verified check-point vouches for
the priority packets it covers: their rows become verified, and another packet received with one of
their seqs is forged. A vouched-for packet's data are trusted only along a chain of trusted packets:
the MAC covers a packet's bytes, not the decoder state it was decoded on.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from server.core.db import Tx, now
from server.core.events import Event, LinkNotice, PacketsSettled
from server.link.batch import Batch
from server.link.state import VehicleState
from server.telemetry.models import PacketTrust
from server.vehicles import keys
from server.vehicles.models import Vehicle
from tacit import auth
from tacit.packets import COVER_BITS, CheckpointPacket

log = logging.getLogger("tacit.server.ingest")


@dataclass
class Verdict:
    """What verifying a check-point found: its trust, the events, the key version that signed it and the
    (seq, hash) of each priority packet it vouches for."""

    trust: PacketTrust
    events: list[Event] = field(default_factory=list)
    version: int | None = None
    covered: list[tuple[int, bytes]] = field(default_factory=list)
    floor: int = 0  # the replay floor once it is applied
    late: bool = False  # stamped below the replay floor, never stored: verified, not applied


def current_floor(floor: int, shore_now: float, max_skew: float) -> int:
    """The replay floor a check-point is held to now. ``raised_floor`` never lifts it beyond the shore's
    time plus ``max_skew``, so a floor further ahead was raised while the shore's own clock was ahead (a
    synced vehicle follows the shore's SYNCs): with that clock set right, it comes back to ``max_skew``
    behind it, and the vehicle is heard again at once instead of an hour later. A check-point recorded
    while the clock was ahead and replayed now is still refused by its MAC (the last accepted are kept)."""
    return floor if floor <= shore_now + max_skew else int(shore_now - max_skew)


class KeyMixUp(auth.BadMac):
    """A check-point signed with another registered vehicle's key: a configuration mistake (two agents'
    keys swapped, a key copied to the wrong vehicle), refused all the same."""


def signs(
    vehicle: Vehicle, cp: CheckpointPacket, address: int, candidates: Sequence[Sequence[bytes]]
) -> bool:
    """Whether one of ``vehicle``'s keys signed ``cp`` (sent from ``address``)."""
    try:
        auth.verify_checkpoint(cp, keys.accepted(vehicle), address, candidates)
    except (auth.BadMac, auth.Unverifiable):
        return False
    return True


def raised_floor(cp: CheckpointPacket, floor: int, shore_now: float, max_skew: float) -> int:
    """The replay floor after a verified check-point: an unsynced vehicle's time never raises it (its
    clock is unknown), and a synced one stamped more than ``max_skew`` ahead of the shore raises it only
    to the shore's time (so the check-points after its clock is corrected are not "older than the last")."""
    if cp.unsynced:
        return floor
    return max(floor, cp.time if cp.time <= shore_now + max_skew else int(shore_now))


class Verifier:
    def __init__(self, stats: dict[str, int], max_skew: float) -> None:
        self.stats = stats
        self.max_skew = max_skew  # Settings.max_skew

    def checkpoint(
        self,
        batch: Batch,
        v: VehicleState,
        vehicle: Vehicle,
        cp: CheckpointPacket,
        others: Callable[[], Sequence[Vehicle]],
        stored: Callable[[], bool] = lambda: False,
    ) -> Verdict:
        """Verify a check-point (nothing is applied here, but the challenge of an unsynced one stamped
        below the floor, which is answered all the same: a vehicle whose lost state held a large clock
        offset would otherwise never be heard again, and a SYNC echoing an old MAC answers nothing).
        ``others``: the registered vehicles, read only when the MAC fails, to tell a key configured on
        the wrong vehicle (two agents' keys swapped) from a forgery. ``stored``: whether its bytes were
        stored before, asked only of one stamped below the floor (late, or a replay)."""
        seqs = cp.covered_seqs()
        candidates = [[h for h, _ in v.link.recent.get(seq, [])] for seq in seqs]
        try:
            version, chosen = auth.verify_checkpoint(cp, keys.accepted(vehicle), v.address, candidates)
        except auth.Unverifiable as exc:
            return self._refused(batch, v, PacketTrust.UNVERIFIABLE, cp, exc)
        except auth.BadMac as exc:
            owner = next(
                (o.name for o in others() if o.id != vehicle.id and signs(o, cp, v.address, candidates)), None
            )
            why = (
                exc
                if owner is None
                else KeyMixUp(
                    f"signed with {owner}'s key, not {v.name}'s: is {v.name}'s agent configured with {owner}'s key?"
                )
            )
            return self._refused(batch, v, PacketTrust.FORGED, cp, why)
        if cp.mac in v.link.accepted_macs:
            return self._refused(batch, v, PacketTrust.REPLAYED, cp, ValueError("accepted before"))
        shore_now = time.time()
        floor = current_floor(v.link.checkpoint_time, shore_now, self.max_skew)
        late = cp.time < floor
        if late:
            v.link.echo = cp.mac if cp.unsynced else v.link.echo
            if stored():
                return self._refused(
                    batch,
                    v,
                    PacketTrust.REPLAYED,
                    cp,
                    ValueError("older than the replay floor, stored before"),
                )
            self.stats["late"] += 1
            log.warning(
                "vehicle %s: check-point seq %d stamped %d s before the last came late: verified, its "
                "packets vouched for, the vehicle's state left as the newer one set it",
                *(v.name, cp.seq, v.link.checkpoint_time - cp.time),
            )
        v.verified += 1
        self.stats["verified"] += 1
        floor = floor if late else raised_floor(cp, floor, shore_now, self.max_skew)
        covered = list(zip(seqs, chosen, strict=True))
        return Verdict(PacketTrust.VERIFIED, version=version, covered=covered, floor=floor, late=late)

    def _refused(
        self, batch: Batch, v: VehicleState, trust: PacketTrust, cp: CheckpointPacket, why: Exception
    ) -> Verdict:
        detail = f"check-point seq {cp.seq}: {why}"
        kind = f"{trust.value}_checkpoint"
        v.forged += trust is not PacketTrust.UNVERIFIABLE
        self.stats[trust.value] += 1
        batch.events.append(
            {
                "vehicle_id": v.id,
                "kind": kind,
                "at": now(),
                "detail": {"error": detail, "hex": cp.encode().hex()},
            }
        )
        log.warning("vehicle %s: %s check-point ignored: %s", v.name, trust.value, detail)
        return Verdict(trust, [LinkNotice(event=kind, vehicle=v.name, detail={"error": detail})])

    def vouch(
        self, s: Tx, batch: Batch, v: VehicleState, seq: int, covered: list[tuple[int, bytes]]
    ) -> list[Event]:
        """The ``covered`` packets (seq, hash) of check-point ``seq`` are verified; another packet received
        with one of their seqs is forged; a pending one no later check-point can reach is unverifiable."""
        good: list[int] = []
        bad: list[int] = []
        for covered_seq, digest in covered:
            for h, packet_id in v.link.recent.get(covered_seq, []):
                (good if h == digest else bad).append(packet_id)
            v.link.recent[covered_seq] = [
                (h, pid) for h, pid in v.link.recent.get(covered_seq, []) if h == digest
            ]
        reach = _out_of_reach(v, seq)
        states = batch.packet_states(s, [*good, *reach])  # one query for both
        batch.set_trust(good, PacketTrust.VERIFIED)
        lost = [i for i in reach if i not in good and states.get(i, {}).get("auth") == PacketTrust.PENDING]
        batch.set_trust(lost, PacketTrust.UNVERIFIABLE)  # pending, and no check-point can reach them now
        trusted = self._trusted(s, batch, {i: states[i] for i in good if i in states})
        batch.trust_data(trusted)
        if len(trusted) < len(good) and not v.link.needs_restart:
            v.link.needs_restart = True  # its chain ran through a packet nobody vouched for: start clean
            log.warning(
                "vehicle %s: %d genuine packet(s) were decoded on a state no check-point vouched "
                "for, or could not be decoded on it: their data stay unverified; asking for a "
                "chain restart",
                v.name,
                len(good) - len(trusted),
            )
        if bad:
            batch.set_trust(bad, PacketTrust.FORGED)
            self.stats["forged"] += len(bad)
            log.warning(
                "vehicle %s: %d priority packet(s) not the ones the check-point vouched for: forged",
                v.name,
                len(bad),
            )
        return [PacketsSettled(vehicle=v.name, verified=good, forged=bad, trusted=trusted, unverifiable=lost)]

    @staticmethod
    def _trusted(s: Tx, batch: Batch, rows: dict[int, dict]) -> list[int]:
        """Of packets whose bytes a check-point just vouched for, those whose data can be trusted too: a
        packet's data are trusted only if the packet its state came from (its origin) was trusted as
        well. A forged packet slipped into the chain leaves what was decoded after it untrusted. A genuine
        packet that could not be decoded (its state was a forged one's, read as garbage) is not trusted
        either: the shore's chain is broken there, and the vehicle must restart it."""
        origins = {row["origin"] for row in rows.values()} - set(rows) - {None}
        earlier = batch.packet_states(s, sorted(i for i in origins if i is not None))
        trusted: list[int] = []
        waiting = sorted(i for i in rows if not rows[i]["body"].get("error"))
        while True:  # in passes: an origin that came late was stored after the packet decoded on it
            on = {i: rows[i]["origin"] for i in waiting}
            more = [i for i, o in on.items() if o is None or o in trusted or _was_trusted(earlier.get(o))]
            if not more:
                return trusted
            trusted += more
            waiting = [i for i in waiting if i not in more]


def _out_of_reach(v: VehicleState, seq: int) -> list[int]:
    """The packets (ids) heard at seqs that no check-point after ``seq`` can cover (``COVER_BITS`` behind
    it, at most half the ring: the rest are ahead), forgotten from the candidates. The vehicle covers only
    packets whose ACK it heard; one the shore heard but whose ACK was lost stays pending here forever
    otherwise, and the screens would say "pending" of a packet nothing will ever verify."""
    behind = [q for q in v.link.recent if COVER_BITS <= (seq - q) % 256 < 128]
    return [packet_id for q in behind for _, packet_id in v.link.recent.pop(q)]


def _was_trusted(state: dict | None) -> bool:
    return state is not None and state["auth"] == PacketTrust.VERIFIED and bool(state["trusted"])
