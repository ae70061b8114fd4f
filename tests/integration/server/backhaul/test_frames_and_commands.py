"""The backhaul (issue 24), integration tier: a real nats-server with JetStream, started and stopped by
the tests (to cut the gateways off), the center's store on SQLite and, where it matters, PostgreSQL.

Frames go up once and in order, through a broker outage, a center dying between its commit and its acks,
a gateway's retry after JetStream's de-duplication window, and two gateways hearing one frame.
"""

from __future__ import annotations

import asyncio
import json
import sqlite3
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest
from nats.js.api import PubAck
from sqlalchemy import create_engine, text

from launch.split import throwaway_database as postgres_database
from server.backhaul import subjects
from server.backhaul.center import Center
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.relay import RelayedIncoming, RelayIngest
from server.backhaul.subjects import CommandMessage, FrameMessage, WithdrawMessage, WithdrawReason
from server.core.config import Settings
from server.core.db import make_engine, migrate
from server.core.events import Bus
from tacit.streams import default_streams
from tests.support.nats import NATS_SERVER, NatsServer

ROOT = Path(__file__).resolve().parents[4]  # the repository: its own `server` is the one imported
pytestmark = pytest.mark.skipif(not Path(NATS_SERVER).exists(), reason="nats-server is not installed")


def ingest_on(url: str) -> RelayIngest:
    """A center's ingest on the store at ``url`` (a new one: as a restarted center process)."""
    ingest = RelayIngest(make_engine(url), Bus(), default_streams(), Settings(stranger_frames_kept=10_000))
    ingest.load_vehicles()
    return ingest


def stored(url: str) -> list[tuple[int, bytes, float | None]]:
    """The frames in the center's store, in the order they were stored: (src, data, snr_in)."""
    with create_engine(url).connect() as c:
        rows = c.execute(text("SELECT src, data, snr_in FROM frame ORDER BY id")).all()
    return [(int(src), bytes(data), snr) for src, data, snr in rows]


async def until(
    condition: Callable[[], bool], step: Callable[[], Awaitable[object]], timeout: float = 15.0
) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        await step()


def hear(outbox: Outbox, src: int, n: int, start: int = 0, snr: float = 10.0) -> list[bytes]:
    """The gateway's modem hears ``n`` frames from ``src``; their bytes."""
    data = [f"vehicle {src} frame {i}".encode() for i in range(start, start + n)]
    for d in data:
        outbox.add_frame(src, 0, d, rate=1, snr_in=snr, snr_out=snr - 1, stats={"rate": 1})
    return data


def per_vehicle(rows: list[tuple[int, bytes, float | None]], src: int) -> list[bytes]:
    return [data for s, data, _ in rows if s == src]


def test_frames_reach_the_center_once_and_in_order(
    broker: NatsServer, sqlite_url: str, tmp_path: Path
) -> None:
    async def main() -> None:
        outbox = Outbox(tmp_path / "ship.db", "ship")
        gateway = Gateway(outbox, broker.url, heartbeat=0.2)
        center = Center(ingest_on(sqlite_url), broker.url, batch=8)
        await gateway.start()
        await center.connect()
        try:
            one, two = hear(outbox, 1, 12), hear(outbox, 2, 8)
            await until(lambda: len(stored(sqlite_url)) >= 20, center.step)
            await until(lambda: "ship" in center.gateways, center.step_events)
            rows = stored(sqlite_url)
            assert len(rows) == 20
            assert per_vehicle(rows, 1) == one and per_vehicle(rows, 2) == two
            await until(lambda: outbox.depth() == 0, lambda: asyncio.sleep(0.05))
            assert center.gateways["ship"]["backhaul"] == "up"
        finally:
            await center.close()
            await gateway.stop()

    asyncio.run(main())


def test_a_backhaul_outage_loses_nothing_and_doubles_nothing(
    broker: NatsServer, sqlite_url: str, tmp_path: Path
) -> None:
    async def main() -> None:
        outbox = Outbox(tmp_path / "buoy.db", "buoy")
        gateway = Gateway(outbox, broker.url)
        center = Center(ingest_on(sqlite_url), broker.url, batch=4)
        await gateway.start()
        await center.connect()
        try:
            heard = hear(outbox, 1, 5)
            await until(lambda: len(stored(sqlite_url)) == 5, center.step)
            broker.stop()  # the backhaul is cut: the gateway's modem goes on hearing
            heard += hear(outbox, 1, 10, start=5)
            heard2 = hear(outbox, 2, 3)
            await asyncio.sleep(1.0)
            assert outbox.depth() == 13 and len(stored(sqlite_url)) == 5
            broker.start()
            heard += hear(outbox, 1, 5, start=15)
            await until(lambda: len(stored(sqlite_url)) >= 23, center.step, timeout=25)
            for _ in range(5):  # anything doubled would come now
                await center.step(timeout=0.2)
            rows = stored(sqlite_url)
            assert outbox.stored() == len(rows) == 23  # heard == stored
            assert per_vehicle(rows, 1) == heard and per_vehicle(rows, 2) == heard2
            assert outbox.depth() == 0
        finally:
            await center.close()
            await gateway.stop()

    asyncio.run(main())


class SilentLink:
    """A TCP relay to the broker that can go silent: while ``silent``, it forwards nothing and closes
    nothing (a radio backhaul lost: no reset, no FIN), and new connections hang the same way."""

    def __init__(self, target: str) -> None:
        host, port = target.removeprefix("nats://").rsplit(":", 1)
        self.target = (host, int(port))
        self.silent = False
        self.server: asyncio.Server | None = None

    async def start(self) -> str:
        self.server = await asyncio.start_server(self._join, "127.0.0.1", 0)
        return f"nats://127.0.0.1:{self.server.sockets[0].getsockname()[1]}"

    async def _join(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        upstream, downstream = await asyncio.open_connection(*self.target)
        await asyncio.gather(self._pipe(reader, downstream), self._pipe(upstream, writer))

    async def _pipe(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while data := await reader.read(65536):
                while self.silent:
                    await asyncio.sleep(0.1)
                writer.write(data)
                await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            writer.close()

    async def close(self) -> None:
        if self.server is not None:
            self.server.close()


def test_a_silent_backhaul_cut_is_timed_from_its_start_and_loses_nothing(
    broker: NatsServer, sqlite_url: str, tmp_path: Path
) -> None:
    """The backhaul goes silent (no reset: the client's pings notice it some seconds on): the outage the
    gateway reports lasted as long as the cut (from its first failed publish), and its frames arrive."""
    cut = 20.0

    async def main() -> None:
        link = SilentLink(broker.url)
        outbox = Outbox(tmp_path / "buoy.db", "buoy")
        gateway = Gateway(outbox, await link.start())
        center = Center(ingest_on(sqlite_url), broker.url, batch=4)
        await gateway.start()
        await center.connect()
        try:
            heard = hear(outbox, 1, 3)
            await until(lambda: len(stored(sqlite_url)) == 3, center.step)
            link.silent = True
            heard += hear(outbox, 1, 4, start=3)
            await asyncio.sleep(cut)
            assert gateway.down_since is not None  # noticed within the cut
            link.silent = False
            await until(lambda: len(stored(sqlite_url)) == 7, center.step, timeout=30)
            await until(lambda: gateway.outage is not None, lambda: asyncio.sleep(0.2))
            assert gateway.outage is not None and cut - 3.0 <= gateway.outage.lasted <= cut + 15.0
            assert gateway.outage.backlog == 4
            assert per_vehicle(stored(sqlite_url), 1) == heard
        finally:
            await center.close()
            await gateway.stop()
            await link.close()

    asyncio.run(main())


def test_a_center_dying_before_its_acks_loses_and_doubles_nothing(
    broker: NatsServer, sqlite_url: str, tmp_path: Path
) -> None:
    async def main() -> None:
        outbox = Outbox(tmp_path / "pier.db", "pier")
        gateway = Gateway(outbox, broker.url)
        await gateway.start()
        first = Center(ingest_on(sqlite_url), broker.url, ack_wait=30.0)
        await first.connect()
        try:
            heard = hear(outbox, 1, 10)
            await until(lambda: outbox.depth() == 0, lambda: asyncio.sleep(0.05))
            msgs = await first.subs[subjects.partition(1)].fetch(6, timeout=2)  # consumed and stored ...
            first.ingest.handle_batch([RelayedIncoming.of(FrameMessage.decode(m.data)) for m in msgs])
            assert len(stored(sqlite_url)) == 6
        finally:
            await first.close()  # ... and the center dies before acking
        second = Center(ingest_on(sqlite_url), broker.url, ack_wait=30.0)  # a new process
        await second.connect()  # set back to its ack floor: no 30 s wait for the redeliveries
        try:
            await until(lambda: second.counters["messages"] >= 10, second.step, timeout=10)
            rows = stored(sqlite_url)
            assert per_vehicle(rows, 1) == heard
            assert second.ingest.stats["relayed_duplicates"] == 6
        finally:
            await second.close()
            await gateway.stop()

    asyncio.run(main())


def test_a_retry_after_the_broker_window_is_still_stored_once(broker: NatsServer, sqlite_url: str) -> None:
    async def main() -> None:
        center = Center(ingest_on(sqlite_url), broker.url, duplicate_window=1.0)
        await center.connect()
        assert center.js is not None
        try:
            frame = FrameMessage(
                "ship-0a0b0c0d-1", "ship", 4, 0, b"a frame heard once", snr_in=9.0, at=time.time()
            )

            def publish() -> Awaitable[PubAck]:
                return center.js.publish(
                    subjects.frames("ship", 4), frame.encode(), headers={subjects.MSG_ID: frame.id}
                )

            assert not (await publish()).duplicate
            assert (await publish()).duplicate  # within the window: the broker drops it
            await until(lambda: len(stored(sqlite_url)) == 1, center.step)
            await asyncio.sleep(1.5)  # past the window: the broker takes it again ...
            assert not (await publish()).duplicate
            await until(lambda: center.ingest.stats["relayed_duplicates"] == 1, center.step)
            assert len(stored(sqlite_url)) == 1  # ... and the store drops it
        finally:
            await center.close()

    asyncio.run(main())


def test_two_gateways_hearing_one_frame_store_it_once_with_the_best_snr(
    broker: NatsServer, tmp_path: Path, postgres_server: str
) -> None:
    """On PostgreSQL, as the center runs."""
    with postgres_database(postgres_server) as url:
        migrate(url)

        async def main() -> None:
            ship, buoy = Outbox(tmp_path / "ship.db", "ship"), Outbox(tmp_path / "buoy.db", "buoy")
            gateways = [Gateway(ship, broker.url), Gateway(buoy, broker.url)]
            center = Center(ingest_on(url), broker.url)
            for g in gateways:
                await g.start()
            await center.connect()
            try:
                at = time.time()
                ship.add_frame(3, 0, b"one transmission", snr_in=5.0, at=at)
                buoy.add_frame(3, 0, b"one transmission", snr_in=12.5, at=at + 0.8)  # heard better, later
                ship.add_frame(3, 0, b"only the ship", snr_in=7.0, at=at + 1)
                buoy.add_frame(3, 0, b"one transmission", snr_in=20.0, at=at + 60)  # a retransmission
                await until(lambda: center.counters["messages"] >= 4, center.step)
                rows = stored(url)
                assert sorted(d for _, d, _ in rows) == [
                    b"one transmission",
                    b"one transmission",
                    b"only the ship",
                ]
                assert center.ingest.stats["diversity_copies"] == 1
                with create_engine(url).connect() as c:
                    first = c.execute(
                        text("SELECT id, snr_in FROM frame WHERE data = :d ORDER BY id LIMIT 1"),
                        {"d": b"one transmission"},
                    ).one()
                    kept = (
                        c.execute(
                            text("SELECT gateway FROM relayedframe WHERE frame_id = :f AND kept"),
                            {"f": first.id},
                        )
                        .scalars()
                        .all()
                    )
                assert first.snr_in == 12.5 and kept == ["buoy"]
                assert center.ingest.heard_by(first.id) == 2
            finally:
                await center.close()
                for g in gateways:
                    await g.stop()

        asyncio.run(main())


def test_commands_go_down_once_and_are_kept_by_the_gateway(
    broker: NatsServer, sqlite_url: str, tmp_path: Path
) -> None:
    async def main() -> None:
        outbox = Outbox(tmp_path / "ship.db", "ship")
        gateway = Gateway(outbox, broker.url)
        center = Center(ingest_on(sqlite_url), broker.url)
        await gateway.start()
        await center.connect()
        try:
            await until(lambda: "ship" in center.gateways, center.step_events)  # its consumers made
            command = CommandMessage(
                "cmd-7-1", "ship", address=1, data=b"signed", expires_at=time.time() + 600
            )
            assert await center.send_command(command)
            assert not await center.send_command(command)  # a retry: JetStream drops it
            await until(lambda: bool(outbox.commands()), lambda: asyncio.sleep(0.05))
            assert outbox.commands() == [command]
            await until(lambda: outbox.depth() == 0, lambda: asyncio.sleep(0.05))  # its receipt went up
            withdrawal = WithdrawMessage("withdraw-cmd-7-1", "ship", command.id, WithdrawReason.CANCELLED)
            assert await center.send_command(withdrawal)
            await until(lambda: not outbox.commands(), lambda: asyncio.sleep(0.05))
            assert outbox.commands("withdrawn") == [command]  # kept, never to be sent
        finally:
            await center.close()
            await gateway.stop()

    asyncio.run(main())


def test_the_outbox_ids_survive_a_restart_and_published_frames_are_pruned(tmp_path: Path) -> None:
    outbox = Outbox(tmp_path / "ship.db", "ship", keep=2)
    first = [outbox.add_frame(1, 0, b"x") for _ in range(3)]
    for item in outbox.pending()[:2]:
        outbox.mark_published(item.seq)
    outbox.close()
    again = Outbox(tmp_path / "ship.db", "ship", keep=1)
    assert [p.id for p in again.pending()] == first[2:]  # resumes from the first unpublished
    later = again.add_frame(1, 0, b"y")
    assert later not in first and later.split("-")[1] == first[0].split("-")[1]
    assert again.prune() == 1 and again.stored() == 3
    other = Outbox(tmp_path / "new.db", "ship")  # a lost file: new ids, not the old ones again
    assert other.add_frame(1, 0, b"x") != first[0]


def test_frames_of_the_previous_wire_left_in_an_outbox_go_on_their_partitions(tmp_path: Path) -> None:
    """A gateway upgraded with frames stored on its gateway's subject (no partition) and not published:
    opening the outbox moves them to their partitions' subjects; published ones stay as they were."""
    outbox = Outbox(tmp_path / "ship.db", "ship")
    ids = [outbox.add_frame(src, 0, b"x") for src in (3, 20, 5)]
    outbox.mark_published(outbox.pending()[0].seq)
    outbox.close()
    with sqlite3.connect(tmp_path / "ship.db") as db:
        db.execute("UPDATE outbox SET subject = 'tacit.v1.frames.ship'")
    again = Outbox(tmp_path / "ship.db", "ship")
    assert [(p.id, p.subject) for p in again.pending()] == [
        (ids[1], subjects.frames("ship", 4)),
        (ids[2], subjects.frames("ship", 5)),
    ]
    with sqlite3.connect(tmp_path / "ship.db") as db:
        published = db.execute("SELECT subject FROM outbox WHERE published = 1").fetchall()
    assert published == [("tacit.v1.frames.ship",)]


def test_the_gateway_loads_no_web_stack() -> None:
    code = (
        "import sys, server.backhaul.gateway; "
        "print(sorted(m for m in ('fastapi', 'uvicorn', 'viser', 'sqlmodel', 'sqlalchemy') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("command", ["gateway", "center"])
def test_the_commands_have_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    from tacit.cli import COMMANDS, main

    assert COMMANDS[command].extra == command
    with pytest.raises(SystemExit) as stop:
        main([command, "--help"])
    assert stop.value.code == 0 and "--nats" in capsys.readouterr().out


def test_a_frame_two_gateways_heard_is_decoded_once(sqlite_url: str) -> None:
    """A known vehicle's signed check-point, heard by two gateways: one frame row, one packet, verified
    once (the second copy never reaches the decoder: not even the duplicate window sees it)."""
    from sqlmodel import Session

    from server.vehicles.models import Vehicle
    from tacit import auth
    from tacit.packets import CheckpointPacket, MissionState

    key, address = bytes(range(32)), 2
    with Session(make_engine(sqlite_url)) as s:
        s.add(Vehicle(name="rov1", address=address, key_hex=key.hex(), next_seq=1))
        s.commit()
    ingest = ingest_on(sqlite_url)
    cp = CheckpointPacket(seq=0, time=int(time.time()), state=MissionState.PREPROGRAMMED)
    data, at = auth.sign_checkpoint(cp, key, 1, address, []), time.time()
    copies = [
        FrameMessage(f"{g}-0a0b0c0d-1", g, address, 0, data, snr_in=snr, at=at + lag)
        for g, snr, lag in (("ship", 4.0, 0.0), ("buoy", 9.0, 0.5), ("pier", 6.0, 1.0))
    ]
    ingest.handle_batch([RelayedIncoming.of(copies[0]), RelayedIncoming.of(copies[1])])
    ingest.handle_batch([RelayedIncoming.of(copies[2]), RelayedIncoming.of(copies[1])])  # and a redelivery
    assert [snr for _, _, snr in stored(sqlite_url)] == [9.0]
    with create_engine(sqlite_url).connect() as c:
        assert c.execute(text("SELECT count(*) FROM packet")).scalar_one() == 1
    assert ingest.stats["verified"] == 1 and ingest.stats["packets"] == 1 and ingest.stats["duplicates"] == 0
    assert ingest.stats["diversity_copies"] == 2 and ingest.stats["relayed_duplicates"] == 1
    assert ingest.heard_by(1) == 3


def test_a_message_twice_in_one_batch_is_stored_once(sqlite_url: str) -> None:
    """The batch's message ids are read once, before its first frame: the same message twice in one batch
    (a gateway's retry beside the original) is still one frame, and the redelivery after it is dropped."""
    ingest = ingest_on(sqlite_url)
    message = RelayedIncoming.of(FrameMessage("ship-0a0b0c0d-1", "ship", 9, 0, bytes(range(1, 33)), at=1.0))
    ingest.handle_batch([message, message])
    ingest.handle_batch([message])
    assert len(stored(sqlite_url)) == 1 and ingest.stats["relayed_duplicates"] == 2


def test_a_gateway_on_a_modem_relays_what_it_hears_and_sends_what_it_is_given(
    broker: NatsServer, sqlite_url: str, tmp_path: Path
) -> None:
    """A scripted Micro-Modem on a pty: a frame it hears reaches the center with its statistics; a
    command from the center is sent in a data cycle and its ACK goes up as the attempt's outcome."""
    from simulators.scripted_modem import ScriptedModem, default_rule
    from tacit import modem as mm
    from tacit import nmea

    def rule(modem: ScriptedModem, sentence: nmea.Sentence | nmea.Raw) -> list[str]:
        replies = default_rule(modem, sentence)
        if isinstance(sentence, nmea.Cycle) and sentence.src == 0:
            replies.append(
                nmea.DataRequest("120000", sentence.src, sentence.dest, sentence.ack, 32, 1).line()
            )
        if isinstance(sentence, nmea.TxData) and sentence.data:
            replies += [
                nmea.TxStarted(len(sentence.data)).line(),
                nmea.TxFinished(len(sentence.data)).line(),
                nmea.Ack(sentence.dest, sentence.src, 1, 1).line(),
            ]
        return replies

    modem = ScriptedModem(tmp_path / "modem", rule)
    cst = "CACST,0,223413.0000,0,1440,25,0175,0166,75,01,01,01,03,1,007,006,0,3,3,0,146,03,04,-100,-1,000,-1.2,45,10000,2000"

    async def main() -> None:
        driver = mm.ModemDriver(
            mm.DriverSettings(url=str(modem.path), address=0, echo_timeout=0.3, keepalive=0.3)
        )
        outbox = Outbox(tmp_path / "ship.db", "ship")
        gateway = Gateway(outbox, broker.url, driver)
        center = Center(ingest_on(sqlite_url), broker.url)
        await gateway.start()
        await center.connect()
        try:
            await until(lambda: driver.state is mm.LinkState.READY, lambda: asyncio.sleep(0.05))
            modem.send(nmea.RxData(2, 0, False, 1, b"\x01" * 32).line())
            modem.send(f"${cst}*{nmea.checksum(cst)}\r\n")
            await until(lambda: len(stored(sqlite_url)) == 1, center.step)
            assert stored(sqlite_url) == [(2, b"\x01" * 32, 3.0)]  # $CACST: SNR in 3, out 4
            await until(lambda: "ship" in center.gateways, center.step_events)  # its consumers made
            command = CommandMessage("cmd-1-1", "ship", address=2, data=b"signed command", ack_timeout=2.0)
            assert await center.send_command(command)
            await until(lambda: outbox.commands("acked") == [command], lambda: asyncio.sleep(0.05))
        finally:
            await center.close()
            await gateway.stop()

    try:
        asyncio.run(main())
    finally:
        modem.close()
    with sqlite3.connect(tmp_path / "ship.db") as db:
        events = [
            json.loads(p) for (p,) in db.execute("SELECT payload FROM outbox WHERE subject LIKE '%events%'")
        ]
    outcomes = [e["detail"]["outcome"] for e in events if e["kind"] == "attempt"]
    assert outcomes == ["stored", "acked", "acked"]  # the attempt, then the final outcome
    assert any(e["kind"] == "modem" and e["detail"]["state"] == "ready" for e in events)


def test_a_frame_on_another_gateways_subject_is_refused(broker: NatsServer, sqlite_url: str) -> None:
    async def main() -> None:
        center = Center(ingest_on(sqlite_url), broker.url)
        await center.connect()
        assert center.js is not None
        try:
            forged = FrameMessage("buoy-0a0b0c0d-1", "buoy", 4, 0, b"passed off", at=time.time())
            await center.js.publish(
                subjects.frames("ship", 4), forged.encode(), headers={subjects.MSG_ID: forged.id}
            )
            await center.js.publish(subjects.frames("ship", 4), b"not json", headers={subjects.MSG_ID: "x"})
            await until(lambda: center.counters["malformed"] == 2, center.step)
            assert stored(sqlite_url) == []
        finally:
            await center.close()

    asyncio.run(main())
