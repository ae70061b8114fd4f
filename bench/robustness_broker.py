"""Attacks on the split shore's broker from one gateway's credentials (``bench_robustness.py --broker``).

A real nats-server with the accounts ``tacit broker-config`` writes (gateways ``ship`` and ``buoy``), a
center process (``Center`` with leases, storing into a SQLite file) and the buoy's gateway sending frames
all along; the attacker holds the ship's credentials. Each row repeats its attack ``cases`` times and
says what shows it reached the broker (the server answered, or delivered the ship's own commands
somewhere in its account) before it counts what the attack changed; a row that cannot show it is
``NOT MEASURED`` and the command exits 1.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import tempfile
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import nats
from nats.aio.client import Client
from nats.aio.msg import Msg
from robustness_system import Row
from sqlalchemy import create_engine, text

from launch.broker import Secured
from server.backhaul import access, subjects
from server.backhaul.center import Center
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.relay import RelayIngest
from server.backhaul.subjects import CommandMessage, FrameMessage
from server.core.config import Settings
from server.core.db import make_engine, migrate
from server.core.events import Bus
from tacit.streams import default_streams

TEST = "test_access: no_request_of_a_gateway"
NEXT = f"{access.GATEWAY_API}.CONSUMER.MSG.NEXT.{subjects.COMMANDS_STREAM}.gateway-ship"


class Scene:
    """The broker, the center, the buoy, and the attacker's connection."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.server = Secured(folder / "broker", ["ship", "buoy"], monitor=True)
        self.url = f"sqlite:///{folder}/center.db"
        self.errors: list[str] = []

    async def __aenter__(self) -> Scene:
        self.server.start()
        migrate(self.url)
        ingest = RelayIngest(make_engine(self.url), Bus(), default_streams(), Settings())
        self.center = Center(ingest, self.server.url, auth=self.server.credentials("center"), instance="c1")
        self.running = asyncio.create_task(self.center.run())
        self.gateways = [
            Gateway(Outbox(self.folder / f"{n}.db", n), self.server.url, heartbeat=0.2,
                    auth=self.server.credentials(f"gateway-{n}"))
            for n in ("ship", "buoy")
        ]  # fmt: skip
        for gateway in self.gateways:
            await gateway.start()
        await until(lambda: set(self.center.gateways) == {"ship", "buoy"})
        await self.gateways[0].stop()  # its consumers made; its credentials the attacker's now

        async def error(exc: Exception) -> None:
            self.errors.append(str(exc))

        options = self.server.credentials("gateway-ship").options()
        self.ship: Client = await nats.connect(self.server.url, error_cb=error, **options)
        return self

    async def __aexit__(self, *_: object) -> None:
        await self.ship.close()
        await self.gateways[1].stop()
        self.running.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self.running
        self.server.stop()

    async def commands(self, n: int) -> None:
        """``n`` commands for the ship, which its pulls may take."""
        for i in range(n):
            command = CommandMessage(
                f"cmd-{time.time_ns()}-{i}", "ship", 4, b"signed", expires_at=time.time() + 60
            )
            await self.center.send_command(command)

    async def delivered(self) -> int:
        """The ship's command consumer's deliveries so far."""
        assert self.center.js is not None
        info = await self.center.js.consumer_info(subjects.COMMANDS_STREAM, "gateway-ship")
        return info.delivered.consumer_seq

    async def kept(self, stream: str) -> int:
        assert self.center.js is not None
        return (await self.center.js.stream_info(stream)).state.messages

    def stored(self) -> int:
        with create_engine(self.url).connect() as c:
            return int(c.execute(text("SELECT count(*) FROM frame")).scalar_one())


async def until(condition: Callable[[], bool], timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError("not reached")
        await asyncio.sleep(0.05)


async def pulls_into(scene: Scene, reply: str, cases: int) -> str:
    """The ship's pulls of its own commands, each naming ``reply``, after one to its own inbox (which a
    command answers: the way to JetStream is open); what shows they reached the broker."""
    await scene.commands(cases + 1)
    control: list[str] = []

    async def got(msg: Msg) -> None:
        control.append(msg.subject)

    inbox = f"{access.inbox_prefix('gateway-ship')}.control"
    sub = await scene.ship.subscribe(inbox, cb=got)
    pull = json.dumps({"batch": 1, "expires": 500_000_000}).encode()
    await scene.ship.publish(NEXT, pull, reply=inbox)
    await scene.ship.flush()
    await asyncio.sleep(0.5)
    await sub.unsubscribe()
    received = scene.server.received("gateway-ship")
    for _ in range(cases):
        await scene.ship.publish(NEXT, pull, reply=reply)
    await scene.ship.flush()
    await asyncio.sleep(0.5)
    received = scene.server.received("gateway-ship") - received
    if not control or received < cases:
        return f"NOT MEASURED: {len(control)} control pulls answered, {received} of {cases} received"
    return f"{received} received by the broker (a pull to its own inbox: answered)"


async def leases(scene: Scene, cases: int) -> Row:
    """Its commands delivered into the center's coordinator lease: the center must keep its role."""
    bucket = scene.center.durable
    reached = await pulls_into(scene, f"$KV.{bucket}.coordinator", cases)
    kv = await scene.center.js.key_value(bucket)  # type: ignore[union-attr]
    owner = json.loads((await kv.get("coordinator")).value or b"{}").get("instance")
    held = scene.center.leases is not None and len(scene.center.leases.held) == 1 + subjects.PARTITIONS
    outcome = "0 leases lost" if owner == "c1" and held else "THE CENTER LOST ITS LEASES"
    return Row("reply into the center's leases", f"{cases}", outcome, reached, TEST)


async def down_subjects(scene: Scene, cases: int) -> Row:
    """Its commands delivered onto the buoy's schedule, SYNC budgets and commands."""
    streams = (subjects.SCHEDULE_STREAM, subjects.SYNCS_STREAM, subjects.COMMANDS_STREAM)
    before = [await scene.kept(s) for s in streams]
    replies = (subjects.schedule("buoy"), subjects.syncs("buoy", 4), subjects.commands("buoy"))
    reached = [await pulls_into(scene, reply, cases) for reply in replies]
    added = sum([await scene.kept(s) for s in streams]) - sum(before) - 3 * (cases + 1)  # less its own
    shown = next((r for r in reached if "NOT MEASURED" in r), reached[-1])
    return Row(
        "reply into another gateway's subjects", f"{3 * cases}", f"{added} messages written", shown, TEST
    )


async def deliver_subject(scene: Scene, cases: int) -> Row:
    """A consumer of its own name with a deliver subject into the buoy's commands."""
    assert scene.center.js is not None
    config = {
        "durable_name": "gateway-ship",
        "deliver_subject": subjects.commands("buoy"),
        "ack_policy": "none",
    }
    body = json.dumps({"stream_name": subjects.COMMANDS_STREAM, "config": config}).encode()
    received = scene.server.received("gateway-ship")
    for prefix in ("$JS.API", access.GATEWAY_API):
        for _ in range(cases):
            create = f"{prefix}.CONSUMER.CREATE.{subjects.COMMANDS_STREAM}"
            await scene.ship.publish(create, body, reply=f"{access.inbox_prefix('gateway-ship')}.create")
    await scene.ship.flush()
    await asyncio.sleep(0.5)
    received = scene.server.received("gateway-ship") - received
    consumers = await scene.center.js.consumers_info(subjects.COMMANDS_STREAM)
    made = sum(1 for c in consumers if c.config.deliver_subject)
    reached = f"{received} received by the broker" if received >= 2 * cases else "NOT MEASURED: not received"
    return Row("consumer with a deliver subject", f"{2 * cases}", f"{made} made", reached, TEST)


async def frames_meanwhile(scene: Scene, cases: int, attack: Callable[[], Awaitable[object]]) -> Row:
    """The buoy's frames while the ship attacks: every one stored."""
    outbox = scene.gateways[1].outbox
    before = scene.stored()
    for i in range(cases):
        outbox.add_frame(4, 0, f"buoy frame {i}".encode(), at=time.time())
    await attack()
    with contextlib.suppress(TimeoutError):
        await until(lambda: scene.stored() - before >= cases)
    lost = cases - (scene.stored() - before)
    reached = (
        f"{scene.center.frames['buoy']} buoy frames consumed"
        if scene.center.frames["buoy"]
        else "NOT MEASURED"
    )
    return Row("frames stored while a gateway attacks", f"{cases}", f"{lost} lost", reached, TEST)


async def forged_frames(scene: Scene, cases: int) -> Row:
    """Frames published on the buoy's subject with the ship's credentials."""
    before, errors = scene.stored(), len(scene.errors)
    for i in range(cases):
        frame = FrameMessage(f"buoy-0a0b0c0d-{i}", "buoy", 4, 0, b"passed off", at=time.time())
        await scene.ship.publish(subjects.frames("buoy", 4), frame.encode())
    await scene.ship.flush()
    await asyncio.sleep(0.5)
    refused = len(scene.errors) - errors
    reached = f"{refused} refused by the server" if refused else "NOT MEASURED: no refusal heard"
    return Row("frames as another gateway", f"{cases}", f"{scene.stored() - before} stored", reached, TEST)


def run(cases: int = 50) -> list[Row]:
    async def main() -> list[Row]:
        with tempfile.TemporaryDirectory() as folder:
            async with Scene(Path(folder)) as scene:
                rows = [await leases(scene, cases), await down_subjects(scene, cases)]
                rows.append(await deliver_subject(scene, cases))
                rows.append(await forged_frames(scene, cases))
                rows.append(await frames_meanwhile(scene, cases, lambda: leases(scene, cases)))
                return rows

    return asyncio.run(main())
