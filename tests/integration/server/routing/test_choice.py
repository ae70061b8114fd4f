"""Which gateway talks to which vehicle (issue 24, item 4), integration tier: a real nats-server, the
center (``tacit center``'s app: the API, the backhaul consumers and the command dispatcher) on
PostgreSQL, two gateways whose modems are stand-ins that reach a vehicle or not.

A command goes down once through the vehicle's gateway and, when that gateway is killed, once through
the other; the assignment moves with hysteresis and never flaps; an operator's pin holds.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from gateway.timing import Timing
from launch.split import throwaway_database as postgres_database
from server.app import create_app
from server.backhaul.center import Center, serve
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.relay import RelayIngest
from server.core.config import Settings
from server.core.db import make_engine, migrate, writing
from server.core.events import Bus
from server.routing.service import Routing
from server.vehicles.models import Vehicle as VehicleRow
from tacit import auth
from tacit import modem as mm
from tacit.packets import CheckpointPacket, Command, MissionState
from tacit.streams import default_streams
from tests.support.nats import NATS_SERVER, NatsServer

pytestmark = pytest.mark.skipif(not Path(NATS_SERVER).exists(), reason="nats-server is not installed")

OP = {"Authorization": "Bearer operator-token"}
ADDRESS = 2


@dataclass
class Vehicle:
    """The vehicle's end of the acoustic link: the command frames it received (verified with its key),
    by the gateway they came through, and which gateways reach it."""

    key: bytes = b""
    reaches: set[str] = field(default_factory=set)
    received: list[tuple[str, int]] = field(default_factory=list)  # (gateway, command seq)
    syncs: list[tuple[str, int]] = field(default_factory=list)  # (gateway, SYNC counter)


class StandInModem:
    """A shore modem that reaches ``vehicle`` when its gateway is in ``vehicle.reaches`` (ACKed), and
    transmits into the void otherwise (no ACK); its polls go unanswered (the test says what is heard)."""

    def __init__(self, gateway: str, vehicle: Vehicle) -> None:
        self.gateway = gateway
        self.vehicle = vehicle
        self.state = mm.LinkState.READY
        self.polls: list[int] = []  # the addresses it polled (its vehicle answers nothing here)

    def add_listener(self, listener: Callable[[Any], None]) -> None:
        pass

    async def start(self) -> None:
        pass

    async def stop(self) -> None:
        pass

    async def poll(self, remote: int, rate: int = 0, ack: bool = False) -> None:
        self.polls.append(remote)

    async def ping(self, dest: int, timeout: float = 10.0) -> float | None:
        return None  # unanswered, as its polls

    async def send(
        self,
        dest: int,
        frames: list[bytes],
        rate: int = 0,
        ack: bool = True,
        ack_timeout: float | None = None,
    ) -> mm.TransmitResult:
        if dest != ADDRESS or self.gateway not in self.vehicle.reaches:
            return mm.TransmitResult(dest, len(frames), transmitted=True, error="no acknowledgement")
        for frame in frames:
            packet = auth.verify(frame, self.vehicle.key, dest)
            heard = self.vehicle.syncs if packet.command is Command.SYNC else self.vehicle.received
            heard.append((self.gateway, packet.seq))
        return mm.TransmitResult(
            dest, len(frames), transmitted=True, acked=frozenset(range(1, len(frames) + 1))
        )


FAST = Timing(time_scale=20.0)  # the stand-in modems' exchanges fit the tests' 0.8 s slots


def settings(url: str, **changes: Any) -> Settings:
    base: dict[str, Any] = {
        "database_url": url,
        "map_enabled": False,
        "write_tokens": ["operator-token"],
        "read_tokens": ["observer-token"],
        "routing_window": 60.0,
        "routing_margin": 3.0,
        "routing_dwell": 0.0,
        "gateway_timeout": 5.0,
        "dispatch_receipt": 1.5,
        "tdma_slot": 0.8,
        "tdma_guard": 0.05,
        "command_attempts": 2,
        "metrics_port": 0,
    }
    return Settings(**{**base, **changes})


def until(condition: Callable[[], object], timeout: float = 20.0, what: str = "condition") -> None:
    """Poll ``condition`` until it holds (the API and the center run in the client's event loop)."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


class Air:
    """A vehicle and what the modems of two gateways (``ship``, ``buoy``) hear of it: their outboxes."""

    def __init__(self, tmp_path: Path, key: bytes = b"") -> None:
        self.vehicle = Vehicle(key)
        self.outboxes = {name: Outbox(tmp_path / f"{name}.db", name) for name in ("ship", "buoy")}
        self.seq = 0

    def heard(self, snr: dict[str, float], at: float | None = None) -> None:
        """The vehicle sends a check-point; each gateway in ``snr`` hears it at that SNR."""
        self.seq += 1
        at = time.time() if at is None else at
        cp = CheckpointPacket(seq=self.seq, time=int(at), state=MissionState.PREPROGRAMMED)
        data = auth.sign_checkpoint(cp, self.vehicle.key, 1, ADDRESS, [])
        for name, value in snr.items():
            self.outboxes[name].add_frame(ADDRESS, 0, data, rate=0, snr_in=value, at=at)


class Layout(Air):
    """The center's app on a client, and the two gateways on stand-in modems in its event loop."""

    def __init__(self, client: TestClient, broker: NatsServer, tmp_path: Path) -> None:
        super().__init__(tmp_path)
        self.client = client
        self.gateways = {
            name: Gateway(outbox, broker.url, StandInModem(name, self.vehicle), heartbeat=0.2, timing=FAST)  # type: ignore[arg-type]
            for name, outbox in self.outboxes.items()
        }

    def start(self, name: str) -> None:
        assert self.client.portal is not None
        self.client.portal.call(self.gateways[name].start)

    def stop(self, name: str) -> None:
        assert self.client.portal is not None
        self.client.portal.call(self.gateways[name].stop)

    def register(self) -> int:
        answer = self.client.post("/api/v1/vehicles", json={"name": "rov1", "address": ADDRESS}, headers=OP)
        assert answer.status_code == 201, answer.text
        self.vehicle.key = bytes.fromhex(answer.json()["key"])
        return int(answer.json()["id"])

    def route(self, vehicle_id: int) -> dict[str, Any]:
        routes = self.client.get("/api/v1/routing", headers=OP).json()
        return next(r for r in routes if r["vehicle_id"] == vehicle_id)

    def command(self, vehicle_id: int) -> int:
        answer = self.client.post(
            f"/api/v1/vehicles/{vehicle_id}/commands", json={"command": "hold"}, headers=OP
        )
        assert answer.status_code == 202, answer.text
        return int(answer.json()["id"])

    def status(self, command_id: int) -> str:
        return str(self.client.get(f"/api/v1/commands/{command_id}", headers=OP).json()["status"])


@contextmanager
def running_center(
    broker: NatsServer,
    tmp_path: Path,
    postgres_server: str,
    prepare: Callable[[Layout], None] = lambda layout: None,
    **changes: Any,
) -> Iterator[Layout]:
    """The center on a fresh PostgreSQL database (``settings`` with ``changes``) and its gateways, each
    ``prepare``d, then started; the gateways still running are stopped at the end."""
    with postgres_database(postgres_server) as url:
        app = create_app(settings(url, **changes), RelayIngest, [lambda shore: serve(shore, broker.url)])
        with TestClient(app) as client:
            layout = Layout(client, broker, tmp_path)
            prepare(layout)
            for name in layout.gateways:
                layout.start(name)
            try:
                yield layout
            finally:
                for name, gateway in layout.gateways.items():
                    if gateway.nc is not None:
                        layout.stop(name)


@pytest.fixture
def center(
    broker: NatsServer, tmp_path: Path, postgres_server: str, request: pytest.FixtureRequest
) -> Iterator[Layout]:
    """The layout on a fresh PostgreSQL database; ``settings`` changes through the test's parameters."""
    with running_center(broker, tmp_path, postgres_server, **getattr(request, "param", {})) as layout:
        yield layout


def test_a_command_reaches_the_vehicle_once_through_its_gateway_and_through_the_other_when_it_is_killed(
    center: Layout,
) -> None:
    vehicle_id = center.register()
    center.vehicle.reaches = {"ship", "buoy"}
    center.heard({"ship": 20.0, "buoy": 12.0})
    until(lambda: center.route(vehicle_id)["gateway"] == "ship", what="the ship to take the vehicle")

    first = center.command(vehicle_id)
    until(lambda: center.status(first) == "acknowledged", what="the first command's ACK")
    assert center.vehicle.received == [("ship", 1)]  # once, through its gateway
    assert center.vehicle.syncs[0][0] == "ship"  # the center's SYNC went first, through it too

    center.stop("ship")  # killed: its heartbeat is still fresh, so the center tries it first
    second = center.command(vehicle_id)
    until(lambda: center.status(second) == "acknowledged", what="the second command's ACK")
    assert center.vehicle.received == [("ship", 1), ("buoy", 2)]  # once more, through the other
    history = center.client.get(f"/api/v1/commands/{second}", headers=OP).json()["history"]
    assert [h["status"] for h in history] == ["queued", "sent", "acknowledged"]
    assert "via buoy" in history[1]["detail"]
    routing = center.client.app.state.shore.routing  # type: ignore[attr-defined]
    assert [(d.gateway, d.state) for d in routing.dispatches(second)] == [
        ("ship", "unanswered"),
        ("buoy", "acked"),
    ]

    center.start("ship")  # back: the command waiting for it came after its start_by, so it is not sent
    ship = center.outboxes["ship"]
    until(lambda: ship.commands("expired"), what="the ship to drop the stale command")
    assert center.vehicle.received == [("ship", 1), ("buoy", 2)]


def test_a_command_no_gateway_gets_acknowledged_fails_after_both_tried(center: Layout) -> None:
    vehicle_id = center.register()
    center.heard({"ship": 20.0, "buoy": 12.0})
    until(lambda: center.route(vehicle_id)["gateway"] == "ship", what="an assignment")
    center.vehicle.reaches = set()  # the vehicle went out of both gateways' reach
    command = center.command(vehicle_id)
    until(lambda: center.status(command) == "failed", timeout=30, what="the command to fail")
    detail = center.client.get(f"/api/v1/commands/{command}", headers=OP).json()["history"][-1]["detail"]
    assert detail == "no gateway reached it (tried buoy, ship)"
    assert center.vehicle.received == []


def test_an_operator_pins_a_vehicle_to_a_gateway(center: Layout) -> None:
    vehicle_id = center.register()
    center.vehicle.reaches = {"ship", "buoy"}
    center.heard({"ship": 20.0, "buoy": 12.0})
    until(lambda: center.route(vehicle_id)["gateway"] == "ship", what="the ship to take the vehicle")
    assert (
        center.client.put("/api/v1/vehicles/99/gateway", json={"gateway": "buoy"}, headers=OP).status_code
        == 404
    )
    missing = center.client.put(
        f"/api/v1/vehicles/{vehicle_id}/gateway", json={"gateway": "pier"}, headers=OP
    )
    assert missing.status_code == 404 and missing.json()["field"] == "gateway"
    pinned = center.client.put(f"/api/v1/vehicles/{vehicle_id}/gateway", json={"gateway": "buoy"}, headers=OP)
    assert pinned.status_code == 200 and pinned.json()["gateway"] == "buoy" and pinned.json()["pinned"]

    center.heard({"ship": 25.0, "buoy": 10.0})  # the ship hears it far better: the pin holds
    command = center.command(vehicle_id)
    until(lambda: center.status(command) == "acknowledged", what="the command's ACK")
    assert center.vehicle.received == [("buoy", 1)]
    route = center.route(vehicle_id)
    assert route["gateway"] == "buoy" and route["reason"] == "pinned by an operator"
    assert [h["gateway"] for h in route["heard"]] == ["ship", "buoy"]  # the scores, best first

    unpinned = center.client.delete(f"/api/v1/vehicles/{vehicle_id}/gateway", headers=OP)
    assert unpinned.status_code == 200 and not unpinned.json()["pinned"]
    until(lambda: center.route(vehicle_id)["gateway"] == "ship", what="the rule to choose again")


def test_the_vehicle_moves_to_the_gateway_that_hears_it_better_with_hysteresis(
    broker: NatsServer, tmp_path: Path, postgres_server: str
) -> None:
    """Frames through two gateways and the broker into the center's store; the assignment applied every
    10 s (of the frames' own clock): within the 3 dB margin the vehicle stays wherever the SNRs wobble,
    a clearly better gateway takes it only after the 60 s dwell, and nothing goes back and forth."""
    steps = [  # (ship SNR, buoy SNR) heard of one check-point, every 10 s
        (20.0, 12.0),  # t=0   first heard: the ship
        (19.0, 21.0),  # t=10  buoy 2 dB better: under the margin
        (20.0, 19.0),  # t=20  the ship is best again
        (18.0, 20.5),  # t=30  buoy 2.5 dB better: under the margin
        (5.0, 30.0),  # t=40  the vehicle drives to the buoy: 25 dB better, but the dwell
        (4.0, 31.0),  # t=50  still the dwell
        (3.0, 32.0),  # t=60  dwell over: the buoy takes it
        (22.0, 20.0),  # t=70  the ship a little better: under the margin
        (30.0, 10.0),  # t=80  the ship far better: the dwell again (since t=60)
    ]
    with postgres_database(postgres_server) as url:
        migrate(url)
        config = settings(url, routing_window=5.0, routing_dwell=60.0, gateway_timeout=30.0)
        routing = Routing(make_engine(url), config)

        async def main() -> list[tuple[str | None, str]]:
            ingest = RelayIngest(make_engine(url), Bus(), default_streams(), config)
            air = Air(tmp_path, key=bytes(range(32)))
            with writing(ingest.db) as s:
                s.add(VehicleRow(name="rov1", address=ADDRESS, key_hex=air.vehicle.key.hex()))
                s.commit()
            ingest.load_vehicles()
            gateways = [Gateway(outbox, broker.url) for outbox in air.outboxes.values()]
            center = Center(ingest, broker.url)
            for g in gateways:
                await g.start()
            await center.connect()
            base, decisions = time.time(), []
            try:
                for i, (ship, buoy) in enumerate(steps):
                    at = base + 10 * i
                    air.heard({"ship": ship, "buoy": buoy}, at)
                    for name in air.outboxes:
                        routing.seen(name, at)
                    await until_async(lambda n=2 * (i + 1): center.counters["messages"] >= n, center.step)
                    routing.update(at + 1)
                    route = routing.routes(at + 1)[0]
                    decisions.append((route.gateway, route.reason))
            finally:
                await center.close()
                for g in gateways:
                    await g.stop()
            return decisions

        decisions = asyncio.run(main())
    assert [g for g, _ in decisions] == ["ship"] * 6 + ["buoy"] * 3
    reasons = [r for _, r in decisions]
    assert "under the 3.0 dB margin" in reasons[1] and "under the 3.0 dB margin" in reasons[3]
    assert "after the 60 s dwell" in reasons[4] and "after the 60 s dwell" in reasons[5]
    assert reasons[6].startswith("buoy heard it") and "better than ship" in reasons[6]
    assert "after the 60 s dwell" in reasons[8]


async def until_async(condition: Callable[[], bool], step: Callable[[], Awaitable[object]]) -> None:
    deadline = time.monotonic() + 15
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        await step()


def test_two_gateways_on_one_band_never_collide(
    broker: NatsServer, tmp_path: Path, postgres_server: str
) -> None:
    """Two gateways on simulated Micro-Modems 1.2 km apart on one channel, each with a vehicle near it;
    commands to both vehicles at once go down in the slots the center hands out: every one is
    acknowledged and no two transmissions overlap at any receiver. The same two sends without slots
    collide (the count works)."""
    from simulators.run import ModemSpec, SimConfig, SimWorld

    scale = 4.0  # simulated seconds per wall second: a rate-0 command and its ACK take ~1.3 s of wall time
    config = SimConfig(
        time_scale=scale,
        channel={"fading_sigma_db": 0.0},
        modems=[
            ModemSpec(1, "ship", (-600.0, 0.0, 1.0)),
            ModemSpec(5, "buoy", (600.0, 0.0, 1.0)),
            ModemSpec(2, "rov1", (-300.0, 0.0, 5.0)),
            ModemSpec(3, "rov2", (300.0, 0.0, 5.0)),
        ],
    )
    world = SimWorld(config)
    with postgres_database(postgres_server) as url:
        app = create_app(
            settings(url, tdma_slot=2.5, tdma_guard=0.3, dispatch_receipt=5.0, command_attempts=3),
            RelayIngest,
            [lambda shore: serve(shore, broker.url)],
        )
        with TestClient(app) as client:
            assert client.portal is not None
            client.portal.call(world.start)
            ptys = {m["name"]: m["pty"] for m in world.describe()["modems"]}
            drivers = {
                name: mm.ModemDriver(mm.DriverSettings(url=ptys[name], address=address, keepalive=10.0))
                for name, address in (("ship", 1), ("buoy", 5))
            }
            outboxes = {name: Outbox(tmp_path / f"{name}.db", name) for name in drivers}
            timing = Timing(time_scale=scale)
            gateways = [
                Gateway(outboxes[n], broker.url, drivers[n], heartbeat=0.2, timing=timing) for n in drivers
            ]
            try:
                for gateway in gateways:
                    client.portal.call(gateway.start)
                until(lambda: all(d.state is mm.LinkState.READY for d in drivers.values()), what="the modems")
                ids = []
                for name, address, near in (("rov1", 2, "ship"), ("rov2", 3, "buoy")):
                    answer = client.post(
                        "/api/v1/vehicles", json={"name": name, "address": address}, headers=OP
                    )
                    ids.append(answer.json()["id"])
                    cp = CheckpointPacket(seq=1, time=int(time.time()), state=MissionState.PREPROGRAMMED)
                    report = auth.sign_checkpoint(cp, bytes.fromhex(answer.json()["key"]), 1, address, [])
                    outboxes[near].add_frame(address, 0, report, snr_in=20.0)  # heard: commands may go
                until(
                    lambda: (
                        [r["gateway"] for r in client.get("/api/v1/routing", headers=OP).json()]
                        == ["ship", "buoy"]
                    ),
                    what="the assignment",
                )
                commands = [
                    client.post(
                        f"/api/v1/vehicles/{v}/commands", json={"command": "hold"}, headers=OP
                    ).json()["id"]
                    for _ in range(2)
                    for v in ids
                ]
                until(
                    lambda: all(
                        client.get(f"/api/v1/commands/{c}", headers=OP).json()["status"] == "acknowledged"
                        for c in commands
                    ),
                    timeout=60,
                    what="the ACKs",
                )
                assert world.channel.stats["collisions"] == 0
                assert world.channel.stats["transmissions"] >= 8  # 4 commands and their ACKs
                for gateway in gateways:  # every attempt inside the gateway's own slot and its guards
                    plan = gateway.schedule.current
                    assert plan is not None and gateway.transmissions
                    for start, end in gateway.transmissions:
                        assert plan.owner(start) == gateway.name == plan.owner(end)

                async def at_once() -> None:  # the control: both gateways' modems at the same moment
                    await asyncio.gather(
                        drivers["ship"].send(2, [b"x" * 32]), drivers["buoy"].send(3, [b"y" * 32])
                    )

                client.portal.call(at_once)
                assert world.channel.stats["collisions"] > 0
            finally:
                for gateway in gateways:
                    client.portal.call(gateway.stop)
                client.portal.call(world.stop)
