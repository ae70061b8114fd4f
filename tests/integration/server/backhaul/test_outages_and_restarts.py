"""The backhaul across outages and restarts (issue 24, item 3), integration tier: a real nats-server, real
signed packets from the vehicle's compressor, the center's store on SQLite.

A vehicle heard by two gateways, one of them cut off while the vehicle moves into its water and back:
on reconnection every frame is stored once, every check-point verified (late ones as late, none refused
as a replay), every priority packet decoded, and the shown pose never goes back. A fresh center starts
from the gateways' current events, a restarted one from its ack floor.
"""

from __future__ import annotations

import asyncio
import json
import math
import threading
import time
from collections.abc import Awaitable, Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import create_engine, text
from sqlmodel import Session

from gateway.slots import SlotPlan
from gateway.timing import Timing
from server.backhaul import broker as broker_client
from server.backhaul import subjects
from server.backhaul.audit import audit
from server.backhaul.center import Center
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.subjects import EventMessage
from server.core.db import make_engine, migrate, reading
from server.telemetry import repository as telemetry
from server.telemetry.models import Frame
from server.vehicles.models import Vehicle
from tacit import auth
from tacit.packets import CheckpointPacket, MissionState, Stream, cover_bitmap
from tacit.streams import default_streams
from tests.integration.server.backhaul.test_frames_and_commands import ingest_on, until
from tests.support.nats import NATS_SERVER, NatsServer
from vehicle_agent.compressor import Compressor

pytestmark = pytest.mark.skipif(not Path(NATS_SERVER).exists(), reason="nats-server is not installed")

KEY = bytes(range(32))
ADDRESS = 2
ENV = default_streams()[Stream.ENVIRONMENTAL]


class Rov:
    """The vehicle's half, as the agent builds it: the compressor's chained priority packets (each based
    on the last one a gateway ACKed), check-points covering those delivered since the last, stamped on
    the vehicle's clock (``t``, which each frame also carries as when it was heard)."""

    def __init__(self) -> None:
        self.compressor = Compressor(default_streams(), max_latency=5.0, max_silence=5.0)
        self.seq = 0
        self.t = math.floor(time.time()) - 300.0
        self.truth: dict[int, list[float]] = {}
        self.delivered: list[tuple[int, bytes]] = []
        self.checkpoint_times: list[int] = []

    def priority(self) -> bytes:
        for _ in range(8):
            self.t += 1.0
            values = [20.0 + 0.3 * math.sin(self.t / 7), 5.0 + self.t % 3, 8.0]
            self.truth[ENV.tick(self.t)] = values
            self.compressor.add(Stream.ENVIRONMENTAL, self.t, values)
        ready = [p for p in self.compressor.ready(self.t + 100, self.seq) if p[0] is Stream.ENVIRONMENTAL]
        packet = auth.tag_priority(ready[0][1].packet, KEY, ADDRESS)
        self.compressor.resolve(self.seq, True)  # a gateway's modem ACKed it
        self.delivered.append((self.seq, packet))
        self.seq += 1
        return packet

    def checkpoint(self) -> bytes:
        self.t += 1.0
        seq, self.seq = self.seq, self.seq + 1
        covered = [q for q, _ in self.delivered]
        cp = CheckpointPacket(seq=seq, time=int(self.t), state=MissionState.PREPROGRAMMED,
                              north=float(seq), covered=cover_bitmap(seq, covered))  # fmt: skip
        frame = auth.sign_checkpoint(cp, KEY, 1, ADDRESS, [auth.packet_hash(p) for _, p in self.delivered])
        self.delivered = []
        self.checkpoint_times.append(int(self.t))
        return frame


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request: pytest.FixtureRequest, sqlite_url: str) -> Iterator[str]:
    """The center's store: a SQLite file, or a fresh database on the machine's PostgreSQL."""
    if request.param == "sqlite":
        yield sqlite_url
        return
    from launch.split import throwaway_database

    with throwaway_database(request.getfixturevalue("postgres_server")) as url:
        migrate(url)
        yield url


def test_a_vehicle_heard_through_a_gateway_behind_an_outage_is_stored_verified_and_decoded_once(
    broker: NatsServer, store_url: str, tmp_path: Path
) -> None:
    """The ship is cut off; the vehicle goes on reporting through both, then into the ship's water only
    (its packets there chain the ones after), then back to the buoy. The buoy's frames come first, the
    ship's backlog after: its check-points are late (verified, not applied), the buoy's packets that
    waited for the ship's are decoded and verified once they come."""
    db = make_engine(store_url)
    with Session(db) as s:
        s.add(Vehicle(name="rov1", address=ADDRESS, key_hex=KEY.hex(), next_seq=1))
        s.commit()
    rov = Rov()
    plan = [  # (packet, who hears it): the ship is cut off after the third
        ("p", "both"), ("p", "both"), ("cp", "both"),
        ("p", "both"), ("p", "ship"), ("cp", "ship"), ("p", "ship"),  # the ship cut off; into its water
        ("p", "buoy"), ("cp", "buoy"), ("p", "buoy"), ("cp", "buoy"),  # back: they chain the ship's
    ]  # fmt: skip
    after = ("cp", "both")  # once the ship is back

    async def main() -> list[tuple[int, int]]:
        outboxes = {name: Outbox(tmp_path / f"{name}.db", name) for name in ("ship", "buoy")}
        gateways = {name: Gateway(outbox, broker.url) for name, outbox in outboxes.items()}
        center = Center(ingest_on(store_url), broker.url, batch=4)
        for g in gateways.values():
            await g.start()
        await center.connect()
        shown: list[tuple[int, int]] = []  # (in memory, in the store) after every batch

        def hear(kind: str, who: str) -> None:
            data = rov.priority() if kind == "p" else rov.checkpoint()
            for name in ("ship", "buoy") if who == "both" else (who,):
                outboxes[name].add_frame(ADDRESS, 0, data, snr_in=10.0, at=rov.t)

        async def consume(n: int) -> None:
            async def step() -> None:
                await center.step(timeout=0.3)
                shown.append(pose(center, db))

            await until(lambda: center.counters["messages"] >= n, step, timeout=20)

        try:
            for i, (kind, who) in enumerate(plan):
                if i == 3:  # the ship's backhaul is cut: its modem goes on hearing
                    await until(lambda: outboxes["ship"].depth() == 0, lambda: asyncio.sleep(0.05))
                    await gateways["ship"].stop()
                hear(kind, who)
            await consume(3 * 2 + 5)  # before the cut both copies, after it the buoy's five
            assert outboxes["ship"].depth() == 4
            gateways["ship"] = Gateway(outboxes["ship"], broker.url)  # reconnected
            await gateways["ship"].start()
            hear(*after)
            await consume(3 * 2 + 5 + 4 + 2)
        finally:
            await center.close()
            for g in gateways.values():
                await g.stop()
        assert center.ingest.stats["replayed"] == 0 and center.ingest.stats["late"] == 2
        assert center.ingest.stats["waited"] == 3  # the buoy's two packets and check-point after the move
        return shown

    shown = asyncio.run(main())
    with create_engine(store_url).connect() as c:
        assert c.execute(text("SELECT count(*) FROM frame")).scalar_one() == len(plan) + 1  # once each
        rows = c.execute(text("SELECT type, auth, body FROM packet ORDER BY id")).all()
    assert [r.type for r in rows].count("checkpoint") == 5 and len(rows) == len(plan) + 1
    assert {r.auth for r in rows} == {"verified"}  # every check-point, every packet vouched for
    assert not [r for r in rows if r.type == "priority" and "error" in _body(r.body)]  # all decoded
    assert decoded_within_eps(store_url, rov) > 0
    newest = rov.checkpoint_times[-1]
    assert shown[-1] == (newest, newest)
    assert all(a[0] <= b[0] and a[1] <= b[1] for a, b in zip(shown, shown[1:], strict=False))  # never back

    files = [tmp_path / "ship.db", tmp_path / "buoy.db"]
    counts = {c.gateway: c for c in audit(files, store_url)}  # heard, stored, merged, decoded, missing
    assert [(c.heard, c.published, c.stored, c.merged, c.decoded, c.missing) for c in counts.values()] == [
        (9, 9, 9, 5, 9, []),  # the buoy: four before and during the cut, four after the move, the last
        (8, 8, 8, 5, 8, []),  # the ship: three before, four behind the cut, the last
    ]
    buoy = Outbox(tmp_path / "buoy.db", "buoy")  # a frame it published that the center never stored
    lost = buoy.add_frame(ADDRESS, 0, b"never stored", at=time.time())
    buoy.mark_published(buoy.pending()[0].seq)
    again = audit(files, store_url)[0]
    assert again.missing == [lost] and "HEARD BUT NOT STORED: 1" in again.line()


def test_a_frame_that_only_resent_stored_packets_is_counted_as_resent(sqlite_url: str) -> None:
    """The audit tells a retransmission (the vehicle missed the ACK and sent the same packets again: the
    decoder drops them as duplicates) from a frame that was not decoded."""
    x, y = bytes(32), bytes(range(32))
    frames = [(2, x), (2, x), (2, x + y), (3, x), (2, y + x)]  # resent, new y, another vehicle, resent
    with Session(make_engine(sqlite_url)) as s:
        rows = [Frame(direction="in", src=src, dest=1, data=data) for src, data in frames]
        s.add_all(rows)
        s.commit()
        ids = [row.id for row in rows]
        assert telemetry.resent_frames(s, ids) == {ids[1], ids[4]}


def pose(center: Center, db: object) -> tuple[int, int]:
    """The vehicle's shown check-point time: the center's memory, and the store's latest (the screens)."""
    state = center.ingest.vehicles[ADDRESS]
    with reading(db) as s:  # type: ignore[arg-type]
        stored = telemetry.checkpoints(s, state.id, 1)
    memory = int(state.link.checkpoint["time"]) if state.link.checkpoint else 0
    return memory, int(stored[0].body["time"]) if stored else 0


def _body(body: object) -> dict:
    return json.loads(body) if isinstance(body, str) else dict(body)  # type: ignore[call-overload]


def decoded_within_eps(url: str, rov: Rov) -> int:
    """How many certain env samples were decoded; each within eps of what the vehicle measured."""
    with create_engine(url).connect() as c:
        query = text("SELECT tick, \"values\" FROM telemetry WHERE stream = 'env' AND certain")
        samples = c.execute(query).all()
    for tick, values in samples:
        got = np.array(json.loads(values) if isinstance(values, str) else values, dtype=float)
        assert np.all(np.abs(got - rov.truth[tick]) <= np.array(ENV.eps) + 1e-9), (tick, got)
    return len(samples)


def test_a_fresh_center_starts_from_current_events_and_a_restarted_one_from_its_ack_floor(
    broker: NatsServer, sqlite_url: str
) -> None:
    """Events the stream keeps from before a fresh center are not applied (an old attempt report, an old
    incarnation's heartbeat); a restarted center gets what came while it was away, and a stale heartbeat
    among them neither makes the gateway up nor holds its name against the current incarnation."""

    def beat(incarnation: str, at: float) -> EventMessage:
        return EventMessage(f"ship-beat-{incarnation}-{at:.3f}", "ship", "heartbeat", at,
                            {"incarnation": incarnation, "backhaul": "up", "outbox": 0})  # fmt: skip

    async def main() -> None:
        nc = await broker_client.connect(broker.url, "test")
        js = nc.jetstream()
        await broker_client.ensure_streams(js)

        async def publish(*events: EventMessage) -> None:
            for e in events:
                await js.publish(subjects.events("ship"), e.encode(), headers={subjects.MSG_ID: e.id})

        report = EventMessage("ship-aaaa-1", "ship", "attempt", time.time(),
                              {"command": "cmd-1-1", "outcome": "acked", "final": True})  # fmt: skip
        await publish(beat("aaaa", time.time()), report)  # the day before, say
        await asyncio.sleep(1.5)
        current = beat("bbbb", time.time())
        await publish(current)
        seen: list[str] = []

        async def on_event(event: EventMessage) -> None:
            seen.append(event.id)

        center = Center(ingest_on(sqlite_url), broker.url, events_since=1.0)
        center.on_event = on_event
        await center.connect()
        try:
            await until(lambda: bool(seen), center.step_events)
            for _ in range(3):
                await center.step_events(timeout=0.2)
            assert seen == [current.id]  # neither the old report nor the old heartbeat
            assert center.guard.up("ship", time.time()) and center.gateways["ship"]["incarnation"] == "bbbb"
        finally:
            await center.close()
        away = [beat("aaaa", time.time() - 60), beat("bbbb", time.time())]  # a stale one, then the current
        await publish(*away)
        again = Center(ingest_on(sqlite_url), broker.url, events_since=1.0)
        again.on_event = on_event
        await again.connect()
        try:
            await until(lambda: len(seen) == 3, again.step_events)
            assert seen[1:] == [e.id for e in away]  # from its ack floor
            assert again.guard.refused["twice"] == 0 and again.guard.announced["ship"].incarnation == "bbbb"
            assert again.gateways["ship"]["incarnation"] == "bbbb"
        finally:
            await again.close()
            await nc.close()

    asyncio.run(main())


class Loop:
    """An event loop in a thread of its own: the simulator and the gateways outlive a center's app."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def call(self, work: Callable[[], Awaitable[object]]) -> object:
        return asyncio.run_coroutine_threadsafe(_awaited(work), self.loop).result(timeout=30)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout=10)


async def _awaited(work: Callable[[], Awaitable[object]]) -> object:
    return await work()


def test_a_restarted_center_hands_out_slots_no_gateway_collides_with(
    broker: NatsServer, tmp_path: Path, postgres_server: str
) -> None:
    """Two gateways on simulated modems 1.2 km apart follow the first center's plan. The center is
    restarted while the buoy is away (its gateway restarting): the new center must not hand the ship a
    plan of its own while the buoy, back, follows the old one it finds kept for it. No collision."""
    from fastapi.testclient import TestClient

    from launch.split import throwaway_database as postgres_database
    from server.app import create_app
    from server.backhaul.center import serve
    from server.backhaul.relay import RelayIngest
    from simulators.run import ModemSpec, SimConfig, SimWorld
    from tacit import modem as mm
    from tests.integration.server.routing.test_choice import OP, settings

    config = SimConfig(
        time_scale=4.0,
        channel={"fading_sigma_db": 0.0},
        modems=[ModemSpec(1, "ship", (-600.0, 0.0, 1.0)), ModemSpec(5, "buoy", (600.0, 0.0, 1.0)),
                ModemSpec(2, "rov1", (-300.0, 0.0, 5.0)), ModemSpec(3, "rov2", (300.0, 0.0, 5.0))],
    )  # fmt: skip
    world, loop = SimWorld(config), Loop()
    addresses = {"ship": 1, "buoy": 5}
    outboxes = {name: Outbox(tmp_path / f"{name}.db", name) for name in addresses}

    def gateway(name: str) -> Gateway:
        pty = next(m["pty"] for m in world.describe()["modems"] if m["name"] == name)
        driver = mm.ModemDriver(mm.DriverSettings(url=pty, address=addresses[name], keepalive=10.0))
        g = Gateway(
            outboxes[name], broker.url, driver, heartbeat=0.2, timing=Timing(time_scale=config.time_scale)
        )
        loop.call(g.start)
        until_sync(lambda: driver.state is mm.LinkState.READY, "the modem")
        return g

    with postgres_database(postgres_server) as url:
        values = settings(url, tdma_slot=3.0, tdma_guard=0.3, gateway_timeout=14.0)

        def center() -> TestClient:
            return TestClient(create_app(values, RelayIngest, [lambda shore: serve(shore, broker.url)]))

        loop.call(world.start)
        gateways = {name: gateway(name) for name in addresses}
        try:
            with center() as client:
                for name, address in (("rov1", 2), ("rov2", 3)):
                    client.post("/api/v1/vehicles", json={"name": name, "address": address}, headers=OP)
                until_sync(lambda: all(_follows(g, ("buoy", "ship")) for g in gateways.values()), "a plan")
            kept = gateways["buoy"].schedule.plan(time.time())  # the plan the stream keeps for the buoy
            assert kept is not None
            loop.call(gateways["buoy"].stop)  # the buoy restarts, and is away longer than the timeout
            time.sleep(values.gateway_timeout + 1)
            with center():
                restarted = time.time()
                ship = gateways["ship"]
                until_sync(lambda: _plan_from(ship, restarted), "the new center's first plan in force")
                time.sleep(max(0.0, _slot_of("buoy", kept, time.time() + 1.0) - 0.5 - time.time()))
                gateways["buoy"] = gateway("buoy")  # back, as its slot in the kept plan begins
                sent = world.channel.stats["transmissions"]
                until_sync(lambda: world.channel.stats["transmissions"] >= sent + 6, "polls in both slots")
                assert all(_follows(g, ("buoy", "ship")) for g in gateways.values())
            assert world.channel.stats["collisions"] == 0
        finally:
            for g in gateways.values():
                loop.call(g.stop)
            loop.call(world.stop)
            loop.close()


def _plan_from(gateway: Gateway, since: float) -> bool:
    """The gateway follows a plan handed out after ``since``."""
    plan = gateway.schedule.plan(time.time())
    return plan is not None and plan.epoch > since


def _slot_of(name: str, plan: SlotPlan, after: float) -> float:
    """When the next slot of ``name`` in ``plan`` begins after ``after``."""
    k = math.floor((after - plan.epoch) / plan.slot) + 1
    while plan.order[k % len(plan.order)] != name:
        k += 1
    return plan.epoch + k * plan.slot


def _follows(gateway: Gateway, order: tuple[str, ...]) -> bool:
    plan = gateway.schedule.plan(time.time())
    return plan is not None and plan.order == order


def until_sync(condition: Callable[[], bool], what: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)
