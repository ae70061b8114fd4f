"""The backhaul's down messages: a command frame and its withdrawal, both on a gateway's commands subject."""

from __future__ import annotations

import pytest

from server.backhaul import subjects
from server.backhaul.subjects import (
    CommandMessage,
    FrameKind,
    PayloadError,
    ScheduleMessage,
    WithdrawMessage,
    WithdrawReason,
)


def test_a_command_keeps_its_kind_rank_and_stamp() -> None:
    sent = CommandMessage("cmd-4-1", "ship", 2, b"frame", kind=FrameKind.STOP, rank=7, stamp=1700.0)
    got = subjects.down(sent.encode())
    assert got == sent


def test_a_command_of_an_older_center_is_a_command_or_a_sync_by_its_id() -> None:
    older = b'{"v":1,"id":"sync-2-99","gateway":"ship","address":2,"data":"00"}'
    got = subjects.down(older)
    assert isinstance(got, CommandMessage) and got.kind is FrameKind.SYNC and got.rank == 0
    assert CommandMessage.decode(older.replace(b"sync-2-99", b"cmd-3-1")).kind is FrameKind.COMMAND


def test_a_withdrawal_is_told_from_a_command() -> None:
    withdrawal = WithdrawMessage(
        subjects.withdraw_id("cmd-4-1"), "ship", "cmd-4-1", WithdrawReason.ACKNOWLEDGED
    )
    assert subjects.down(withdrawal.encode()) == withdrawal


@pytest.mark.parametrize(
    "payload",
    [
        b'{"v":1,"type":"withdraw","id":"w","gateway":"ship","command":"cmd-1-1","reason":"because"}',
        b'{"v":1,"type":"withdraw","id":"w","gateway":"ship"}',
        b'{"v":1,"id":"cmd-1-1","gateway":"ship","address":2,"data":"00","kind":"launch"}',
        b'{"v":2,"type":"withdraw","id":"w","gateway":"ship","command":"c","reason":"cancelled"}',
    ],
)
def test_a_malformed_down_message_is_refused(payload: bytes) -> None:
    with pytest.raises(PayloadError):
        subjects.down(payload)


def test_a_schedule_carries_the_vehicles_shares_and_refuses_one_not_positive() -> None:
    schedule = ScheduleMessage(
        "s1", "ship", 1000.0, 20.0, 1.0, ("ship", "buoy"), (2, 3), ((2, 4.0), (3, 1.0))
    )
    assert ScheduleMessage.decode(schedule.encode()) == schedule
    bad = schedule.encode().replace(b'"2":4.0', b'"2":-1')
    with pytest.raises(PayloadError):
        ScheduleMessage.decode(bad)
