"""The agent's state file: a corrupt one is set aside and the agent starts safe; a lost one still refuses a
captured command."""

from __future__ import annotations

from pathlib import Path

import pytest

from tacit import auth

KEY = bytes(range(32))
ADDRESS = 2


@pytest.mark.parametrize(
    "content",
    [
        b'{"mission": {"state": "PREPRO',
        b"\x00\xff garbage",
        b"[1, 2]",
        b'{"packet_seq": "x"}',
        b'{"north": NaN}',
        b"",
    ],
)
def test_a_corrupt_state_file_is_set_aside_and_the_agent_starts_safe(
    tmp_path: Path, content: bytes, caplog: pytest.LogCaptureFixture
) -> None:
    from vehicle_agent.state import AgentState

    path = tmp_path / "agent-state.json"
    path.write_bytes(content)
    state = AgentState.load(path)
    assert state.fresh and state.mission == {} and state.sync_counter is None  # unsynced
    assert not path.exists() and len(list(tmp_path.glob("agent-state.json.corrupt-*"))) == 1
    assert "set aside" in caplog.text
    state.save(path)
    assert path.stat().st_mode & 0o777 == 0o600
    again = AgentState.load(path)
    assert not again.fresh and again.replay == state.replay and again.sync_counter is None


def test_a_lost_state_file_still_refuses_a_captured_command(tmp_path: Path) -> None:
    from tacit.packets import Command, ControlPacket
    from vehicle_agent.state import AgentState

    now = 1_800_000_000
    captured = auth.sign(ControlPacket(Command.MOVE, seq=5, time=now - 120, distance=5), KEY, ADDRESS)
    state = AgentState.load(tmp_path / "missing.json")  # the file is gone: unsynced
    receiver = auth.ControlReceiver(
        KEY, ADDRESS, auth.ReplayWindow.from_dict(state.replay), auth.SyncWindow(counter=state.sync_counter)
    )
    with pytest.raises(auth.Unsynced):
        receiver.accept(captured, now)
    receiver.sync.challenge(b"MAC!")  # a check-point it signed; the shore answers it
    receiver.accept(auth.sign(ControlPacket(Command.SYNC, seq=1, time=now, echo=b"MAC!"), KEY, ADDRESS), now)
    with pytest.raises(auth.Replayed):
        receiver.accept(captured, now)
    resent = auth.sign(ControlPacket(Command.MOVE, seq=5, time=now, distance=5), KEY, ADDRESS)
    assert receiver.accept(resent, now).seq == 5  # the shore's next attempt is signed afresh
