"""The broker is no back door: a real nats-server with the accounts ``tacit broker-config`` writes. A
stranger is refused; a gateway publishes only its own frames and events, reads only its own commands and
schedule, makes no consumer and touches no stream, and no reply or deliver subject it names reaches beyond
its own account; two deployments share a broker and nothing else; the center's guard refuses bad input,
logged and counted, and goes on."""

from __future__ import annotations

import asyncio
import contextlib
import json
import shutil
import stat
import time
from pathlib import Path

import nats
import pytest
from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.errors import Error as NatsError
from nats.js import JetStreamContext

from server.backhaul import access, subjects
from server.backhaul.center import Center
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.subjects import (
    UNNAMED,
    CommandMessage,
    Deployment,
    EventMessage,
    FrameMessage,
    ScheduleMessage,
)
from server.core.db import migrate
from tests.integration.server.backhaul.test_frames_and_commands import hear, ingest_on, stored, until
from tests.support.nats import NATS_SERVER, NatsServer, Secured, certificates

pytestmark = pytest.mark.skipif(not Path(NATS_SERVER).exists(), reason="nats-server is not installed")


async def client(server: Secured, user: str, errors: list[str] | None = None) -> Client:
    """A raw client as ``user`` (its permission errors collected in ``errors``)."""

    async def error(exc: Exception) -> None:
        if errors is not None:
            errors.append(str(exc))

    options = server.credentials(user).options()
    return await nats.connect(server.url, error_cb=error, allow_reconnect=False, **options)


def test_a_stranger_or_a_wrong_password_is_refused(secured: Secured) -> None:
    async def main() -> None:
        for options in ({}, {"user": "gateway-ship", "password": "guessed"}, {"user": "admin"}):
            with pytest.raises(NatsError, match="Authorization Violation"):
                await nats.connect(secured.url, allow_reconnect=False, connect_timeout=2, **options)

    asyncio.run(main())


def test_gateways_and_the_center_work_with_their_credentials(
    secured: Secured, sqlite_url: str, tmp_path: Path
) -> None:
    """The gateway starts first and waits for the center to create the streams (it may not)."""

    async def main() -> None:
        outbox = Outbox(tmp_path / "ship.db", "ship")
        gateway = Gateway(outbox, secured.url, heartbeat=0.2, auth=secured.credentials("gateway-ship"))
        center = Center(ingest_on(sqlite_url), secured.url, auth=secured.credentials("center"))
        await gateway.start()
        heard = hear(outbox, 1, 5)
        await center.connect()
        try:
            await until(lambda: len(stored(sqlite_url)) == 5, center.step)
            assert [d for _, d, _ in stored(sqlite_url)] == heard
            await until(lambda: "ship" in center.gateways, center.step_events)  # its consumers made
            command = CommandMessage(
                "cmd-1-1", "ship", address=1, data=b"signed", expires_at=time.time() + 60
            )
            assert await center.send_command(command)
            await until(lambda: outbox.commands() == [command], lambda: asyncio.sleep(0.05))
            assert center.js is not None
            for consumer in access.gateway_consumers("ship"):  # the center's, none of the gateway's own
                info = await center.js.consumer_info(consumer.stream, consumer.name)
                assert info.config.description and info.config.description.startswith("gateway ship")
            assert center.guard.refused == {}
        finally:
            await center.close()
            await gateway.stop()

    asyncio.run(main())


def test_a_gateway_cannot_publish_as_another_or_send_commands(secured: Secured, sqlite_url: str) -> None:
    async def main() -> None:
        center = Center(ingest_on(sqlite_url), secured.url, auth=secured.credentials("center"))
        await center.connect()
        errors: list[str] = []
        ship = await client(secured, "gateway-ship", errors)
        js = ship.jetstream(timeout=0.5)
        try:
            own = FrameMessage("ship-0a0b0c0d-1", "ship", 3, 0, b"the ship's", at=time.time())
            await js.publish(subjects.frames("ship", 3), own.encode(), headers={subjects.MSG_ID: own.id})
            forged = FrameMessage("buoy-0a0b0c0d-1", "buoy", 3, 0, b"passed off", at=time.time())
            command = CommandMessage("cmd-9-1", "ship", address=3, data=b"unsigned")
            for subject, payload in (
                (subjects.frames("buoy", 3), forged.encode()),
                (subjects.events("buoy"), EventMessage("buoy-x-1", "buoy", "modem", time.time()).encode()),
                (subjects.commands("ship"), command.encode()),
                (subjects.commands("buoy"), command.encode()),
            ):
                with pytest.raises(NatsError):  # JetStream never answers: the broker dropped it
                    await js.publish(subject, payload, timeout=0.5)
            for stream in (subjects.FRAMES_STREAM, subjects.COMMANDS_STREAM):
                with pytest.raises(NatsError):
                    await js.delete_stream(stream)  # nor may it touch the streams
            await until(lambda: len(stored(sqlite_url)) == 1, center.step)
            for _ in range(3):
                await center.step(timeout=0.2)
            assert stored(sqlite_url) == [(3, b"the ship's", None)]
            assert center.js is not None
            assert (await center.js.stream_info(subjects.COMMANDS_STREAM)).state.messages == 0
            assert sum("permissions violation for publish" in e for e in errors) == 6
        finally:
            await ship.close()
            await center.close()

    asyncio.run(main())


def test_a_gateway_cannot_read_another_gateways_commands(
    secured: Secured, sqlite_url: str, tmp_path: Path
) -> None:
    async def main() -> None:
        center = Center(ingest_on(sqlite_url), secured.url, auth=secured.credentials("center"))
        await center.connect()
        errors: list[str] = []
        ship = await client(secured, "gateway-ship", errors)
        snooped: list[str] = []

        async def snoop(msg: object) -> None:
            snooped.append(str(msg))

        for subject in (subjects.commands(">"), "_INBOX.>", "$JS.>", ">"):
            await ship.subscribe(subject, cb=snoop)
        buoy = Gateway(
            Outbox(tmp_path / "buoy.db", "buoy"),
            secured.url,
            heartbeat=0.2,
            auth=secured.credentials("gateway-buoy"),
        )
        await buoy.start()
        try:
            await until(lambda: "buoy" in center.gateways, center.step_events)
            command = CommandMessage("cmd-2-1", "buoy", address=4, data=b"for the buoy only")
            assert await center.send_command(command)
            await until(lambda: buoy.outbox.commands() == [command], lambda: asyncio.sleep(0.05))
            for prefix in ("$JS.API", access.GATEWAY_API):  # the server's API, and the center's it imports
                js = ship.jetstream(prefix=prefix, timeout=0.5)
                with pytest.raises(NatsError):  # the buoy's consumer
                    await js.consumer_info(subjects.COMMANDS_STREAM, "gateway-buoy")
                for durable in ("gateway-ship", "mine"):  # its own consumer's name, another's: none is made
                    with pytest.raises(NatsError):
                        await js.pull_subscribe(
                            subjects.commands("buoy"), durable=durable, stream=subjects.COMMANDS_STREAM
                        )
            await asyncio.sleep(0.3)
            assert snooped == []
            assert sum("permissions violation for subscription" in e for e in errors) == 4
        finally:
            await buoy.stop()
            await ship.close()
            await center.close()

    asyncio.run(main())


def test_a_gateway_cannot_read_another_gateways_schedule(
    secured: Secured, sqlite_url: str, tmp_path: Path
) -> None:
    """The center hands the buoy its slots; the ship gets them by no way, not even through a consumer of
    its own name; the buoy gets its own, also after a restart (its consumer made anew at the last one)."""

    async def main() -> None:
        center = Center(ingest_on(sqlite_url), secured.url, auth=secured.credentials("center"))
        await center.connect()
        errors: list[str] = []
        ship = await client(secured, "gateway-ship", errors)
        snooped: list[str] = []

        async def snoop(msg: object) -> None:
            snooped.append(str(msg))

        await ship.subscribe(subjects.schedule(">"), cb=snoop)
        js = ship.jetstream(prefix=access.GATEWAY_API, timeout=0.5)
        auth = secured.credentials("gateway-buoy")
        buoy = Gateway(Outbox(tmp_path / "buoy.db", "buoy"), secured.url, heartbeat=0.2, auth=auth)
        schedule = ScheduleMessage("schedule-1-buoy", "buoy", time.time(), 2.0, 0.1, ("buoy", "ship"), (4,))
        await center.publish(subjects.schedule("buoy"), schedule.encode(), schedule.id)
        await buoy.start()
        try:
            await until(lambda: "buoy" in center.gateways, center.step_events)
            await until(lambda: buoy.polls == (4,), lambda: asyncio.sleep(0.05))
            await buoy.stop()  # a restart reads the last schedule kept for it, the center or not
            await center.close()
            buoy = Gateway(Outbox(tmp_path / "buoy.db", "buoy"), secured.url, auth=auth)
            await buoy.start()
            await until(lambda: buoy.polls == (4,), lambda: asyncio.sleep(0.05))
            for name in ("schedule-buoy", "schedule-ship"):
                with pytest.raises(NatsError):  # the buoy's consumer; its own name on the buoy's subject
                    await js.pull_subscribe(
                        subjects.schedule("buoy"), durable=name, stream=subjects.SCHEDULE_STREAM
                    )
            with pytest.raises(NatsError):  # an ordered consumer (an ephemeral one, unfiltered subject)
                await js.subscribe(
                    subjects.schedule("buoy"), stream=subjects.SCHEDULE_STREAM, ordered_consumer=True
                )
            with pytest.raises(NatsError):  # nor read the buoy's last one directly
                await js.get_last_msg(subjects.SCHEDULE_STREAM, subjects.schedule("buoy"), direct=True)
            for name in ("schedule-buoy", "schedule-ship"):  # nor delete a consumer, even its own
                with pytest.raises(NatsError):
                    await js.delete_consumer(subjects.SCHEDULE_STREAM, name)
            await asyncio.sleep(0.3)
            assert snooped == []
            assert sum("permissions violation for subscription" in e for e in errors) == 1
        finally:
            await buoy.stop()
            await ship.close()

    asyncio.run(main())


def _forbidden(bucket: str) -> list[str]:
    """The subjects a gateway's request must never reach, as reply or deliver subject: the other
    gateway's and its own down subjects, the center's leases and live events, the stream and consumer
    API, the center's acks and inbox."""
    frames, commands = subjects.FRAMES_STREAM, subjects.COMMANDS_STREAM
    return [
        subjects.frames("buoy", 4), subjects.events("buoy"), subjects.commands("buoy"),
        subjects.commands("ship"), subjects.schedule("buoy"), subjects.schedule("ship"),
        subjects.syncs("buoy", 4), subjects.syncs("ship", 4), subjects.live("c1"),
        f"$KV.{bucket}.coordinator", f"$KV.{bucket}.partition.4", f"$KV.{bucket}.member.c1",
        f"$JS.API.STREAM.DELETE.{frames}", f"$JS.API.STREAM.PURGE.{frames}",
        f"$JS.API.CONSUMER.DELETE.{frames}.{bucket}-4", f"$JS.API.CONSUMER.DELETE.{commands}.gateway-buoy",
        f"$JS.ACK.{frames}.{bucket}-4.1.1.1.0.0", "_INBOX.center.x",
    ]  # fmt: skip


def _requests(forbidden: list[str]) -> list[tuple[str, bytes]]:
    """Every request the ship's account may send (its imports, wildcards filled in) with payloads that
    pull, ack, read and publish, and the consumer creations it may not, each with a deliver subject."""
    frame = FrameMessage("ship-0a0b0c0d-99", "ship", 4, 0, b"the ship's own", at=time.time())
    pull = json.dumps({"batch": 5, "expires": 200_000_000}).encode()
    requests: list[tuple[str, bytes]] = []
    for subject in access.gateway_requests("ship"):
        if ".MSG.NEXT." in subject:
            requests += [(subject, pull), (subject, b'{"batch": 5, "no_wait": true}')]
        elif subject.startswith("$JS.ACK."):
            requests += [
                (subject.replace(">", f"1.{seq}.1.0.0"), ack) for seq in (1, 2) for ack in (b"+ACK", b"-NAK")
            ]
        elif subject.endswith(".*"):
            requests.append((subject.replace("*", "4"), frame.encode()))
        else:
            requests.append((subject, b""))
    for prefix in ("$JS.API", access.GATEWAY_API):
        for stream in (subjects.COMMANDS_STREAM, subjects.SCHEDULE_STREAM, subjects.FRAMES_STREAM):
            for deliver in forbidden:
                config = {"durable_name": "gateway-ship", "deliver_subject": deliver, "ack_policy": "none"}
                body = json.dumps({"stream_name": stream, "config": config}).encode()
                requests += [
                    (f"{prefix}.CONSUMER.CREATE.{stream}", body),
                    (f"{prefix}.CONSUMER.DURABLE.CREATE.{stream}.gateway-ship", body),
                ]
    return requests  # fmt: skip


async def _control_pull(ship: Client) -> str:
    """One of the ship's commands pulled to its own inbox, as its gateway does; the subject it came on."""
    pulls = [s for s in access.gateway_requests("ship") if ".MSG.NEXT." in s and "gateway-ship" in s]
    inbox = access.inbox_prefix("gateway-ship") + ".control"
    sub = await ship.subscribe(inbox, max_msgs=1)
    await ship.publish(pulls[0], json.dumps({"batch": 1, "expires": 1_000_000_000}).encode(), reply=inbox)
    return (await sub.next_msg(timeout=2)).subject


async def _consumers(js: JetStreamContext) -> dict[str, tuple[str | None, str | None]]:
    """Every consumer of every stream: (its filter subject, its deliver subject) by stream/name."""
    found = {}
    for stream in await js.streams_info():
        for info in await js.consumers_info(stream.config.name):
            found[f"{stream.config.name}/{info.name}"] = (
                info.config.filter_subject,
                info.config.deliver_subject,
            )
    return found


def test_no_request_of_a_gateway_reaches_beyond_its_own_account(
    secured: Secured, sqlite_url: str, tmp_path: Path
) -> None:
    """The ship's credentials send every request its account may send, and those it may not, with every
    reply and deliver subject it must not reach: its pulls do reach its own commands (they are delivered,
    within its account), and nothing else changes: the streams' down subjects hold what the center put
    there, no consumer is made, the center keeps its leases, and it stores every frame the buoy sends
    meanwhile."""

    async def main() -> None:
        center = Center(ingest_on(sqlite_url), secured.url, auth=secured.credentials("center"), instance="c1")
        running = asyncio.create_task(center.run())
        await until(lambda: center.coordinator and len(center.subs) == 16, lambda: asyncio.sleep(0.05))
        assert center.js is not None and center.leases is not None
        gateways = {
            name: Gateway(Outbox(tmp_path / f"{name}.db", name), secured.url, heartbeat=0.2,
                          auth=secured.credentials(f"gateway-{name}"))
            for name in ("ship", "buoy")
        }  # fmt: skip
        for gateway in gateways.values():
            await gateway.start()
        buoy = gateways["buoy"]
        try:
            await until(lambda: set(center.gateways) == {"ship", "buoy"}, lambda: asyncio.sleep(0.05))
            await gateways.pop("ship").stop()  # its consumers made; its credentials now the attacker's
            for i, name in enumerate(("ship", "ship", "buoy")):
                command = CommandMessage(
                    f"cmd-{i}-1", name, address=4, data=b"signed", expires_at=time.time() + 60
                )
                await center.send_command(command)
            await until(lambda: len(buoy.outbox.commands()) == 1, lambda: asyncio.sleep(0.05))
            down = (subjects.COMMANDS_STREAM, subjects.SCHEDULE_STREAM, subjects.SYNCS_STREAM)
            before = [(await center.js.stream_info(s)).state for s in down]
            consumers = await _consumers(center.js)
            heard = hear(buoy.outbox, 4, 10)
            errors: list[str] = []
            ship = await client(secured, "gateway-ship", errors)
            seen: list[str] = []

            async def see(msg: Msg) -> None:
                seen.append(msg.subject)

            watch = await nats.connect(secured.url, **secured.credentials("center").options())
            for subject in (subjects.live("c1"), "_INBOX.center.x"):  # forbidden subjects of core NATS
                await watch.subscribe(subject, cb=see)
            assert await _control_pull(ship) == subjects.commands("ship")  # the way to JetStream is open
            forbidden = _forbidden(center.durable)
            requests = _requests(forbidden)
            received = secured.received("gateway-ship")
            for subject, payload in requests:
                for reply in forbidden:
                    await ship.publish(subject, payload, reply=reply)
                heard += hear(buoy.outbox, 4, 1, start=len(heard))  # the buoy goes on meanwhile
            await ship.flush()
            await until(lambda: len(stored(sqlite_url)) >= len(heard) + 1, lambda: asyncio.sleep(0.1))
            assert secured.received("gateway-ship") - received >= len(requests) * len(
                forbidden
            )  # all reached it
            assert [(await center.js.stream_info(s)).state.messages for s in down] == [
                b.messages for b in before
            ]
            assert [(await center.js.stream_info(s)).state.last_seq for s in down] == [
                b.last_seq for b in before
            ]
            assert await _consumers(center.js) == consumers
            assert center.coordinator and len(center.leases.held) == 17
            kv = await center.js.key_value(center.durable)
            for key in await kv.keys():
                assert json.loads((await kv.get(key)).value or b"")["instance"] == "c1"
            events = await center.js.stream_info(subjects.EVENTS_STREAM, subjects_filter=">")
            assert set(events.state.subjects or {}) == {subjects.events("ship"), subjects.events("buoy")}
            assert sorted(d for s, d, _ in stored(sqlite_url) if d != b"the ship's own") == sorted(heard)
            assert seen == []
            assert sum("permissions violation for publish" in e for e in errors) > 0  # the API's refused
        finally:
            for gateway in gateways.values():
                await gateway.stop()
            running.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await running

    asyncio.run(main())


def test_bad_input_across_the_broker_is_a_logged_refusal(
    broker: NatsServer, sqlite_url: str, caplog: pytest.LogCaptureFixture
) -> None:
    """Malformed messages, a frame on its own gateway's subject with a name no subject has, a frame on
    another partition's subject than its source's, a stranger's frame (stored, not decoded) and a frame
    the pipeline fails on (stored undecoded, alone: the rest of its batch decoded): the center goes on,
    and every frame is stored, in order (each vehicle's: their partitions are consumed side by side)."""

    async def main() -> None:
        center = Center(ingest_on(sqlite_url), broker.url, batch=4)
        await center.connect()
        assert center.js is not None
        good = [
            FrameMessage(f"ship-0a0b0c0d-{i}", "ship", 2, 0, f"good {i}".encode(), at=time.time())
            for i in range(3)
        ]
        bad = [
            b"not json",
            b'{"v": 2, "id": "ship-1-1"}',
            b'{"v": 1, "id": "ship-1-2", "gateway": "ship", "src": 2, "dest": 0, "data": "zz", "at": 1}',
            b'{"v": 1, "id": "ship-1-3", "gateway": "ship", "src": 2, "dest": 0, "data": "00", "at": NaN}',
            b'{"v": 1, "id": "ship-1-4", "gateway": "ship", "src": 2, "dest": 0, "data": "00", "at": 1, "stats": [1]}',
            FrameMessage("ship-" + "9" * 200, "ship", 2, 0, b"an id too long", at=time.time()).encode(),
            FrameMessage("ship-1-5", "ship.x", 2, 0, b"a name no subject has", at=time.time()).encode(),
        ]
        stranger = FrameMessage("ship-0a0b0c0d-9", "ship", 77, 0, b"an unknown vehicle", at=time.time())
        astray = FrameMessage("ship-0a0b0c0d-7", "ship", 3, 0, b"on partition 2", at=time.time())
        poison = FrameMessage("ship-0a0b0c0d-8", "ship", 2, 0, b"poison", at=time.time())
        handle_batch = center.ingest.handle_batch

        def picky(frames: list) -> list:  # a pipeline that fails on one frame, whatever the batch
            if any(f.data == b"poison" for f in frames):
                raise ValueError("the pipeline fails on this one")
            return handle_batch(frames)

        center.ingest.handle_batch = picky  # type: ignore[method-assign]
        try:
            await center.js.publish(subjects.frames("ship", 2), good[0].encode())
            for i, payload in enumerate(bad):
                await center.js.publish(
                    subjects.frames("ship", 2), payload, headers={subjects.MSG_ID: f"bad-{i}"}
                )
            await center.js.publish(subjects.frames("ship", 2), astray.encode())
            for frame in (stranger, poison, *good[1:]):
                part = subjects.partition(frame.src)
                await center.js.publish(subjects.frames("ship", part), frame.encode())
            await until(lambda: center.counters["messages"] >= len(bad) + 6, center.step)
            rows = stored(sqlite_url)
            assert [d for s, d, _ in rows if s == 2] == [
                good[0].data,
                poison.data,
                good[1].data,
                good[2].data,
            ]
            assert [d for s, d, _ in rows if s != 2] == [stranger.data]
            assert center.guard.refused == {"malformed": 6, "foreign": 1, "partition": 1}
            assert center.counters["malformed"] == 8
            assert center.ingest.stats["undecoded"] == 1
            # no vehicle is known here: every frame stored, none decoded
            assert center.ingest.stats["unknown_vehicle"] == 4
        finally:
            await center.close()

    with caplog.at_level("WARNING"):
        asyncio.run(main())
    assert sum("dropped" in r.getMessage() for r in caplog.records) == 8
    assert any("ship-0a0b0c0d-8 (stream seq 11) failed" in r.getMessage() for r in caplog.records)
    assert any("unknown modem address 77" in r.getMessage() for r in caplog.records)


def test_a_gateway_announcing_itself_twice_is_refused_but_its_frames_are_stored(
    broker: NatsServer, sqlite_url: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    async def main() -> None:
        first = Gateway(Outbox(tmp_path / "a.db", "ship"), broker.url, heartbeat=0.2)
        second = Gateway(Outbox(tmp_path / "b.db", "ship"), broker.url, heartbeat=0.2)
        center = Center(ingest_on(sqlite_url), broker.url)
        center.guard.heartbeat = 0.2
        await center.connect()
        await first.start()
        await until(lambda: "ship" in center.gateways, center.step_events)
        await second.start()
        try:
            heard = hear(first.outbox, 1, 2) + hear(second.outbox, 1, 2, start=2)
            await until(lambda: len(stored(sqlite_url)) == 4, center.step)
            await until(lambda: center.guard.refused["twice"] >= 2, center.step_events)
            assert sorted(d for _, d, _ in stored(sqlite_url)) == sorted(heard)
            assert center.gateways["ship"]["incarnation"] == first.outbox.incarnation
            await first.stop()  # gone: after three silent heartbeats the other takes the name
            await until(
                lambda: center.gateways["ship"]["incarnation"] == second.outbox.incarnation,
                center.step_events,
            )
        finally:
            await second.stop()
            await center.close()

    with caplog.at_level("ERROR"):
        asyncio.run(main())
    assert any("announced twice" in r.getMessage() for r in caplog.records)


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is not installed")
def test_over_tls_the_broker_is_reached_with_its_ca_only(tmp_path: Path, sqlite_url: str) -> None:
    ca, cert, key = certificates(tmp_path / "pki")
    server = Secured(tmp_path / "broker", ["ship"], tls=(cert, key))
    server.start()

    async def main() -> None:
        center = Center(ingest_on(sqlite_url), server.url, auth=server.credentials("center", ca))
        await center.connect()  # verified against the CA, streams created
        try:
            gateway = server.credentials("gateway-ship").options()  # no CA: the certificate is not trusted
            with pytest.raises((NatsError, OSError)):
                await nats.connect(server.url, allow_reconnect=False, connect_timeout=2, **gateway)
            plain = server.url.replace("tls://", "nats://")
            with pytest.raises((NatsError, OSError)):
                await nats.connect(plain, allow_reconnect=False, connect_timeout=2, **gateway)
        finally:
            await center.close()

    try:
        asyncio.run(main())
    finally:
        server.stop()


def test_broker_config_writes_private_files_and_keeps_passwords(tmp_path: Path) -> None:
    from tacit.cli import main

    out = tmp_path / "broker"
    assert main(["broker-config", "--gateway", "ship", "--out", str(out), "--store", "/srv/nats"]) == 0
    before = access.BrokerAuth.load(out / "gateway-ship.toml")
    assert main(["broker-config", "--gateway", "ship", "--gateway", "buoy", "--out", str(out)]) == 0
    assert access.BrokerAuth.load(out / "gateway-ship.toml") == before
    assert sorted(p.name for p in out.iterdir()) == [
        "center.toml",
        "gateway-buoy.toml",
        "gateway-ship.toml",
        "nats-server.conf",
    ]
    assert all(stat.S_IMODE(p.stat().st_mode) == 0o600 for p in out.iterdir())
    assert (
        before.user == "gateway-ship"
        and before.password
        and before.password in (out / "nats-server.conf").read_text()
    )
    with pytest.raises(SystemExit):
        main(["broker-config", "--gateway", "a.b", "--out", str(out)])


def test_broker_config_has_help(capsys: pytest.CaptureFixture[str]) -> None:
    from tacit.cli import main

    with pytest.raises(SystemExit) as stop:
        main(["broker-config", "--help"])
    assert stop.value.code == 0 and "--gateway" in capsys.readouterr().out


def test_a_credentials_file_others_may_read_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text(access.credentials_text("center", "secret"))
    path.chmod(0o644)
    with pytest.raises(access.CredentialsError, match="chmod 600"):
        access.BrokerAuth.load(path)


async def _exchange(center: Center, gateway: Gateway, url: str, deployment: Deployment) -> None:
    """Three frames up and a command down between a center and its gateway."""
    heard = hear(gateway.outbox, 1, 3, start=10 * len(deployment.name))
    await until(lambda: "ship" in center.gateways, center.step_events)
    command = CommandMessage(f"cmd-{deployment.name}-1", "ship", address=1, data=deployment.name.encode())
    assert await center.send_command(command)
    await until(lambda: len(stored(url)) == 3, center.step)
    assert [d for _, d, _ in stored(url)] == heard
    await until(lambda: gateway.outbox.commands() == [command], lambda: asyncio.sleep(0.05))


def test_two_deployments_share_a_broker_and_nothing_else(tmp_path: Path) -> None:
    """``tacit broker-config`` run for deployment ``lab`` beside the unnamed one (both with a gateway named
    ship): the first's passwords kept, each center stores only its own gateway's frames, each gateway
    gets only its own center's command, and one's credentials are refused by the other's deployment."""
    server = Secured(tmp_path / "broker", ["ship"])
    lab = Deployment("lab")
    before = server.credentials("gateway-ship")
    server.add(lab, ["ship"])
    assert server.credentials("gateway-ship") == before
    server.start()

    async def main() -> None:
        sides = {}
        for deployment, prefix in ((UNNAMED, ""), (lab, "lab.")):
            url = f"sqlite:///{tmp_path}/{deployment.name or 'unnamed'}.db"
            migrate(url)
            auth = server.credentials(f"{prefix}center")
            center = Center(ingest_on(url), server.url, deployment, auth=auth)
            outbox = Outbox(tmp_path / f"{deployment.name or 'unnamed'}-ship.db", "ship")
            gateway = Gateway(outbox, server.url, heartbeat=0.2, auth=server.credentials(f"{prefix}gateway-ship"),
                              deployment=deployment)  # fmt: skip
            await center.connect()
            await gateway.start()
            sides[deployment] = (center, gateway, url)
        try:
            for deployment, (center, gateway, url) in sides.items():
                await _exchange(center, gateway, url, deployment)
            for center, _, url in sides.values():
                for _ in range(3):
                    await center.step(timeout=0.2)
                assert len(stored(url)) == 3
            with pytest.raises(access.CredentialsError, match="deployment 'lab'"):
                access.client_auth("x", str(server.credentials_file("lab.center")), None, False, UNNAMED)
        finally:
            for center, gateway, _ in sides.values():
                await gateway.stop()
                await center.close()

    try:
        asyncio.run(main())
    finally:
        server.stop()


def test_a_client_without_credentials_refuses_to_start_unless_insecure(
    capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    from tacit.cli import main

    assert main(["gateway", "--name", "ship", "--nats", "nats://127.0.0.1:1"]) == 2
    assert "no broker credentials" in capsys.readouterr().err
    with caplog.at_level("WARNING"):
        assert access.client_auth("tacit gateway ship", None, None, True, UNNAMED) == access.BrokerAuth()
    assert any("INSECURE" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize(
    ("values", "said"),
    [({}, None), ({"nats_insecure": True}, "insecure"), ({"nats_credentials": "center.toml"}, "accounts")],
)
def test_the_health_route_says_how_the_center_reaches_its_broker(
    tmp_path: Path, values: dict[str, object], said: str | None
) -> None:
    from fastapi.testclient import TestClient

    from server.app import create_app
    from server.core.config import Settings

    settings = Settings(database_url=f"sqlite:///{tmp_path}/t.db", map_enabled=False, **values)  # type: ignore[arg-type]
    with TestClient(create_app(settings)) as client:
        assert client.get("/api/v1/health").json()["broker"] == said
