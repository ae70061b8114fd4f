"""The command lifecycle: one set of allowed transitions, one writer, a history row per change."""

from __future__ import annotations

from pathlib import Path

import pytest
from sqlmodel import Session

from server.db import make_engine, migrate, writing
from server.errors import NotFound
from server.events import EventBus
from server.models import Mission, Vehicle
from server.schemas import CommandIn
from server.services.commands import CommandDesk, CommandRefused, Status, advance, allowed, history
from tacit.navigation import Pose


def test_the_vehicle_has_the_last_word() -> None:
    assert allowed("queued", Status.SENT) and allowed("sent", Status.ACKNOWLEDGED)
    assert allowed("acknowledged", Status.EXECUTING) and allowed("executing", Status.EXECUTED)
    assert allowed("failed", Status.EXECUTED)  # a check-point shows it ran after all
    assert not allowed("executed", Status.REFUSED)  # final: a later packet cannot flip it
    assert not allowed("executing", Status.ACKNOWLEDGED)  # a late ACK does not undo the vehicle's word
    assert not allowed("refused", Status.SENT)


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
    woken: list[bool] = []
    return CommandDesk(db, EventBus(), lambda address: Pose(45.0, 0.0, 2.0, 0.0), lambda: woken.append(True))


def test_submit_checks_queues_and_records(desk: CommandDesk) -> None:
    command = desk.submit(1, CommandIn(command="move", distance=3, angle=0, depth=1))
    assert command.status == "queued" and command.frame == b""  # signed when sent, not before
    with pytest.raises(CommandRefused) as refused:  # 45 m north + 10 m: outside the 50 m geofence
        desk.submit(1, CommandIn(command="move", distance=10, angle=0, depth=0))
    assert refused.value.field == "distance"
    with pytest.raises(NotFound):
        desk.submit(9, CommandIn(command="hold"))
    started = desk.submit(
        1, CommandIn(command="start_mission", param_id=1), mission_id=1, mission_status="started"
    )
    assert started.seq == command.seq + 1  # a refused command takes no sequence number
    with Session(desk.db) as s:
        assert s.get(Mission, 1).status == "started"
        assert [e.status for e in history(s, started.id)] == ["queued"]


def test_advance_writes_history_only_for_allowed_moves(desk: CommandDesk) -> None:
    command = desk.submit(1, CommandIn(command="hold"))
    steps = [(Status.SENT, True), (Status.EXECUTED, True), (Status.REFUSED, False), (Status.SENT, False)]
    for status, applied in steps:
        with writing(desk.db) as s:
            current = s.get(type(command), command.id)
            assert advance(s, current, status, "detail") is applied
            s.commit()
    with Session(desk.db) as s:
        assert [e.status for e in history(s, command.id)] == ["queued", "sent", "executed"]
