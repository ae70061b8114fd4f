"""The link engine's parts without a modem: slot timings, and which command a vehicle's slot carries."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest
from sqlalchemy import update

from server.commands.models import CommandRecord as Command
from server.commands.models import CommandState as Status
from server.commands.schemas import CommandIn
from server.commands.service import MODEM, CommandDesk, advance
from server.core.config import Settings
from server.core.db import make_engine, migrate, writing
from server.core.events import Bus as EventBus
from server.link.delivery import Delivery
from server.link.store import LinkStore
from server.link.timing import Timing
from server.vehicles.models import Vehicle


@pytest.fixture
def delivery(tmp_path: Path) -> tuple[Delivery, CommandDesk]:
    url = f"sqlite:///{tmp_path}/tacit.db"
    migrate(url)
    db = make_engine(url)
    with writing(db) as s:
        s.add(Vehicle(name="rov1", address=2, key_hex="11" * 32))
        s.commit()
    settings = Settings(confirm_timeout=60.0)
    desk = CommandDesk(db, EventBus(), lambda _address: None, settings.max_queued_commands)
    return Delivery(settings, LinkStore(db), desk, Timing(settings)), desk


def test_the_oldest_pending_command_goes_first_then_an_unconfirmed_latest(
    delivery: tuple[Delivery, CommandDesk],
) -> None:
    link, desk = delivery
    first = desk.submit(1, CommandIn(command="hold"), "tester")
    second = desk.submit(1, CommandIn(command="goto_depth", depth=2), "tester")
    assert asyncio.run(link.next_command(1)).id == first.id
    with writing(desk.db) as s:
        for command in (first, second):
            current = s.get(Command, command.id)
            assert advance(s, current, Status.SENT, origin=MODEM) and advance(
                s, current, Status.ACKNOWLEDGED, origin=MODEM
            )
        s.commit()
    assert asyncio.run(link.next_command(1)) is None  # acknowledged recently: wait for a check-point
    with writing(desk.db) as s:  # a minute later, still no check-point has confirmed it
        s.execute(update(Command).values(updated_at=time.time() - 61))
        s.commit()
    assert asyncio.run(link.next_command(1)).id == second.id  # only the latest
    with writing(desk.db) as s:
        assert advance(s, s.get(Command, second.id), Status.EXECUTED, origin=MODEM)
        s.commit()
    assert asyncio.run(link.next_command(1)) is None


def test_a_command_sent_again_after_its_ack_gets_a_fresh_round_of_attempts(
    delivery: tuple[Delivery, CommandDesk],
) -> None:
    link, desk = delivery
    command = desk.submit(1, CommandIn(command="hold"), "tester")
    with writing(desk.db) as s:
        current = s.get(Command, command.id)
        for _ in range(3):  # three attempts, the third acknowledged
            assert advance(s, current, Status.SENT, origin=MODEM)
        assert advance(s, current, Status.ACKNOWLEDGED, origin=MODEM)
        assert advance(s, current, Status.SENT, origin=MODEM)  # no check-point confirmed it: again
        s.commit()
    assert desk.unanswered(command.id) == 1  # not 4: one more miss must not fail it at once
