"""The command lifecycle: one set of allowed transitions, one writer, a history row per change."""

from __future__ import annotations

from pathlib import Path

import pytest
from sqlmodel import Session

from server.commands.models import CommandState as Status
from server.commands.repository import steps as history_of
from server.commands.schemas import CommandIn
from server.commands.service import MODEM, CommandDesk, CommandRefused, advance
from server.core.config import Settings
from server.core.db import make_engine, migrate, writing
from server.core.errors import NotFound
from server.core.events import Bus as EventBus
from server.missions.models import Mission
from server.missions.service import Missions
from server.vehicles.models import Vehicle
from tacit.navigation import Pose


@pytest.fixture
def desk(tmp_path: Path) -> CommandDesk:
    url = f"sqlite:///{tmp_path}/tacit.db"
    migrate(url)
    db = make_engine(url)
    with writing(db) as s:
        s.add(Vehicle(name="rov1", address=2, key_hex="11" * 32, max_depth=20.0, geofence_radius=50.0))
        s.flush()
        s.add(Mission(vehicle_id=1, name="square", number=1))
        s.commit()
    return CommandDesk(
        db, EventBus(), lambda address: Pose(45.0, 0.0, 2.0, 0.0), Settings().max_queued_commands
    )


def test_submit_checks_queues_and_records(desk: CommandDesk) -> None:
    command = desk.submit(1, CommandIn(command="move", distance=3, angle=0, depth=1), "tester")
    assert command.status == "queued" and command.frame == b""  # signed when sent, not before
    with pytest.raises(CommandRefused) as refused:  # 45 m north + 10 m: outside the 50 m geofence
        desk.submit(1, CommandIn(command="move", distance=10, angle=0, depth=0), "tester")
    assert refused.value.field == "distance"
    with pytest.raises(NotFound):
        desk.submit(9, CommandIn(command="hold"), "tester")
    started = Missions(desk.db, desk).start(1, "tester")
    assert started.seq == command.seq + 1  # a refused command takes no sequence number
    assert started.issued_by == "tester"
    with Session(desk.db) as s:
        assert s.get(Mission, 1).status == "started"
        assert [e.status for e in history_of(s, [started.id])[started.id]] == ["queued"]


def test_advance_writes_history_only_for_allowed_moves(desk: CommandDesk) -> None:
    command = desk.submit(1, CommandIn(command="hold"), "tester")
    steps = [(Status.SENT, True), (Status.EXECUTED, True), (Status.REFUSED, False), (Status.SENT, False)]
    for status, applied in steps:
        with writing(desk.db) as s:
            current = s.get(type(command), command.id)
            assert advance(s, current, status, "detail", origin=MODEM) is applied
            s.commit()
    with Session(desk.db) as s:
        assert [e.status for e in history_of(s, [command.id])[command.id]] == ["queued", "sent", "executed"]
