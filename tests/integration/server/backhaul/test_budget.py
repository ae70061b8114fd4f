"""The SYNC budget (issue 24, item 8), integration tier: SYNCs the center signs ahead for each vehicle's
gateway, sent by the gateway while the center's own SYNCs do not reach it.

A vehicle's agent on a simulated modem behind a gateway on another hears authentic SYNCs through a cut
longer than its link-lost timeout (time scaled by 10); a recorded pre-signed SYNC replayed is refused
and none moves the vehicle's clock (the agent as it runs); a budget moves with its vehicle; a gateway
reads no other's budgets on a broker with ``tacit broker-config``'s permissions, and refuses bad ones.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from nats.errors import Error as NatsError

from gateway.timing import Timing
from server.app import create_app
from server.backhaul import access, subjects
from server.backhaul.budget import scheduled_syncs
from server.backhaul.center import Center, serve
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.relay import RelayIngest
from server.backhaul.subjects import SyncBudgetMessage
from server.core.config import Settings
from server.vehicles.models import Vehicle as VehicleRow
from tacit import auth
from tacit import modem as mm
from tacit.packets import CheckpointPacket, Command, ControlFlag, ControlPacket, MissionState, decode_control
from tests.integration.server.backhaul.test_access import client as broker_client
from tests.integration.server.backhaul.test_frames_and_commands import ingest_on
from tests.integration.server.backhaul.test_frames_and_commands import until as until_async
from tests.support.nats import NATS_SERVER, NatsServer, Secured
from vehicle_agent.agent import Agent, AgentConfig

pytestmark = pytest.mark.skipif(not Path(NATS_SERVER).exists(), reason="nats-server is not installed")

OP = {"Authorization": "Bearer operator-token"}
KEY = bytes(range(32))
ADDRESS = 2
SCALE = 10.0  # simulated seconds per wall second (the center's intervals and the acoustics)
LINK_LOST = AgentConfig().link_lost_timeout / SCALE  # the agent's default, in wall seconds


def until(condition: Callable[[], object], timeout: float = 30.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def center_app(url: str, broker: NatsServer, **changes: Any) -> Any:
    settings = Settings(
        **{
            "database_url": url,
            "map_enabled": False,
            "write_tokens": ["operator-token"],
            "metrics_port": 0,
            "gateway_timeout": 5.0,
            **changes,
        }
    )
    return create_app(settings, RelayIngest, [lambda shore: serve(shore, broker.url)])


def register(client: TestClient) -> int:
    body = {"name": "rov1", "address": ADDRESS, "key": KEY.hex()}
    answer = client.post("/api/v1/vehicles", json=body, headers=OP)
    assert answer.status_code == 201, answer.text
    return int(answer.json()["id"])


@contextmanager
def ship_and_rov1(
    broker: NatsServer,
    tmp_path: Path,
    slot: float,
    prepare: Callable[[Agent], None],
    heard: Callable[[Agent, ControlPacket], None],
) -> Iterator[tuple[TestClient, Gateway, Outbox, Agent]]:
    """The center (time scaled by ``SCALE``, ``slot`` s slots), the ship's gateway and rov1's agent on
    simulated Micro-Modems 300 m apart: the agent ``prepare``d before its modem starts, ``heard`` told
    every control packet it takes (after its link did)."""
    from simulators.run import ModemSpec, SimConfig, SimWorld

    world = SimWorld(
        SimConfig(
            time_scale=SCALE,
            channel={"fading_sigma_db": 0.0},
            modems=[ModemSpec(1, "ship", (0.0, 0.0, 1.0)), ModemSpec(ADDRESS, "rov1", (300.0, 0.0, 5.0))],
        )
    )
    app = center_app(
        f"sqlite:///{tmp_path}/center.db", broker, time_scale=SCALE, tdma_slot=slot, tdma_guard=0.3
    )
    with TestClient(app) as client:
        assert client.portal is not None
        client.portal.call(world.start)
        ptys = {m["name"]: m["pty"] for m in world.describe()["modems"]}
        driver = mm.ModemDriver(mm.DriverSettings(url=ptys["ship"], address=1, keepalive=10.0))
        outbox = Outbox(tmp_path / "ship.db", "ship")
        gateway = Gateway(outbox, broker.url, driver, heartbeat=0.2, timing=Timing(time_scale=SCALE))
        register(client)
        agent = make_agent(tmp_path, ptys["rov1"])
        prepare(agent)
        handle = agent.link.on_control

        def hear(packet: ControlPacket) -> None:
            handle(packet)
            heard(agent, packet)

        agent.link.on_control = hear
        try:
            client.portal.call(agent.driver.start)
            client.portal.call(gateway.start)
            yield client, gateway, outbox, agent
        finally:
            client.portal.call(gateway.stop)
            client.portal.call(agent.driver.stop)
            client.portal.call(world.stop)


def test_a_backhaul_cut_longer_than_the_link_lost_timeout_keeps_the_vehicle_hearing_authentic_syncs(
    broker: NatsServer, tmp_path: Path
) -> None:
    """The ship's gateway and the vehicle's agent 300 m apart on simulated Micro-Modems; the broker
    stopped for one and a half link-lost timeouts (the gateway and the center both cut off). The agent
    hears the center's SYNCs, then the ship's pre-signed ones, never silent for a timeout, each within the
    window of its clock and none before its time, and its clock stays as the center's SYNCs left it; then
    the center's again."""
    heard: list[tuple[float, ControlPacket]] = []  # (the vehicle's clock, what its agent accepted)

    def synced(agent: Agent) -> None:
        answered(agent, time.time() - 5)  # as the center's answer to its first check-point would have

    with ship_and_rov1(broker, tmp_path, 2.5, synced, lambda _, p: heard.append((time.time(), p))) as rig:
        _, _, outbox, agent = rig
        agent._send_checkpoint()
        report = agent.link.queue.pop().data  # the ship hears its check-point: it is the ship's
        outbox.add_frame(ADDRESS, 0, report, snr_in=20.0)  # (and heard: the center's SYNCs may go)
        until(lambda: outbox.budget_left(ADDRESS)[0] > 0, what="the ship's budget for rov1")
        until(lambda: heard, what="the center's first SYNC")
        broker.stop()
        cut = time.time()
        time.sleep(1.5 * LINK_LOST)
        broker.start()
        back = time.time()
        until(lambda: heard[-1][0] > back and not scheduled(heard[-1][1]), what="the center's SYNCs again")
    assert all(p.command is Command.SYNC for _, p in heard)
    quiet = 2 * Settings.model_fields["sync_interval"].default / SCALE  # the center's last SYNCs are out
    during = [(at, p) for at, p in heard if cut + quiet < at < back]
    assert len(during) >= 3 and all(scheduled(p) for _, p in during)  # only the gateway's budget then
    times = [at for at, _ in heard]
    assert max(b - a for a, b in zip(times, times[1:], strict=False)) < LINK_LOST  # never LINK_LOST
    for at, p in [(at, p) for at, p in heard if scheduled(p)]:  # at their time: in the window, not early
        assert p.time - 1 <= at <= p.time + auth.SCHEDULED_WINDOW
        assert p.seq == p.time
    assert agent.link.offset == 0.0  # the center's SYNCs left the clock right; the budget's moved nothing
    assert agent.link.receiver.sync.counter == heard[-1][1].seq


def scheduled(packet: ControlPacket) -> bool:
    return bool(packet.flags & ControlFlag.SCHEDULED)


def make_agent(tmp_path: Path, modem_url: str = "/dev/null") -> Agent:
    """The agent as ``tacit agent`` builds it, without MAVLink: its link takes the frames its modem
    hears (none without one: the test hands frames to its link)."""
    config = AgentConfig(key=KEY.hex(), state_file=str(tmp_path / "agent-state.json"), modem_url=modem_url)
    return Agent(config, config.plans(tmp_path))


def answered(agent: Agent, now: float) -> None:
    """A SYNC answers the agent's challenge at ``now`` (as the center's would): it is synced, its clock
    right."""
    agent._send_checkpoint()
    echo = agent.link.queue[-1].data[28:]
    packet = ControlPacket(Command.SYNC, seq=int(now), time=int(now), echo=echo)
    agent.link._control(auth.sign(packet, KEY, ADDRESS, epoch=1))
    agent.link.queue.clear()  # the check-point is the challenge, not news for the shore
    assert agent.link.receiver.sync.counter == int(now)


def test_a_recorded_pre_signed_sync_is_refused_and_none_moves_the_clock(tmp_path: Path) -> None:
    now = time.time()
    agent = make_agent(tmp_path)
    answered(agent, now)
    row = VehicleRow(name="rov1", address=ADDRESS, key_hex=KEY.hex())
    budget = scheduled_syncs(row, int(now) + 60, 60.0, 8)  # due 1, 2, ... 8 minutes from now
    assert [decode_control(f).time for f in budget] == [int(now) + 60 * k for k in range(1, 9)]
    clock = [now + 65.0]
    agent.link.clock = lambda: clock[0]
    receiver = agent.link.receiver

    agent.link._control(budget[0])  # sent at its time (5 s late, a slot's wait): accepted
    assert receiver.sync.counter == int(now) + 60 and agent.link.offset == 0.0
    with pytest.raises(auth.Replayed):  # recorded and replayed: its counter
        receiver.accept(budget[0], clock[0])
    clock[0] = now + 120 + auth.SCHEDULED_WINDOW + 1  # the vehicle missed the next; replayed later
    with pytest.raises(auth.OutOfWindow, match="scheduled SYNC"):
        receiver.accept(budget[1], clock[0])
    with pytest.raises(auth.OutOfWindow):  # released four minutes early (a captured gateway)
        receiver.accept(budget[7], clock[0])
    agent.link._control(budget[5])  # released 119 s early: the window's limit, and no more
    assert receiver.sync.counter == int(now) + 360 and agent.link.offset == 0.0  # the clock never moved
    with pytest.raises(auth.Replayed):  # the earlier ones are stale after it
        receiver.accept(budget[4], clock[0])
    assert make_agent(tmp_path).link.receiver.sync.counter == int(now) + 360  # persisted

    (tmp_path / "lost").mkdir()
    fresh = make_agent(tmp_path / "lost")  # a vehicle that lost its state takes no budget's SYNC
    with pytest.raises(auth.Unsynced):
        fresh.link.receiver.accept(budget[0], now + 60)


@pytest.fixture
def layout(broker: NatsServer, tmp_path: Path) -> Iterator[tuple[TestClient, dict[str, Outbox]]]:
    """The center (SQLite) and two gateways without modems (they keep budgets all the same)."""
    outboxes = {name: Outbox(tmp_path / f"{name}.db", name) for name in ("ship", "buoy")}
    gateways = [Gateway(outbox, broker.url, heartbeat=0.2) for outbox in outboxes.values()]
    with TestClient(center_app(f"sqlite:///{tmp_path}/center.db", broker)) as client:
        assert client.portal is not None
        for gateway in gateways:
            client.portal.call(gateway.start)
        try:
            yield client, outboxes
        finally:
            for gateway in gateways:
                client.portal.call(gateway.stop)


def test_a_budget_moves_with_its_vehicle(layout: tuple[TestClient, dict[str, Outbox]]) -> None:
    client, outboxes = layout
    vehicle_id = register(client)
    checkpoint = CheckpointPacket(seq=1, time=int(time.time()), state=MissionState.PREPROGRAMMED)
    heard = auth.sign_checkpoint(checkpoint, KEY, 1, ADDRESS, [])  # the vehicle's own word: routing counts it
    outboxes["ship"].add_frame(ADDRESS, 0, heard, snr_in=20.0)
    until(lambda: outboxes["ship"].budget_left(ADDRESS)[0], what="the ship's budget")
    count, last = outboxes["ship"].budget_left(ADDRESS)
    assert (
        count == 360 and last is not None and last > time.time() + 6 * 3600 - 120
    )  # six hours, a minute apart
    assert outboxes["buoy"].budget_left(ADDRESS) == (0, None)

    until(lambda: len(client.get("/api/v1/gateways", headers=OP).json()) == 2, what="the gateways known")
    answer = client.put(f"/api/v1/vehicles/{vehicle_id}/gateway", json={"gateway": "buoy"}, headers=OP)
    assert answer.status_code == 200, answer.text
    until(lambda: outboxes["buoy"].budget_left(ADDRESS)[0], what="the buoy's budget")
    until(lambda: outboxes["ship"].budget_left(ADDRESS) == (0, None), what="the ship's withdrawn")
    assert [b.address for b in outboxes["buoy"].budgets()] == [ADDRESS] and outboxes["ship"].budgets() == []
    budget = outboxes["buoy"].take_sync(outboxes["buoy"].budgets()[0], time.time() + 120)
    assert budget is not None
    packet = auth.verify(budget[1], KEY, ADDRESS)  # the vehicle's key, its address
    assert scheduled(packet) and packet.seq == packet.time == budget[0]


def test_a_gateway_reads_no_other_gateways_budgets(secured: Secured, sqlite_url: str, tmp_path: Path) -> None:
    async def main() -> None:
        center = Center(ingest_on(sqlite_url), secured.url, auth=secured.credentials("center"))
        await center.connect()
        errors: list[str] = []
        ship = await broker_client(secured, "gateway-ship", errors)
        js = ship.jetstream(prefix=access.GATEWAY_API, timeout=0.5)
        outbox = Outbox(tmp_path / "buoy.db", "buoy")
        buoy = Gateway(outbox, secured.url, heartbeat=0.2, auth=secured.credentials("gateway-buoy"))
        row = VehicleRow(name="rov1", address=ADDRESS, key_hex=KEY.hex())
        budget = SyncBudgetMessage(
            "syncs-buoy-2-1", "buoy", ADDRESS, tuple(scheduled_syncs(row, 10**9, 60.0, 3))
        )
        await center.publish(subjects.syncs("buoy", ADDRESS), budget.encode(), budget.id)
        await buoy.start()
        try:
            await until_async(lambda: "buoy" in center.gateways, center.step_events)  # its consumers made
            await until_async(lambda: outbox.budget_left(ADDRESS)[0] == 3, lambda: asyncio.sleep(0.05))
            for name in ("syncs-buoy", "syncs-ship", "mine"):
                with pytest.raises(NatsError):  # the buoy's consumer, its own name, another on buoy's subject
                    await js.pull_subscribe(
                        subjects.syncs("buoy"), durable=name, stream=subjects.SYNCS_STREAM
                    )
            with pytest.raises(NatsError):  # nor publish one of its own making
                await js.publish(subjects.syncs("ship", ADDRESS), budget.encode())
        finally:
            await buoy.stop()
            await ship.close()
            await center.close()

    asyncio.run(main())


def test_a_bad_budget_is_a_logged_refusal(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    outbox = Outbox(tmp_path / "ship.db", "ship")
    gateway = Gateway(outbox, "nats://127.0.0.1:1")  # never started: its store and its checks only
    row = VehicleRow(name="rov1", address=ADDRESS, key_hex=KEY.hex())
    good = scheduled_syncs(row, 10**9, 60.0, 2)
    command = auth.sign(ControlPacket(Command.HOLD, seq=1, time=10**9), KEY, ADDRESS)
    plain = auth.sign(ControlPacket(Command.SYNC, seq=1, time=10**9), KEY, ADDRESS)
    own = subjects.syncs("ship", ADDRESS)

    def budget(gateway: str = "ship", syncs: tuple[bytes, ...] = tuple(good)) -> bytes:
        return SyncBudgetMessage(f"syncs-{gateway}-{ADDRESS}-1", gateway, ADDRESS, syncs).encode()

    refused = [
        (own, b"not json"),
        (own, budget().replace(b'"interval":60.0', b'"interval":-1')),
        (own, budget(gateway="buoy")),  # another gateway's
        (subjects.syncs("ship", 3), budget()),  # on another vehicle's subject
        (own, budget(syncs=(command,))),  # a command
        (own, budget(syncs=(plain,))),  # a SYNC not pre-signed for its time
        (own, budget(syncs=(b"\x00" * 31,))),
    ]
    for subject, data in refused:
        assert not gateway.keep_budget(subject, data)
    assert outbox.budgets() == [] and len([r for r in caplog.records if r.levelname == "ERROR"]) == 7
    assert gateway.keep_budget(own, budget()) and outbox.budget_left(ADDRESS) == (2, 10**9 + 60)
    assert gateway.keep_budget(own, budget())  # the same again (a redelivery): kept once
    assert outbox.budget_left(ADDRESS) == (2, 10**9 + 60)
