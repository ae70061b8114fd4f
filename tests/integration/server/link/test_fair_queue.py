"""Fair queues: a vehicle's queue of commands is bounded (429 with Retry-After), and polling for data
keeps its share of the vehicle's slots however many commands wait, or forged packets ask for restarts."""

from __future__ import annotations

import asyncio
from pathlib import Path

from fastapi.testclient import TestClient

from server.app import create_app
from server.commands.schemas import CommandIn
from server.link.state import IncomingFrame
from tacit import auth
from tacit import modem as mm
from tacit.packets import SYNC_RESTART_CHAINS, Stream
from tacit.streams import default_streams
from tests.support.api import OP, offline_settings
from tests.support.shore import AckingModem, scripted_shore
from vehicle_agent.compressor import Compressor

KEY = bytes.fromhex("11" * 32)


def test_polls_keep_their_share_while_many_commands_wait(tmp_path: Path) -> None:
    shore = scripted_shore(tmp_path, [KEY.hex()], max_queued_commands=500, command_share=3)
    settings = shore.settings
    for _ in range(100):
        shore.commands.submit(1, CommandIn(command="hold"), "tester")
    link, modem = shore.link, AckingModem()
    link.driver = modem  # type: ignore[assignment]
    (vehicle,) = shore.ingest.states()

    async def slots(n: int) -> None:
        for _ in range(n):
            await link._slot(vehicle)

    asyncio.run(slots(40))
    assert link.counters["polls"] == modem.polls >= 40 // (settings.command_share + 1) - 1
    assert (
        link.delivery.counters["commands_sent"]
        >= 40 * settings.command_share // (settings.command_share + 1) - 2
    )
    assert shore.commands.pending(1) > 0  # commands were still waiting all along


def test_a_full_queue_answers_429_with_retry_after(tmp_path: Path) -> None:
    settings = offline_settings(tmp_path, max_queued_commands=3)
    with TestClient(create_app(settings)) as client:
        vehicle = client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP).json()
        url = f"/api/v1/vehicles/{vehicle['id']}/commands"
        for _ in range(3):
            assert client.post(url, json={"command": "hold"}, headers=OP).status_code == 202
        refused = client.post(url, json={"command": "hold"}, headers=OP)
        assert refused.status_code == 429
        assert int(refused.headers["Retry-After"]) >= 1
        assert "rov1 has 3 commands waiting for the link" in refused.json()["detail"]
        assert len(client.get(url, headers=OP).json()) == 3  # nothing was queued


class CollidingModem(AckingModem):
    """A shore modem whose every acknowledgement collides with a second modem's: none is heard."""

    async def send(self, dest: int, frames: list[bytes], **_: object) -> mm.TransmitResult:
        self.sent += frames
        return mm.TransmitResult(dest, len(frames), True)


def unknown_bases(n: int) -> list[bytes]:
    """``n`` genuine priority packets (a recording, replayed), each based on one the shore never heard."""
    compressor, t, out = Compressor(default_streams(), max_latency=5.0, max_silence=5.0), 1.8e9, []
    for i in range(n + 1):
        for _ in range(10):
            t += 1.0
            compressor.add(Stream.ENVIRONMENTAL, t, [20.0 + i, 5.0, 8.0])
        ready = [p for s, p in compressor.ready(t + 100, i) if s is Stream.ENVIRONMENTAL]
        out.append(auth.tag_priority(ready[0].packet, KEY, 2))
        compressor.resolve(i, True)
    return out[1:]  # the first, on the initial state, is never sent


def test_forged_packets_with_an_unknown_base_neither_stop_polling_nor_flood_restart_requests(
    tmp_path: Path,
) -> None:
    """Issue 21, attack 2: a packet whose chain base is unknown (replayed, or a forgery whose tag held)
    asked for a restart; the
    slot of that SYNC did not poll, and the request stood until ACKed, which a second modem prevented:
    polling stopped. Now every slot polls, and the request goes out ``restart_sends`` times at most per
    ``restart_min_interval``."""
    shore = scripted_shore(tmp_path, [KEY.hex()], sync_retry=1e-6, restart_min_interval=1e6)
    settings = shore.settings
    link, modem = shore.link, CollidingModem()
    link.driver = modem  # type: ignore[assignment]
    (vehicle,) = shore.ingest.states()
    heard = shore.ingest.stats["packets"]  # its check-point

    async def slots(forged: list[bytes]) -> None:
        for packet in forged:  # one forged packet before every slot
            await asyncio.to_thread(shore.ingest.handle, IncomingFrame(2, 1, packet))
            await link._slot(vehicle)

    asyncio.run(slots(unknown_bases(20)))
    restarts = [f for f in modem.sent if auth.verify(f, KEY, 2).param_id & SYNC_RESTART_CHAINS]
    assert shore.ingest.stats["packets"] == heard + 20 and modem.polls == link.counters["polls"] == 20
    assert len(restarts) == settings.restart_sends and not vehicle.link.needs_restart


class HeldPoll(AckingModem):
    """A shore modem whose poll is on the air until the test lets it go."""

    def __init__(self) -> None:
        super().__init__()
        self.on_air = asyncio.Event()
        self.release = asyncio.Event()

    async def poll(self, dest: int, **_: object) -> None:
        await super().poll(dest)
        self.on_air.set()
        await self.release.wait()


def test_a_command_queued_during_an_unanswered_poll_goes_next_not_after_the_idle_pause(
    tmp_path: Path,
) -> None:
    """A poll nobody answers ends the round with nothing heard, and the engine pauses for the poll interval:
    a command queued while that poll was on the air must end the pause (it once waited the whole of it,
    30 s by default: bench_link's commands at 3 km took 39 s instead of 9)."""
    shore = scripted_shore(tmp_path, [KEY.hex()], poll_interval=1e7)  # a pause of 1e4 s at 1000x
    link = shore.link

    async def scenario() -> HeldPoll:
        modem = HeldPoll()
        link.driver = modem  # type: ignore[assignment]
        link._loop = asyncio.get_running_loop()
        runner = asyncio.create_task(link._run())
        try:
            await modem.on_air.wait()
            shore.commands.submit(1, CommandIn(command="hold"), "tester")  # wakes the engine
            modem.release.set()  # nobody answers: the poll's window runs out
            while not link.delivery.counters["commands_sent"]:
                await asyncio.sleep(0.01)
            return modem
        finally:
            runner.cancel()

    modem = asyncio.run(asyncio.wait_for(scenario(), 60))  # the pause would be 1e4 s: TimeoutError
    assert modem.release.is_set() and link.delivery.counters["commands_sent"] == 1
