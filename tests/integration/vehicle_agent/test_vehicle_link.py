"""The vehicle's half of the link on a real pty, with a scripted Micro-Modem speaking the real dialect:
polls answered with queued packets (time-sensitive first, as many as the frame holds), resent until the
shore's ACK, reported lost after the attempts; control packets only with a valid MAC, once."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

from simulators.scripted_modem import ScriptedModem
from tacit import auth, nmea
from tacit.modem import DriverSettings, ModemDriver
from tacit.packets import CheckpointPacket, Command, ControlPacket, MissionState
from vehicle_agent.link import VehicleLink

SHORE, VEHICLE = 1, 2
KEY = bytes(range(32))


def report(seq: int) -> bytes:
    return CheckpointPacket(seq=seq, time=1_800_000_000 + seq, state=MissionState.HOLDING).encode()


def poll(modem: ScriptedModem, maxbytes: int = 32, frame: int = 1, shore: int = SHORE) -> None:
    """The vehicle's modem heard the shore's poll: it asks its host for a frame."""
    modem.send(nmea.DataRequest("000000", VEHICLE, shore, True, maxbytes, frame).line(nmea.MODEM))


def answers(modem: ScriptedModem) -> list[bytes]:
    return [s.data for s in modem.received if isinstance(s, nmea.TxData)]


async def until(predicate: Callable[[], object], timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "condition not reached"
        await asyncio.sleep(0.01)


def scenario(
    tmp_path: Path,
    body: Callable[[ScriptedModem, VehicleLink], Awaitable[None]],
    shore: int | list[int] = SHORE,
) -> None:
    modem = ScriptedModem(tmp_path / "modem")

    async def run() -> None:
        driver = ModemDriver(
            DriverSettings(url=str(modem.path), address=VEHICLE, echo_timeout=0.5, keepalive=60)
        )
        await driver.start()
        link = VehicleLink(driver, auth.ControlReceiver(KEY, VEHICLE), shore, attempts=2)
        try:
            await body(modem, link)
        finally:
            await driver.stop()

    try:
        asyncio.run(asyncio.wait_for(run(), 30))
    finally:
        modem.close()


def test_polls_take_urgent_packets_first_and_as_many_as_the_frame_holds(tmp_path: Path) -> None:
    async def body(modem: ScriptedModem, link: VehicleLink) -> None:
        link.send(report(1))
        link.send(report(2))
        link.send(report(3), urgent=True)
        poll(modem, maxbytes=64)  # a rate-1 frame: two packets
        await until(lambda: answers(modem))
        assert answers(modem)[0] == report(3) + report(1)
        assert [data for _, data in link.pending()] == [report(3), report(1), report(2)]  # none ACKed yet

    scenario(tmp_path, body)


def test_a_split_shore_polls_and_acknowledges_from_any_of_its_gateways_and_no_one_else(
    tmp_path: Path,
) -> None:
    async def body(modem: ScriptedModem, link: VehicleLink) -> None:
        results: list[bool] = []
        link.send(report(1), on_result=results.append)
        poll(modem, shore=9)  # a modem that is not one of the shore's: an empty answer
        poll(modem, shore=11)  # the second gateway's
        await until(lambda: len(answers(modem)) == 2)
        assert answers(modem) == [b"", report(1)]
        modem.send(nmea.Ack(11, VEHICLE, 1).line(nmea.MODEM))
        await until(lambda: results == [True])

    scenario(tmp_path, body, shore=[SHORE, 11])


def test_a_packet_is_resent_until_acked_then_reported_lost(tmp_path: Path) -> None:
    async def body(modem: ScriptedModem, link: VehicleLink) -> None:
        results: list[bool] = []
        link.send(report(1), on_result=results.append)
        link.send(report(2), on_result=results.append)
        poll(modem)
        await until(lambda: len(answers(modem)) == 1)
        modem.send(nmea.Ack(SHORE, VEHICLE, 1).line(nmea.MODEM))  # the shore's modem ACKed frame 1
        await until(lambda: results == [True])
        for attempt in range(2):  # report 2: sent, never acknowledged, sent again, then given up
            poll(modem)
            await until(lambda n=attempt: len(answers(modem)) == n + 2)
        assert answers(modem)[1:] == [report(2), report(2)]  # byte for byte: the shore drops the copy
        poll(modem)
        await until(lambda: results == [True, False])
        assert link.pending() == [] and link.counters["lost"] == 1

    scenario(tmp_path, body)


def test_control_packets_need_the_key_and_run_once(tmp_path: Path) -> None:
    async def body(modem: ScriptedModem, link: VehicleLink) -> None:
        taken: list[ControlPacket] = []
        repeats: list[int] = []
        link.on_control, link.on_repeat = taken.append, repeats.append
        genuine = auth.sign(ControlPacket(Command.HOLD, seq=7, time=int(time.time())), KEY, VEHICLE)
        forged = auth.sign(
            ControlPacket(Command.MOVE, seq=8, time=int(time.time()), distance=50), bytes(32), VEHICLE
        )
        for frame in (genuine, forged, genuine):
            modem.send(nmea.RxData(SHORE, VEHICLE, True, 1, frame).line(nmea.MODEM))
        await until(lambda: link.counters["rejected"] == 2)
        assert [p.seq for p in taken] == [7] and repeats == [7]  # the repeat answered, not run again

    scenario(tmp_path, body)
