"""Protocol version 3 against the attacks that broke version 2 (issue 21), in process: the agent as
it runs (no MAVLink, no modem: frames handed to its link), the shore's ingest and heartbeat.

1. A lost state file no longer reopens the replay window: a recorded SYNC and a recorded command are
   refused until a SYNC echoes one of the vehicle's own check-points, which resynchronises it at once.
4. A clock wrong once no longer blocks reports or commands for as long as it was wrong.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from launch.stack import wait_for
from launch.stepped_clock import stepped
from server.app import create_app
from server.core.config import Settings
from server.core.events import Bus
from server.link.heartbeat import Heartbeat
from server.link.ingest import Ingest
from server.link.state import IncomingFrame
from server.link.store import LinkStore
from server.link.timing import Timing
from server.vehicles.models import Vehicle
from server.vehicles.service import Vehicles
from tacit import auth
from tacit import modem as mm
from tacit.packets import CheckpointPacket, Command, ControlPacket, MissionState, decode
from tacit.streams import default_streams
from tests.support.shore import store_with
from vehicle_agent.agent import Agent, AgentConfig

KEY = bytes(range(32))
ADDRESS = 2
HOUR = 3600
DAY = 86400


def make_agent(tmp_path: Path) -> Agent:
    """The agent as ``tacit agent`` builds it, its state file in ``tmp_path`` (none yet: a fresh state)."""
    config = AgentConfig(key=KEY.hex(), state_file=str(tmp_path / "agent-state.json"), modem_url="/dev/null")
    return Agent(config, config.plans(tmp_path))


def control(command: Command, seq: int, at: float, **fields: object) -> bytes:
    return auth.sign(ControlPacket(command, seq=seq, time=int(at), **fields), KEY, ADDRESS, epoch=1)  # type: ignore[arg-type]


def challenge(agent: Agent) -> bytes:
    """The agent's next check-point frame (queued for the shore's poll)."""
    agent._send_checkpoint()
    return agent.link.queue[-1].data


def test_attack_1_a_lost_state_refuses_a_recorded_sync_and_command_until_an_echo(tmp_path: Path) -> None:
    agent, now = make_agent(tmp_path), time.time()
    frame = challenge(agent)
    assert decode(frame).unsynced  # type: ignore[union-attr]
    agent.link._control(control(Command.SYNC, 5, now - 53))  # recorded 53 s ago
    agent.link._control(control(Command.GOTO_DEPTH, 3, now - 50, depth=4.0))  # then the command
    assert agent.fsm.status.last_command == 0 and agent.link.offset == 0.0
    assert agent.link.counters == {**agent.link.counters, "controls": 0, "rejected": 2}
    agent.link._control(control(Command.SYNC, 1, now + 120, echo=frame[28:]))  # the shore's answer
    assert agent.link.receiver.sync.counter == 1 and agent.link.offset == pytest.approx(120, abs=2)
    assert agent.link.receiver.window.floor == int(now + 120) - auth.FLOOR_SLACK
    agent.link._control(control(Command.GOTO_DEPTH, 3, now - 50, depth=4.0))  # recorded: still refused
    assert agent.fsm.status.last_command == 0
    agent.link._control(control(Command.GOTO_DEPTH, 4, now + 120, depth=1.0))  # signed afresh: runs
    assert agent.fsm.status.last_command == 4
    assert not decode(challenge(agent)).unsynced  # type: ignore[union-attr]
    again = make_agent(tmp_path)  # the state file has it all
    assert again.link.receiver.sync.counter == 1 and again.link.offset == agent.link.offset


def test_an_echo_of_an_unknown_checkpoint_and_a_synced_replay_are_refused(tmp_path: Path) -> None:
    agent, now = make_agent(tmp_path), time.time()
    challenge(agent)
    agent.link._control(control(Command.SYNC, 9, now, echo=b"WXYZ"))  # not one of its check-points
    assert agent.link.receiver.sync.unsynced
    agent.link._control(control(Command.SYNC, 1, now, echo=challenge(agent)[28:]))
    agent.link._control(control(Command.SYNC, 1, now + 60))  # the same counter again
    assert agent.link.counters["controls"] == 1


class AckingModem:
    state = mm.LinkState.READY

    def __init__(self) -> None:
        self.sent: list[bytes] = []

    async def send(self, dest: int, frames: list[bytes], **_: object) -> mm.TransmitResult:
        self.sent += frames
        return mm.TransmitResult(dest, len(frames), True, frozenset(range(len(frames))))


@pytest.fixture
def shore(tmp_path: Path):
    db = store_with(tmp_path, Vehicle(name="rov1", address=ADDRESS, key_hex=KEY.hex()))

    def start() -> tuple[Ingest, Heartbeat]:
        settings = Settings()
        ingest = Ingest(db, Bus(), default_streams(), settings)
        ingest.load_vehicles()
        return ingest, Heartbeat(settings, LinkStore(db), Timing(settings), Vehicles(db), ingest.next_sync)

    yield start
    db.dispose()


def sync(heartbeat: Heartbeat, ingest: Ingest) -> bytes:
    """The frame of the heartbeat's next SYNC to the vehicle."""
    modem = AckingModem()
    asyncio.run(heartbeat.sync(modem, ingest.vehicles[ADDRESS]))  # type: ignore[arg-type]
    return modem.sent[0]


def test_the_shore_answers_an_unsynced_checkpoint_once_and_its_counter_survives_a_restart(
    shore, tmp_path: Path
) -> None:
    ingest, heartbeat = shore()
    agent = make_agent(tmp_path)
    frame = challenge(agent)
    ingest.handle(IncomingFrame(ADDRESS, 1, frame))
    v = ingest.vehicles[ADDRESS]
    assert v.link.checkpoint is not None and v.link.checkpoint_time == 0  # applied; the floor stays
    assert heartbeat.due(v)
    answer = sync(heartbeat, ingest)
    packet = auth.verify(answer, KEY, ADDRESS)
    assert packet.echo == frame[28:] and packet.seq == 1 and not heartbeat.due(v)
    agent.link._control(answer)  # one exchange: synced
    assert not agent.link.receiver.sync.unsynced
    assert auth.verify(sync(heartbeat, ingest), KEY, ADDRESS).echo == bytes(4)  # answers nothing
    ingest, heartbeat = shore()  # the shore restarts: the counter goes on
    assert auth.verify(sync(heartbeat, ingest), KEY, ADDRESS).seq == 3


def checkpoint(at: float, unsynced: bool = False) -> bytes:
    packet = CheckpointPacket(seq=int(at) % 256, time=int(at), state=MissionState.WAITING, unsynced=unsynced)
    return auth.sign_checkpoint(packet, KEY, 1, ADDRESS, [])


def test_attack_4_a_vehicle_clock_an_hour_ahead_blocks_its_reports_for_one_exchange_only(shore) -> None:
    ingest, _ = shore()
    now = time.time()
    for frame in (checkpoint(now + HOUR, unsynced=True), checkpoint(now + HOUR + 1)):  # booted an hour ahead
        ingest.handle(IncomingFrame(ADDRESS, 1, frame))
    assert ingest.stats["verified"] == 2 and ingest.vehicles[ADDRESS].link.checkpoint_time <= now + 1
    for k in range(1, 25):  # the SYNC corrected its clock: every later report is accepted
        ingest.handle(IncomingFrame(ADDRESS, 1, checkpoint(now + 5 + k)))
    assert ingest.stats["verified"] == 26 and ingest.stats["replayed"] == 0


def test_attack_4_a_shore_clock_an_hour_ahead_then_fixed_is_heard_again_at_its_next_sync(
    tmp_path: Path,
) -> None:
    agent, now = make_agent(tmp_path), time.time()
    agent.link._control(control(Command.SYNC, 1, now, echo=challenge(agent)[28:]))
    agent.link._control(control(Command.SYNC, 2, now + HOUR))  # the shore's clock stepped ahead
    agent.link._control(control(Command.HOLD, 1, now + HOUR))
    assert agent.fsm.status.last_command == 1 and agent.link.offset == pytest.approx(HOUR, abs=2)
    agent.link._control(control(Command.SYNC, 3, now + 60))  # fixed: its counter still grows
    assert agent.link.offset == pytest.approx(60, abs=2)
    agent.link._control(control(Command.RESUME, 2, now + 60))
    assert agent.fsm.status.last_command == 2
    assert agent.link.receiver.window.floor == int(now) - auth.FLOOR_SLACK  # never moved by a SYNC


def test_attack_4_a_shore_clock_an_hour_ahead_then_set_right_hears_the_vehicle_again_at_once(
    shore, tmp_path: Path, monkeypatch
) -> None:
    ingest, _ = shore()
    clock = tmp_path / "shore.clock"
    clock.write_text(repr(float(HOUR)))
    monkeypatch.setattr(time, "time", stepped(clock))  # the shore's wall clock (launch.stepped_clock)
    ahead = checkpoint(time.time())  # the vehicle followed the shore's SYNCs an hour ahead
    ingest.handle(IncomingFrame(ADDRESS, 1, ahead))
    clock.write_text("0.0")  # set right; its next SYNC corrects the vehicle back
    wait_for(lambda: time.time() < ingest.vehicles[ADDRESS].link.checkpoint_time, 1.0, what="the step")
    ingest.handle(IncomingFrame(ADDRESS, 1, checkpoint(time.time() - 3)))
    ingest.handle(IncomingFrame(ADDRESS, 1, ahead))  # recorded while it was ahead, replayed
    assert ingest.stats["verified"] == 2 and ingest.stats["replayed"] + ingest.stats["duplicates"] == 1


def test_attack_4_a_vehicle_clock_stepped_a_whole_day_ahead_is_corrected_by_the_next_sync(
    tmp_path: Path, monkeypatch
) -> None:
    clock = tmp_path / "agent.clock"
    monkeypatch.setattr(time, "time", stepped(clock))  # the vehicle's wall clock (launch.stepped_clock)
    agent, now = make_agent(tmp_path), time.time()
    agent.link.clock = time.time  # its link took time.time at import; a stepped process patches first
    agent.link._control(control(Command.SYNC, 1, now, echo=challenge(agent)[28:]))
    clock.write_text(repr(float(DAY)))  # it steps a day ahead
    wait_for(lambda: time.time() > now + DAY - 60, 1.0, every=0.01, what="the step")
    agent.link._control(control(Command.SYNC, 2, now - 5))  # signed 5 s before it arrives
    assert agent.link.receiver.sync.counter == 2 and agent.link.offset == pytest.approx(-DAY, abs=10)
    agent.link._control(control(Command.HOLD, 1, now))
    assert agent.fsm.status.last_command == 1


def test_attack_4_a_shore_clock_stepped_back_an_hour_keeps_sending_syncs(
    shore, tmp_path: Path, monkeypatch
) -> None:
    """SYNC intervals run on the monotonic clock: a wall clock stepped back must not stop them."""
    ingest, heartbeat = shore()
    ingest.handle(IncomingFrame(ADDRESS, 1, checkpoint(time.time())))  # heard: SYNCs are due from now
    heartbeat.settings = Settings(time_scale=100.0)  # a SYNC every 0.6 s
    v = ingest.vehicles[ADDRESS]
    sync(heartbeat, ingest)
    assert not heartbeat.due(v)
    clock = tmp_path / "shore.clock"
    clock.write_text(repr(-float(HOUR)))
    monkeypatch.setattr(time, "time", stepped(clock))  # the shore's wall clock steps (launch.stepped_clock)
    wait_for(lambda: heartbeat.due(v), 2.0, every=0.01, what="the next SYNC due")


def version_2(frame: bytes) -> bytes:
    old = bytearray(frame)
    old[0] = (old[0] & 0x3F) | (2 << 6)
    return bytes(old)


def test_a_version_2_vehicle_is_refused_with_a_clear_reason_logged_once_and_counted_on_the_link(
    tmp_path: Path, caplog
) -> None:
    settings = Settings(
        database_url=f"sqlite:///{tmp_path}/tacit.db", modem_url="", map_enabled=False, write_tokens=["op"]
    )
    with TestClient(create_app(settings)) as client:
        op = {"Authorization": "Bearer op"}
        body = {"name": "rov1", "address": ADDRESS, "key": KEY.hex()}
        client.post("/api/v1/vehicles", json=body, headers=op).raise_for_status()
        ingest = client.app.state.shore.ingest  # type: ignore[attr-defined]
        ingest.load_vehicles()
        for k in range(5):  # an old agent keeps talking
            ingest.handle(IncomingFrame(ADDRESS, 1, version_2(checkpoint(time.time() + k))))
        link = client.get("/api/v1/link", headers=op).json()
    assert caplog.text.count("protocol version 2") == 1 and "update its agent" in caplog.text
    assert link["vehicles"]["rov1"]["old_protocol"] == 5
    assert link["ingest"]["old_protocol"] == 5 and link["ingest"]["rejected"] == 5
    agent = make_agent(tmp_path)
    agent.link._control(version_2(control(Command.HOLD, 1, time.time())))
    assert agent.link.counters["rejected"] == 1


class SilentModem:
    """A cycle on the air that the vehicle's modem never acknowledges."""

    async def send(self, dest: int, frames: list[bytes], **_: object) -> mm.TransmitResult:
        return mm.TransmitResult(dest, len(frames), True)


class BusyModem(AckingModem):
    """Our own modem refusing the cycle (still acknowledging a frame it received)."""

    async def send(self, dest: int, frames: list[bytes], **_: object) -> mm.TransmitResult:
        return mm.TransmitResult(dest, len(frames), False, error="BUSY")


def test_no_sync_before_the_first_checkpoint_and_commands_wait_for_its_answer(shore, tmp_path: Path) -> None:
    """A new vehicle is unsynced: a SYNC sent before its first check-point was heard answers none of
    them, and it refuses any command before the answer; the answer goes again until its modem ACKs it."""
    ingest, heartbeat = shore()
    v = ingest.vehicles[ADDRESS]
    assert not heartbeat.due(v) and not heartbeat.synced(v)
    frame = challenge(make_agent(tmp_path))
    ingest.handle(IncomingFrame(ADDRESS, 1, frame))
    assert heartbeat.due(v) and not heartbeat.synced(v)
    asyncio.run(heartbeat.sync(SilentModem(), v))  # type: ignore[arg-type]
    assert heartbeat.due(v) and not heartbeat.synced(v)
    assert auth.verify(sync(heartbeat, ingest), KEY, ADDRESS).echo == frame[28:]
    assert heartbeat.synced(v) and not heartbeat.due(v)


def test_an_answer_our_modem_refused_goes_out_at_the_next_slot(shore, tmp_path: Path) -> None:
    ingest, heartbeat = shore()
    frame = challenge(make_agent(tmp_path))
    ingest.handle(IncomingFrame(ADDRESS, 1, frame))
    v = ingest.vehicles[ADDRESS]
    assert not asyncio.run(heartbeat.sync(BusyModem(), v))  # type: ignore[arg-type]
    assert heartbeat.due(v) and auth.verify(sync(heartbeat, ingest), KEY, ADDRESS).echo == frame[28:]


def test_checkpoints_say_when_the_vehicle_holds_the_next_key(tmp_path: Path) -> None:
    config = AgentConfig(
        key=KEY.hex(),
        next_key=bytes(range(32, 64)).hex(),
        modem_url="/dev/null",
        state_file=str(tmp_path / "agent-state.json"),
    )
    agent = Agent(config, config.plans(tmp_path))
    assert decode(challenge(agent)).holds_next_key  # type: ignore[union-attr]
    assert not decode(challenge(make_agent(tmp_path / "other"))).holds_next_key  # type: ignore[union-attr]
