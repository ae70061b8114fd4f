"""The link engine's parts without a modem: slot timings, and which command a vehicle's slot carries."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest
from sqlalchemy import update

from server.db import make_engine, migrate, writing
from server.events import EventBus
from server.link.delivery import Delivery
from server.link.ingest import VehicleState
from server.link.store import LinkStore
from server.link.timing import Timing
from server.models import Command, Vehicle
from server.schemas import CommandIn
from server.services.commands import CommandDesk, Status, advance
from server.settings import Settings


def test_slot_timings_grow_with_range_and_shrink_with_time_scale() -> None:
    near, far = VehicleState(1, "a", 2, {}), VehicleState(2, "b", 3, {})
    near.range_m, far.range_m = 100.0, 3000.0
    timing = Timing(Settings(time_scale=1.0))
    assert timing.ack_timeout(far) - timing.ack_timeout(near) == pytest.approx(1.5 * 2 * 2900 / 1500)
    assert timing.poll_window(far, 5) > timing.poll_window(far, 0) > timing.poll_window(near, 0)
    assert Timing(Settings(time_scale=10.0)).ack_timeout(far) == pytest.approx(timing.ack_timeout(far) / 10)
    unknown = VehicleState(3, "c", 4, {})
    assert timing.range_m(unknown) == Settings().default_range  # until a ping measures it


@pytest.fixture
def delivery(tmp_path: Path) -> tuple[Delivery, CommandDesk]:
    url = f"sqlite:///{tmp_path}/tacit.db"
    migrate(url)
    db = make_engine(url)
    with writing(db) as s:
        s.add(Vehicle(name="rov1", address=2, key_hex="11" * 32))
        s.commit()
    settings = Settings(confirm_timeout=60.0)
    desk = CommandDesk(db, EventBus(), lambda _address: None, lambda: None)
    return Delivery(settings, LinkStore(db), EventBus(), Timing(settings)), desk


def test_the_oldest_pending_command_goes_first_then_an_unconfirmed_latest(
    delivery: tuple[Delivery, CommandDesk],
) -> None:
    link, desk = delivery
    first = desk.submit(1, CommandIn(command="hold"))
    second = desk.submit(1, CommandIn(command="goto_depth", depth=2))
    assert asyncio.run(link.next_command(1)).id == first.id
    with writing(desk.db) as s:
        for command in (first, second):
            current = s.get(Command, command.id)
            assert advance(s, current, Status.SENT) and advance(s, current, Status.ACKNOWLEDGED)
        s.commit()
    assert asyncio.run(link.next_command(1)) is None  # acknowledged recently: wait for a check-point
    with writing(desk.db) as s:  # a minute later, still no check-point has confirmed it
        s.execute(update(Command).values(updated_at=time.time() - 61))
        s.commit()
    assert asyncio.run(link.next_command(1)).id == second.id  # only the latest
    with writing(desk.db) as s:
        assert advance(s, s.get(Command, second.id), Status.EXECUTED)
        s.commit()
    assert asyncio.run(link.next_command(1)) is None


def test_a_command_sent_again_after_its_ack_gets_a_fresh_round_of_attempts(
    delivery: tuple[Delivery, CommandDesk],
) -> None:
    link, desk = delivery
    command = desk.submit(1, CommandIn(command="hold"))
    with writing(desk.db) as s:
        current = s.get(Command, command.id)
        for _ in range(3):  # three attempts, the third acknowledged
            assert advance(s, current, Status.SENT)
        assert advance(s, current, Status.ACKNOWLEDGED)
        assert advance(s, current, Status.SENT)  # no check-point confirmed it: again
        s.commit()
    assert link._unanswered(command.id) == 1  # not 4: one more miss must not fail it at once
