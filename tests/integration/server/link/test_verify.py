"""Trust at sea, shore side, in process: forged check-points and priority packets change nothing,
genuine ones are verified when a check-point covers them, command statuses settle, and a restarted
shore decodes again (decoded values compared with what the vehicle measured, not row counts)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from sqlmodel import Session, delete, select

from server.commands.models import CommandRecord as Command
from server.core.config import Settings
from server.core.events import Bus as EventBus
from server.core.events import PacketHeard, PacketsSettled, TelemetryDecoded
from server.link import repository as link_repo
from server.link.ingest import Ingest
from server.link.models import LinkEvent, SavedLinkState
from server.link.state import IncomingFrame
from server.telemetry.models import Packet, Telemetry
from server.vehicles.models import Vehicle
from tacit import auth
from tacit.codec.format import MAX_WINDOW
from tacit.packets import (
    COVER_BITS,
    CheckpointPacket,
    CommandStatus,
    MissionState,
    Stream,
    cover_bitmap,
    pack_settled,
)
from tacit.streams import default_streams
from tests.support.shore import store_with
from vehicle_agent.compressor import Compressor

KEY = bytes(range(32))
STRANGER = bytes(32)
OTHER = bytes(range(32, 64))  # another registered vehicle's key
ADDRESS = 2
ENV = default_streams()[Stream.ENVIRONMENTAL]


class Vehicle_:
    """The vehicle's half, as the agent builds it: compressor, shared seq counter, signed check-points."""

    def __init__(self, key: bytes = KEY, warmer: float = 0.0) -> None:
        self.key, self.warmer = key, warmer
        self.compressor = Compressor(default_streams(), max_latency=5.0, max_silence=5.0)
        self.seq = 0
        self.t = math.floor(time.time()) - 300.0
        self.truth: dict[int, list[float]] = {}
        self.delivered: list[tuple[int, bytes]] = []

    def measure(self, seconds: int) -> None:
        for _ in range(seconds):
            self.t += 1.0
            values = [20.0 + self.warmer + 0.3 * math.sin(self.t / 7), 5.0 + self.t % 3, 8.0]
            self.truth[ENV.tick(self.t)] = values
            self.compressor.add(Stream.ENVIRONMENTAL, self.t, values)

    def priority(self, delivered: bool = True) -> bytes:
        ready = [p for p in self.compressor.ready(self.t + 100, self.seq) if p[0] is Stream.ENVIRONMENTAL]
        assert ready, "nothing ready"
        packet = auth.tag_priority(ready[0][1].packet, self.key, ADDRESS)
        self.compressor.resolve(self.seq, delivered)
        self.seq += 1
        if delivered:
            self.delivered.append((packet[1], packet))
        return packet

    def checkpoint(self, key: bytes | None = None, **fields: object) -> bytes:
        seq = self.seq
        self.seq += 1
        cp = CheckpointPacket(
            seq=seq % 256,
            time=int(time.time()),
            state=MissionState.PREPROGRAMMED,
            covered=cover_bitmap(seq % 256, [s for s, _ in self.delivered]),
            **fields,
        )  # type: ignore[arg-type]
        covered = [p for s, p in self.delivered if (seq - 1 - s) % 256 < 16]
        frame = auth.sign_checkpoint(cp, key or self.key, 1, ADDRESS, [auth.packet_hash(p) for p in covered])
        self.delivered = []
        return frame


@pytest.fixture
def shore(tmp_path: Path):
    commands = [
        Command(vehicle_id=1, seq=n, command="hold", frame=b"", status="acknowledged") for n in range(1, 8)
    ]
    db = store_with(tmp_path, Vehicle(name="rov1", address=ADDRESS, key_hex=KEY.hex(), next_seq=8), *commands)

    def start(settings: Settings | None = None) -> Ingest:
        ingest = Ingest(db, EventBus(), default_streams(), settings or Settings())
        ingest.load_vehicles()
        return ingest

    yield db, start
    db.dispose()


def send(ingest: Ingest, *packets: bytes) -> list[dict]:
    return ingest.handle(IncomingFrame(ADDRESS, 1, b"".join(packets)))


def rows(db, model, **where):
    with Session(db) as s:
        query = select(model)
        for name, value in where.items():
            query = query.where(getattr(model, name) == value)
        return s.exec(query).all()


def decoded_matches_truth(db, vehicle: Vehicle_) -> int:
    """How many stored, certain env rows are within eps of what the vehicle measured (all must be)."""
    good = 0
    for row in rows(db, Telemetry, stream="env", certain=True):
        truth = vehicle.truth[row.tick]
        assert np.all(np.abs(np.array(row.values) - truth) <= np.array(ENV.eps) + 1e-9), (
            row.tick,
            row.values,
        )
        good += 1
    return good


def test_priority_data_is_unverified_until_a_checkpoint_covers_it(shore) -> None:
    db, start = shore
    ingest, vehicle = start(), Vehicle_()
    vehicle.measure(10)
    send(ingest, vehicle.priority())
    vehicle.measure(10)
    send(ingest, vehicle.priority())
    assert {r.verified for r in rows(db, Telemetry)} == {False}
    assert {p.auth for p in rows(db, Packet, type="priority")} == {"pending"}
    send(ingest, vehicle.checkpoint())
    assert {r.verified for r in rows(db, Telemetry)} == {True}
    assert {p.auth for p in rows(db, Packet)} == {"verified"}
    assert decoded_matches_truth(db, vehicle) == 20


def test_forged_checkpoints_change_nothing(shore) -> None:
    db, start = shore
    ingest, vehicle = start(), Vehicle_()
    send(ingest, vehicle.checkpoint(north=10.0))
    forged = [
        vehicle.checkpoint(key=STRANGER, north=-3000.0, depth=300.0, battery=0.5, last_command=7,
                           command_status=CommandStatus.REFUSED),  # a stranger's key
        bytes([b ^ (1 if i == 10 else 0) for i, b in enumerate(vehicle.checkpoint(north=-3000.0))]),  # flipped
    ]  # fmt: skip
    for frame in forged:
        send(ingest, frame)
    assert ingest.vehicles[ADDRESS].link.checkpoint["north"] == 10.0
    assert {c.status for c in rows(db, Command)} == {"acknowledged"}
    assert [p.auth for p in rows(db, Packet)] == ["verified", "forged", "forged"]
    assert ingest.stats["verified"] == 1 and ingest.stats["forged"] == 2
    genuine = vehicle.checkpoint(north=20.0)
    send(ingest, genuine)
    send(ingest, vehicle.checkpoint(north=30.0))
    ingest.vehicles[ADDRESS].link.seen.recent.clear()  # the duplicate window forgot them
    send(ingest, genuine)  # the same bytes again: a replay
    older = CheckpointPacket(seq=99, time=int(time.time()) - 60, state=MissionState.PREPROGRAMMED, north=-1.0)
    send(ingest, auth.sign_checkpoint(older, KEY, 1, ADDRESS, []))  # genuine, never heard: late, not applied
    assert ingest.vehicles[ADDRESS].link.checkpoint["north"] == 30.0
    assert ingest.stats["replayed"] == 1 and ingest.stats["late"] == 1


def test_a_checkpoint_signed_with_another_vehicles_key_says_whose(shore) -> None:
    """Two agents' keys swapped by mistake: refused as forged like any bad MAC, applying nothing, and the
    link event names the vehicle whose key signed it; a stranger's key is named nowhere."""
    db, start = shore
    with Session(db) as s:
        s.add(Vehicle(name="rov2", address=ADDRESS + 1, key_hex=OTHER.hex()))
        s.commit()
    ingest, vehicle = start(), Vehicle_()
    send(ingest, vehicle.checkpoint(north=10.0))
    send(ingest, vehicle.checkpoint(key=OTHER, north=-3000.0, last_command=7))
    send(ingest, vehicle.checkpoint(key=STRANGER, north=-3000.0))
    assert ingest.vehicles[ADDRESS].link.checkpoint["north"] == 10.0
    assert {c.status for c in rows(db, Command)} == {"acknowledged"}
    assert [p.auth for p in rows(db, Packet)] == ["verified", "forged", "forged"]
    mixed_up, forged = (e.detail["error"] for e in rows(db, LinkEvent, kind="forged_checkpoint"))
    assert mixed_up.endswith(
        "signed with rov2's key, not rov1's: is rov1's agent configured with rov2's key?"
    ), mixed_up
    assert forged.endswith("check-point MAC does not match") and "rov2" not in forged, forged


def test_forged_priority_packet_with_a_genuine_seq_is_marked_forged(shore) -> None:
    db, start = shore
    ingest, vehicle, attacker = start(), Vehicle_(), Vehicle_(STRANGER, warmer=20.0)  # 40 C water
    attacker.t = vehicle.t
    vehicle.measure(10)
    attacker.measure(10)
    forged = attacker.priority()
    send(ingest, forged)  # the stranger's packet arrives first, with the seq the vehicle will use
    send(ingest, vehicle.priority())
    send(ingest, vehicle.checkpoint())
    by_bytes = {bytes.fromhex(p.body["payload"]): p.auth for p in rows(db, Packet, type="priority")}
    assert by_bytes[forged[3:]] == "forged"
    assert sorted(by_bytes.values()) == ["forged", "verified"]


def test_a_checkpoint_settles_the_commands_before_its_last(shore) -> None:
    db, start = shore
    ingest, vehicle = start(), Vehicle_()
    settled = pack_settled([CommandStatus.SUPERSEDED, CommandStatus.REFUSED, None, CommandStatus.EXECUTED])
    send(ingest, vehicle.checkpoint(last_command=7, command_status=CommandStatus.EXECUTING, settled=settled))
    statuses = {c.seq: c.status for c in rows(db, Command)}
    assert statuses == {
        1: "acknowledged",
        2: "acknowledged",
        3: "executed",
        4: "acknowledged",
        5: "refused",
        6: "superseded",
        7: "executing",
    }


def test_a_forged_packet_never_leaves_a_state_genuine_data_are_decoded_on(shore) -> None:
    """A stranger's packet (its own seq, not one the vehicle uses) fails its tag: it is forged at once and
    never decoded, so it leaves no decoder state a genuine packet could build on (in version 2 it did:
    the genuine data after it stayed unverified and the vehicle had to restart its chains)."""
    db, start = shore
    ingest, vehicle, attacker = start(), Vehicle_(), Vehicle_(STRANGER, warmer=20.0)
    attacker.t = vehicle.t
    vehicle.measure(10)
    attacker.measure(10)
    send(ingest, vehicle.priority())
    forged = attacker.priority()
    send(ingest, forged[:1] + bytes([200]) + forged[2:])  # a seq of its own: no collision with the vehicle
    vehicle.measure(10)
    send(ingest, vehicle.priority())
    send(ingest, vehicle.checkpoint())
    verified = rows(db, Telemetry, stream="env", verified=True)
    assert verified  # the first packet's data, decoded from the initial state, are vouched for
    for row in verified:  # and every row marked verified is what the vehicle measured
        assert np.all(np.abs(np.array(row.values) - vehicle.truth[row.tick]) <= np.array(ENV.eps) + 1e-9)
    assert {p.auth for p in rows(db, Packet, type="priority")} == {"verified", "forged"}
    assert decoded_matches_truth(db, vehicle) == len(verified) == 20  # all of it, verified
    assert not ingest.vehicles[ADDRESS].link.needs_restart


def test_a_settled_final_wins_over_superseding(shore) -> None:
    """6 was executing; the next check-point says 7 is executing and settles 6 as executed: the vehicle's
    word for 6 stands (superseding applies only to what it left unsettled)."""
    db, start = shore
    ingest, vehicle = start(), Vehicle_()
    send(ingest, vehicle.checkpoint(last_command=6, command_status=CommandStatus.EXECUTING))
    settled = pack_settled([CommandStatus.EXECUTED, None, None, None])
    send(ingest, vehicle.checkpoint(last_command=7, command_status=CommandStatus.EXECUTING, settled=settled))
    statuses = {c.seq: c.status for c in rows(db, Command)}
    assert statuses[6] == "executed" and statuses[7] == "executing"


def test_a_batch_that_fails_to_commit_leaves_memory_as_it_was(shore) -> None:
    """A commit that fails (here a trigger standing in for a full disk) puts back the duplicate window and
    the decoder: the retried frame is stored and decoded, not dropped as a duplicate."""
    db, start = shore
    ingest, vehicle = start(), Vehicle_()
    vehicle.measure(10)
    frame = vehicle.priority()
    with db.begin() as conn:
        conn.exec_driver_sql(
            "CREATE TRIGGER full BEFORE INSERT ON packet BEGIN SELECT RAISE(ABORT, 'disk full'); END"
        )
    with pytest.raises(Exception, match="disk full"):
        send(ingest, frame)
    with db.begin() as conn:
        conn.exec_driver_sql("DROP TRIGGER full")
    send(ingest, frame)
    assert len(rows(db, Packet, type="priority")) == 1 and decoded_matches_truth(db, vehicle) > 0


def test_a_failing_subscriber_does_not_set_memory_back_behind_the_database(shore) -> None:
    """Regression (review): an event subscriber that raised after the commit rolled the decoder back, so
    the next packet's base was unknown and the vehicle had to restart its chains."""
    db, start = shore
    ingest, vehicle = start(), Vehicle_()

    class Failing(EventBus):
        def publish(self, kind: str, **data: object) -> None:
            raise RuntimeError("subscriber failed")

    ingest.bus = Failing()
    vehicle.measure(10)
    with pytest.raises(RuntimeError, match="subscriber failed"):
        send(ingest, vehicle.priority())
    ingest.bus = EventBus()
    vehicle.measure(10)
    send(ingest, vehicle.priority())
    assert not ingest.vehicles[ADDRESS].link.needs_restart and decoded_matches_truth(db, vehicle) == 20


def test_a_restarted_shore_decodes_again(shore) -> None:
    db, start = shore
    ingest, vehicle = start(), Vehicle_()
    for _ in range(3):
        vehicle.measure(10)
        send(ingest, vehicle.priority())
    before = decoded_matches_truth(db, vehicle)
    ingest = start()  # SIGKILL and start again: nothing in memory survives, the database does
    vehicle.measure(10)
    send(ingest, vehicle.priority())
    assert decoded_matches_truth(db, vehicle) == before + 10
    send(ingest, vehicle.checkpoint())  # the hashes of the packets before the restart were saved too
    assert {r.verified for r in rows(db, Telemetry)} == {True}
    assert ingest.vehicles[ADDRESS].link.seen.first_time(b"x" * 32)


def saved_frame(db) -> int | None:
    """The last frame the vehicle's saved state includes (None: no state saved)."""
    with Session(db) as s:
        state = link_repo.saved_state(s, 1)
    return None if state is None else state["frame"]


def test_a_crash_between_state_saves_replays_the_frames_stored_after_the_saved_state(shore) -> None:
    """The state is saved with the vehicle's first batch, then every ``state_save_interval`` s: after a
    crash the frames stored after the saved state are handed through the pipeline again (nothing is
    stored twice), so a retransmission from before the crash is still a duplicate, the next packet
    decodes on the chain and a check-point verifies the packets heard before the crash."""
    db, start = shore
    hourly = Settings(state_save_interval=3600)
    ingest, vehicle = start(hourly), Vehicle_()
    for _ in range(4):
        vehicle.measure(10)
        send(ingest, vehicle.priority())
    assert saved_frame(db) == 1  # saved with its first batch only
    ingest = start(hourly)  # SIGKILL and start again
    assert ingest.vehicles[ADDRESS].link.frame == 4
    send(ingest, vehicle.delivered[-1][1])  # its ACK was lost: sent again
    assert len(rows(db, Packet, type="priority")) == 4
    vehicle.measure(10)
    send(ingest, vehicle.priority())
    assert not ingest.vehicles[ADDRESS].link.needs_restart
    assert decoded_matches_truth(db, vehicle) == 50 == len(rows(db, Telemetry))
    send(ingest, vehicle.checkpoint())
    assert {r.verified for r in rows(db, Telemetry)} == {True}
    assert ingest.stats["packets"] == 2 and ingest.stats["duplicates"] == 1  # replays are not counted


def test_the_state_is_saved_on_a_timer_and_at_shutdown(shore) -> None:
    db, start = shore
    ingest, vehicle = start(Settings(state_save_interval=0)), Vehicle_()
    for n in range(1, 3):
        vehicle.measure(10)
        send(ingest, vehicle.priority())
        assert saved_frame(db) == n  # an interval of 0: with every batch
    ingest = start(Settings(state_save_interval=3600))
    vehicle.measure(10)
    send(ingest, vehicle.priority())
    assert saved_frame(db) == 2
    ingest.save_states()  # at shutdown: a restart replays nothing
    assert saved_frame(db) == 3
    start(Settings(state_save_interval=3600)).save_states()  # one that heard nothing overwrites nothing
    with Session(db) as s:
        s.exec(delete(SavedLinkState))
        s.commit()
    start().save_states()
    assert saved_frame(db) is None


def test_a_shutdown_save_with_the_database_away_is_logged_not_raised(shore, caplog) -> None:
    db, start = shore
    ingest, vehicle = start(Settings(state_save_interval=3600)), Vehicle_()
    for _ in range(2):
        vehicle.measure(10)
        send(ingest, vehicle.priority())
    with db.begin() as conn:
        conn.exec_driver_sql("DROP TABLE linkstate")
    ingest.save_states()
    assert "the next start replays" in caplog.text


def test_packets_the_shore_never_stored_are_recovered_by_one_restart_request(shore) -> None:
    """The packets after one the shore never stored wait while it may still come (a version-4 vehicle's
    window: ``MAX_WINDOW`` seqs), then ask for a restart."""
    db, start = shore
    ingest, vehicle = start(), Vehicle_()
    vehicle.measure(10)
    send(ingest, vehicle.priority())
    vehicle.measure(10)
    vehicle.priority()  # ACKed by the shore's modem while the shore's software was down: never stored
    waited = 0
    while not ingest.vehicles[ADDRESS].link.needs_restart:  # the engine's next SYNC carries the request
        vehicle.measure(10)
        send(ingest, vehicle.priority())
        waited += 1
    assert waited == MAX_WINDOW + 1  # the first numbered more than MAX_WINDOW seqs after the missing one
    vehicle.compressor.restart_chains()  # what the agent does on that SYNC
    vehicle.measure(10)
    send(ingest, vehicle.priority())
    assert decoded_matches_truth(db, vehicle) == 20


def test_the_api_shows_what_is_verified(tmp_path: Path) -> None:
    from fastapi.testclient import TestClient

    from server.app import create_app
    from server.core.config import Settings

    app = create_app(
        Settings(
            database_url=f"sqlite:///{tmp_path}/tacit.db",
            map_enabled=False,
            read_tokens=["observer"],
            write_tokens=["operator"],
        )
    )
    with TestClient(app) as client:
        key = client.post(
            "/api/v1/vehicles",
            json={"name": "rov1", "address": ADDRESS},
            headers={"Authorization": "Bearer operator"},
        ).json()["key"]
        ingest, vehicle = app.state.shore.link.ingest, Vehicle_(bytes.fromhex(key))
        vehicle.measure(10)
        send(ingest, vehicle.priority())
        obs = {"Authorization": "Bearer observer"}
        assert {r["verified"] for r in client.get("/api/v1/telemetry", headers=obs).json()["items"]} == {
            False
        }
        assert client.get("/api/v1/packets", headers=obs).json()["items"][0]["auth"] == "pending"
        send(ingest, vehicle.checkpoint())
        assert {r["verified"] for r in client.get("/api/v1/telemetry", headers=obs).json()["items"]} == {True}
        assert {p["auth"] for p in client.get("/api/v1/packets", headers=obs).json()["items"]} == {"verified"}


def test_a_checkpoint_publishes_which_packets_it_settled(shore) -> None:
    """The screens turn packets and samples from pending to verified or forged live, on ``PacketsSettled``;
    every packet and sample names its packet id."""
    db, start = shore
    ingest, vehicle, attacker = start(), Vehicle_(), Vehicle_(STRANGER, warmer=20.0)
    attacker.t = vehicle.t
    vehicle.measure(10)
    attacker.measure(10)
    heard = send(ingest, attacker.priority()) + send(ingest, vehicle.priority())
    ids = [e.id for e in heard if isinstance(e, PacketHeard)]
    assert len(set(ids)) == 2 and {e.packet_id for e in heard if isinstance(e, TelemetryDecoded)} <= set(ids)
    [settled] = [e for e in send(ingest, vehicle.checkpoint()) if isinstance(e, PacketsSettled)]
    by_id = {p.id: p.auth for p in rows(db, Packet, type="priority")}
    assert settled.verified == settled.trusted == [i for i, a in by_id.items() if a == "verified"]
    # the stranger's twin failed its tag on arrival: forged then, so the check-point has none left to refuse
    assert settled.forged == [] and list(by_id.values()).count("forged") == 1
    assert settled.as_dict()["kind"] == "settled"


def test_a_packet_no_checkpoint_can_reach_any_more_is_unverifiable(shore) -> None:
    """The vehicle covers only packets whose ACK it heard: one the shore heard but whose ACK was lost is
    never vouched for. Once a verified check-point is COVER_BITS past it, it is unverifiable, not pending
    for ever (the screens would promise a verification that will never come)."""
    db, start = shore
    ingest, vehicle = start(), Vehicle_()
    vehicle.measure(10)
    send(ingest, vehicle.priority(delivered=False))  # heard here, its ACK lost at the vehicle
    [missed] = rows(db, Packet, type="priority")

    def settle_after(packets: int) -> PacketsSettled:
        for _ in range(packets):
            vehicle.measure(10)
            send(ingest, vehicle.priority())
        [settled] = [e for e in send(ingest, vehicle.checkpoint()) if isinstance(e, PacketsSettled)]
        return settled

    first = settle_after(3)  # still within the reach of a later check-point
    assert missed.id not in first.unverifiable and rows(db, Packet, id=missed.id)[0].auth == "pending"
    later = settle_after(COVER_BITS)
    assert later.unverifiable == [missed.id] and rows(db, Packet, id=missed.id)[0].auth == "unverifiable"
    assert {p.auth for p in rows(db, Packet, type="priority") if p.id != missed.id} == {"verified"}
