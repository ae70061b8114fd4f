"""The async Micro-Modem driver against a scripted modem on a real pty."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from simulators.scripted_modem import ScriptedModem, default_rule
from tacit import nmea
from tacit.modem import (
    DriverSettings,
    Event,
    LineRejected,
    LinkState,
    ModemDriver,
    ModemTimeout,
    ReceivedFrame,
)

VEHICLE = 2
SHORE = 1


def cycle_rule(modem: ScriptedModem, sentence: nmea.Sentence | nmea.Raw) -> list[str]:
    """A modem that runs a full data cycle with ACK from the vehicle, and answers pings at 0.0101 s."""
    replies = default_rule(modem, sentence)
    if isinstance(sentence, nmea.Cycle) and sentence.src == SHORE:
        replies.append(nmea.DataRequest("120000", sentence.src, sentence.dest, sentence.ack, 32, 1).line())
    if isinstance(sentence, nmea.TxData) and sentence.data:
        replies += [
            nmea.TxStarted(len(sentence.data)).line(),
            nmea.TxFinished(len(sentence.data)).line(),
            nmea.Ack(sentence.dest, sentence.src, 1, 1).line(),
        ]
    if isinstance(sentence, nmea.Ping):
        replies.append(nmea.PingReply(sentence.dest, sentence.src, 0.0101).line())
    return replies


def settings(path: Path, **kw: object) -> DriverSettings:
    base = dict(
        url=str(path),
        address=SHORE,
        echo_timeout=0.3,
        keepalive=0.3,
        reconnect_min=0.05,
        log_path=str(path.parent / "modem.log"),
    )
    base.update(kw)
    return DriverSettings(**base)  # type: ignore[arg-type]


async def wait_until(predicate, timeout: float = 5.0) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not predicate():
        if loop.time() > deadline:
            raise AssertionError("condition not reached in time")
        await asyncio.sleep(0.01)


@pytest.fixture
def modem(tmp_path: Path):
    m = ScriptedModem(tmp_path / "modem", cycle_rule)
    yield m
    m.close()


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 30))


def test_configure_sets_address_statistics_and_clock(modem: ScriptedModem, tmp_path: Path) -> None:
    async def scenario() -> None:
        driver = ModemDriver(settings(modem.path))
        await driver.start()
        assert driver.state is LinkState.READY
        await driver.stop()

    run(scenario())
    configs = {s.name: s.value for s in modem.received if isinstance(s, nmea.Config)}
    assert configs["SRC"] == str(SHORE) and configs["CST"] == "1" and configs["XST"] == "1"
    assert modem.wait_for(nmea.Clock)[0].year >= 2024
    log_text = (tmp_path / "modem.log").read_text()
    assert "> $CCCFG,SRC,1*" in log_text and "< $CACFG,SRC,1*" in log_text


def test_send_with_ack_delivers_the_bytes(modem: ScriptedModem) -> None:
    async def scenario():
        driver = ModemDriver(settings(modem.path))
        await driver.start()
        result = await driver.send(VEHICLE, [bytes(range(32))], rate=0, ack=True, ack_timeout=2)
        await driver.stop()
        return result

    result = run(scenario())
    assert result.transmitted and result.all_acked and not result.error
    sent = [s for s in modem.received if isinstance(s, nmea.TxData)]
    assert sent[-1].data == bytes(range(32)) and (sent[-1].src, sent[-1].dest) == (SHORE, VEHICLE)
    cycle = modem.wait_for(nmea.Cycle)[0]
    assert (cycle.src, cycle.dest, cycle.rate, cycle.ack, cycle.nframes) == (SHORE, VEHICLE, 0, True, 1)


def test_send_without_ack_reply_reports_no_acknowledgement(tmp_path: Path) -> None:
    def no_ack(m: ScriptedModem, s: nmea.Sentence) -> list[str]:
        return [r for r in cycle_rule(m, s) if not r.startswith("$CAACK")]

    modem = ScriptedModem(tmp_path / "modem", no_ack)

    async def scenario():
        driver = ModemDriver(settings(modem.path))
        await driver.start()
        result = await driver.send(VEHICLE, [b"x" * 32], ack=True, ack_timeout=0.3)
        await driver.stop()
        return result

    result = run(scenario())
    modem.close()
    assert result.transmitted and not result.all_acked and result.error == "no acknowledgement"


def test_received_frame_carries_its_statistics(modem: ScriptedModem) -> None:
    cst = "CACST,0,223413.0000,0,1440,25,0175,0166,75,01,01,01,03,1,007,006,0,3,3,0,146,03,04,-100,-1,000,-1.2,45,10000,2000"
    events: list[Event] = []

    async def scenario() -> None:
        driver = ModemDriver(settings(modem.path))
        driver.add_listener(events.append)
        await driver.start()
        modem.send(nmea.RxData(VEHICLE, SHORE, False, 1, b"\x01" * 32).line())
        modem.send(f"${cst}*{nmea.checksum(cst)}\r\n")
        await wait_until(lambda: any(isinstance(e, ReceivedFrame) for e in events))
        await driver.stop()

    run(scenario())
    frame = next(e for e in events if isinstance(e, ReceivedFrame))
    assert frame.data == b"\x01" * 32 and frame.src == VEHICLE
    assert frame.stats is not None and frame.stats.snr_out == 4.0 and frame.stats.mode == 0


def test_ping_returns_travel_time(modem: ScriptedModem) -> None:
    async def scenario():
        driver = ModemDriver(settings(modem.path))
        await driver.start()
        travel = await driver.ping(VEHICLE, timeout=2)
        await driver.stop()
        return travel

    assert run(scenario()) == pytest.approx(0.0101)


def test_silent_modem_is_retried_then_declared_not_responding(modem: ScriptedModem) -> None:
    async def scenario() -> None:
        driver = ModemDriver(settings(modem.path, keepalive=60))
        await driver.start()
        modem.silent = True
        before = len(modem.received)
        for _ in range(2):
            with pytest.raises(ModemTimeout):
                await driver.command(nmea.ConfigQuery("SRC"))
        sent = [s for s in modem.received[before:] if isinstance(s, nmea.ConfigQuery)]
        assert len(sent) == 2 * driver.settings.tries
        assert driver.state is LinkState.NOT_RESPONDING
        modem.silent = False
        await driver.command(nmea.ConfigQuery("SRC"))
        assert driver.state is LinkState.READY
        await driver.stop()

    run(scenario())


def test_reboot_triggers_reconfiguration(modem: ScriptedModem) -> None:
    async def scenario() -> None:
        driver = ModemDriver(settings(modem.path, keepalive=60))
        await driver.start()
        first = len([s for s in modem.received if isinstance(s, nmea.Config) and s.name == "SRC"])
        modem.send(nmea.Revision("000052", "INIT", "0.93.0.09").line())
        await wait_until(
            lambda: len([s for s in modem.received if isinstance(s, nmea.Config) and s.name == "SRC"]) > first
        )
        await wait_until(lambda: driver.state is LinkState.READY)
        await driver.stop()

    run(scenario())


def test_vanished_port_comes_back(modem: ScriptedModem) -> None:
    states: list[LinkState] = []

    async def scenario() -> None:
        driver = ModemDriver(settings(modem.path, keepalive=60))
        driver.add_listener(lambda e: states.append(e.state) if hasattr(e, "state") else None)
        await driver.start()
        modem.vanish()
        await wait_until(lambda: driver.state is LinkState.CONNECTING)
        await asyncio.sleep(0.3)  # a few reconnect attempts fail while the port is gone
        modem.appear()
        await wait_until(lambda: driver.state is LinkState.READY, timeout=10)
        result = await driver.send(VEHICLE, [b"y" * 32], ack=True, ack_timeout=2)
        assert result.all_acked
        await driver.stop()

    run(scenario())
    assert states.count(LinkState.READY) >= 2


def test_garbage_from_modem_is_reported_and_the_driver_goes_on(modem: ScriptedModem) -> None:
    events: list[Event] = []

    async def scenario() -> None:
        driver = ModemDriver(settings(modem.path, keepalive=60))
        driver.add_listener(events.append)
        await driver.start()
        modem.send(b"\xff\xfe\x00garbage\r\n$CAMPR,2,1,0.0101*00\r\n$CARXD,2,1,0,1,ZZ*00\r\n")
        await wait_until(lambda: len([e for e in events if isinstance(e, LineRejected)]) >= 3)
        assert await driver.ping(VEHICLE, timeout=2) == pytest.approx(0.0101)
        await driver.stop()

    run(scenario())
    errors = [e.error for e in events if isinstance(e, LineRejected)]
    assert any("checksum" in e for e in errors)


def test_unsolicited_data_request_is_answered_from_the_poll_provider(modem: ScriptedModem) -> None:
    async def scenario() -> None:
        driver = ModemDriver(settings(modem.path, keepalive=60))
        driver.poll_provider = lambda drq: b"\xaa" * drq.maxbytes
        await driver.start()
        modem.send(nmea.DataRequest("120000", SHORE, 3, False, 32, 1).line())
        await asyncio.to_thread(modem.wait_for, nmea.TxData)
        await driver.stop()

    run(scenario())
    txd = [s for s in modem.received if isinstance(s, nmea.TxData)][-1]
    assert txd.data == b"\xaa" * 32 and txd.dest == 3


def test_modem_rebooting_mid_cycle_fails_the_cycle_then_recovers(tmp_path: Path) -> None:
    rebooted: list[bool] = []

    def reboot_once(m: ScriptedModem, s: nmea.Sentence) -> list[str]:
        if (
            isinstance(s, nmea.Cycle) and not rebooted
        ):  # echo the cycle, then reboot instead of asking for data
            rebooted.append(True)
            return [s.line(nmea.MODEM), nmea.Revision("000001", "INIT", "0.94.0.52").line()]
        return cycle_rule(m, s)

    modem = ScriptedModem(tmp_path / "modem", reboot_once)

    async def scenario():
        driver = ModemDriver(settings(modem.path, keepalive=60, drq_timeout=1.0))
        await driver.start()
        configured = len([s for s in modem.received if isinstance(s, nmea.Config) and s.name == "SRC"])
        first = await driver.send(VEHICLE, [b"a" * 32], ack=True, ack_timeout=2)
        await wait_until(
            lambda: (
                len([s for s in modem.received if isinstance(s, nmea.Config) and s.name == "SRC"])
                > configured
            )
        )
        await wait_until(lambda: driver.state is LinkState.READY)
        second = await driver.send(VEHICLE, [b"b" * 32], ack=True, ack_timeout=2)
        await driver.stop()
        return first, second

    first, second = run(scenario())
    modem.close()
    assert not first.transmitted and first.error  # the lost cycle is reported, not hidden
    assert second.transmitted and second.all_acked
