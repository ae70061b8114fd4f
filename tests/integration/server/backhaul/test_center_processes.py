"""Several center processes behind one broker and one database (issue 24, item 7): two ``tacit center``
processes share the frames partitions and the coordinator's role through leases; one is killed
(SIGKILL) and the other takes its partitions and its role over (the SYNC budgets with it: only the
coordinator hands them out). A real nats-server, the machine's
PostgreSQL, a gateway on an outbox in the test's process.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import httpx
import pytest
from sqlalchemy import create_engine, text

from launch.split import throwaway_database as postgres_database
from server.backhaul import subjects
from server.backhaul.center import Center, database_identity, refusal
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.subjects import UNNAMED
from server.core.db import migrate
from tacit import auth
from tacit.packets import CheckpointPacket, MissionState
from tests.integration.server.backhaul.test_frames_and_commands import ingest_on
from tests.support.nats import NATS_SERVER, Secured, free_port

pytestmark = pytest.mark.skipif(not Path(NATS_SERVER).exists(), reason="nats-server is not installed")

OP = {"Authorization": "Bearer operator-token"}
ADDRESSES = range(1, 7)  # six vehicles: partitions 1 to 6, three for each of two processes


class CenterProcess:
    """``tacit center --instance NAME`` on its own API and metrics ports, its log in a file."""

    def __init__(self, name: str, database_url: str, broker: Secured, folder: Path) -> None:
        self.name = name
        self.port, self.metrics_port = free_port(), free_port()
        self.log = folder / f"center-{name}.log"
        env = {
            **os.environ,
            "TACIT_WRITE_TOKENS": "operator-token",
            "TACIT_CENTER_LEASE": "2",
            "TACIT_ROUTING_DWELL": "0",
            "TACIT_GATEWAY_TIMEOUT": "5",
        }
        command = [
            sys.executable, "-m", "tacit.cli", "center", "--instance", name, "--nats", broker.url,
            "--nats-credentials", str(broker.credentials_file("center")), "--database-url", database_url, "--port", str(self.port), "--metrics-port",
            str(self.metrics_port), "--no-map",
        ]  # fmt: skip
        with self.log.open("w") as out:
            self.proc = subprocess.Popen(command, env=env, stdout=out, stderr=subprocess.STDOUT)
        self.api = httpx.AsyncClient(base_url=f"http://127.0.0.1:{self.port}", headers=OP, timeout=10)

    async def metric(self, name: str) -> float | None:
        """A gauge of its ``/metrics``; None while it does not answer."""
        try:
            answer = await self.api.get(f"http://127.0.0.1:{self.metrics_port}/metrics")
        except httpx.HTTPError:
            return None
        for line in answer.text.splitlines():
            if line.startswith(f"{name} "):
                return float(line.split()[1])
        return None

    async def answers(self) -> bool:
        """Its API is up."""
        try:
            return (await self.api.get("/api/v1/vehicles")).status_code == 200
        except httpx.HTTPError:
            return False

    def kill(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=10)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


async def follow(center: CenterProcess, shown: list[dict[str, object]]) -> None:
    """A browser on the center's live event stream: the packet events it is shown."""
    async with center.api.stream("GET", "/api/v1/events", timeout=None) as stream:
        kind = ""
        async for line in stream.aiter_lines():
            if line.startswith("event: "):
                kind = line.removeprefix("event: ")
            elif line.startswith("data: ") and kind == "packet":
                shown.append(json.loads(line.removeprefix("data: ")))


async def until(condition: Callable[[], Awaitable[bool]], what: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not await condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        await asyncio.sleep(0.2)


def scalar(url: str, query: str) -> int:
    with create_engine(url).connect() as c:
        return int(c.execute(text(query)).scalar_one())


def frames_of(url: str, address: int) -> list[bytes]:
    """The vehicle's frames in the order they were stored."""
    with create_engine(url).connect() as c:
        rows = c.execute(text("SELECT data FROM frame WHERE src = :a ORDER BY id"), {"a": address}).all()
    return [bytes(data) for (data,) in rows]


def test_two_center_processes_share_the_vehicles_and_one_takes_over_when_the_other_dies(
    secured: Secured, postgres_server: str, tmp_path: Path
) -> None:
    with postgres_database(postgres_server) as url:
        migrate(url)  # before both start: they would both migrate an empty database at once
        centers = [CenterProcess(name, url, secured, tmp_path) for name in ("alpha", "bravo")]
        try:
            asyncio.run(_scenario(centers, url, secured, tmp_path))
        except BaseException:
            for center in centers:
                print(f"--- {center.name}:\n{center.log.read_text()[-6000:]}")
            raise
        finally:
            for center in centers:
                center.stop()


async def _scenario(centers: list[CenterProcess], url: str, broker: Secured, tmp_path: Path) -> None:
    alpha, bravo = centers

    async def shared() -> bool:
        if not all([await c.answers() for c in centers]):
            return False
        held = [await c.metric("tacit_center_partitions") for c in centers]
        roles = [await c.metric("tacit_center_coordinator") for c in centers]
        return held == [subjects.PARTITIONS / 2] * 2 and sorted(roles) == [0.0, 1.0]

    await until(shared, "the two processes to share the partitions, one coordinating")
    keys: dict[int, bytes] = {}
    ids: dict[int, int] = {}
    for address in ADDRESSES:
        answer = await alpha.api.post("/api/v1/vehicles", json={"name": f"auv{address}", "address": address})
        assert answer.status_code == 201, answer.text
        keys[address], ids[address] = bytes.fromhex(answer.json()["key"]), int(answer.json()["id"])

    shown: list[dict[str, object]] = []  # the packet events a browser on bravo's event stream gets
    browser = asyncio.create_task(follow(bravo, shown))
    outbox = Outbox(tmp_path / "ship.db", "ship")
    gateway = Gateway(outbox, broker.url, heartbeat=0.2, auth=broker.credentials("gateway-ship"))
    await gateway.start()
    heard: dict[int, list[bytes]] = {a: [] for a in ADDRESSES}
    start = int(time.time()) - 100

    def hear(rounds: range) -> None:
        """Each vehicle's signed check-points, one per round, as the ship's modem hears them."""
        for n in rounds:
            for address in ADDRESSES:
                cp = CheckpointPacket(seq=n, time=start + n, state=MissionState.PREPROGRAMMED)
                data = auth.sign_checkpoint(cp, keys[address], 1, address, [])
                outbox.add_frame(address, 0, data, rate=0, snr_in=12.0, at=time.time())
                heard[address].append(data)

    def verified() -> int:
        return scalar(url, "SELECT count(*) FROM packet WHERE auth = 'verified'")

    async def all_verified() -> bool:
        return verified() == sum(len(h) for h in heard.values())

    async def command(center: CenterProcess, address: int) -> int:
        answer = await center.api.post(f"/api/v1/vehicles/{ids[address]}/commands", json={"command": "hold"})
        assert answer.status_code == 202, answer.text
        return int(answer.json()["id"])

    def at_the_gateway() -> list[str]:
        return [c.id for c in outbox.commands() if c.id.startswith("cmd-")]

    try:
        hear(range(3))  # saved with the vehicles' first batches ...
        await until(all_verified, "the first check-points, decoded and verified")
        hear(range(3, 5))  # ... these not (every 30 s): the survivor replays them when it takes over
        await until(all_verified, "the next check-points")
        each = [await c.metric('tacit_ingest_total{counter="verified"}') for c in centers]
        assert each == [15.0, 15.0]  # each process decoded its three vehicles' (partitions 2, 4, 6; 1, 3, 5)

        async def every_vehicle_shown() -> bool:
            return {e["vehicle"] for e in shown} == {f"auv{a}" for a in ADDRESSES}

        await until(every_vehicle_shown, "bravo's browser to be shown alpha's vehicles' packets too")
        first = await command(bravo, 2)  # through either API: the process decoding auv2 dispatches it

        async def first_arrived() -> bool:
            return at_the_gateway() == [f"cmd-{first}-1"]

        await until(first_arrived, "the first command at the gateway")
        coordinator = alpha if await alpha.metric("tacit_center_coordinator") == 1.0 else bravo
        survivor = bravo if coordinator is alpha else alpha

        async def budgets_held() -> bool:
            return sorted(b.address for b in outbox.budgets()) == list(ADDRESSES)

        await until(budgets_held, "every vehicle's SYNC budget at the gateway")
        signed = "pre-signed SYNCs to ship"  # the SYNC budgets: the coordinator's alone
        assert signed in coordinator.log.read_text() and signed not in survivor.log.read_text()
        coordinator.kill()  # its leases are left to expire
        hear(range(5, 10))
        second = await command(survivor, 1)

        async def taken_over() -> bool:
            held = await survivor.metric("tacit_center_partitions")
            return held == subjects.PARTITIONS and await survivor.metric("tacit_center_coordinator") == 1.0

        await until(taken_over, "the survivor to take every partition and the coordinator's role")

        async def budgets_renewed() -> bool:  # the new coordinator starts its budgets afresh
            return signed in survivor.log.read_text()

        await until(budgets_renewed, "the survivor to hand out the SYNC budgets")
        await until(all_verified, "every check-point, decoded and verified")

        async def second_arrived() -> bool:
            return at_the_gateway() == [f"cmd-{first}-1", f"cmd-{second}-1"]

        await until(second_arrived, "the second command at the gateway")
        await asyncio.sleep(2.0)  # anything stored or dispatched twice would come now
        for address in ADDRESSES:
            assert frames_of(url, address) == heard[address]  # each once, in order
        assert scalar(url, "SELECT count(*) FROM packet") == verified() == 60  # decoded once, all verified
        assert at_the_gateway() == [f"cmd-{first}-1", f"cmd-{second}-1"]
        assert scalar(url, "SELECT count(*) FROM dispatch") == 2  # commands dispatched once each
    finally:
        browser.cancel()
        await asyncio.gather(browser, return_exceptions=True)
        await gateway.stop()
        for center in centers:
            await center.api.aclose()


def test_a_second_center_process_joins_its_deployment_or_refuses_in_one_line(
    secured: Secured, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """With a process "alpha" of the (unnamed) deployment running on one database: another name on the
    same database joins; alpha's name again, or another database, is refused in one line before
    anything starts."""
    from tacit.cli import main

    ours, other = (f"sqlite:///{tmp_path}/{name}.db" for name in ("center", "other"))
    migrate(ours)
    auth = secured.credentials("center")

    async def scenario() -> list[str | None]:
        alpha = Center(
            ingest_on(ours), secured.url, auth=auth, instance="alpha", database=database_identity(ours)
        )
        await alpha.connect()
        try:
            answers = [
                await refusal(secured.url, auth, UNNAMED, name, database_identity(url))
                for name, url in (("bravo", ours), ("alpha", ours), ("bravo", other))
            ]
            cli = ["center", "--nats", secured.url, "--nats-credentials", str(secured.credentials_file("center")),
                   "--instance", "bravo", "--database-url", other, "--no-map"]  # fmt: skip
            assert await asyncio.to_thread(main, cli) == 2
            return answers
        finally:
            await alpha.close()

    joins, same_name, other_database = asyncio.run(scenario())
    assert joins is None
    assert same_name is not None and "named 'alpha' runs already" in same_name
    assert other_database is not None and "one database per deployment" in other_database
    assert capsys.readouterr().err.count("\n") == 1
