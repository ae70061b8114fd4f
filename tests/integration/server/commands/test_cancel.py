"""Cancelling a queued command (``CommandDesk.cancel``, ``POST /api/v1/commands/{id}/cancel``): it ends
``cancelled`` with who and when and is never signed for transmission; a cancel that loses the race with
a transmission is a 409 saying so; the queue's cap is explained in the 429 and shown. On a shore with no
modem of its own (nothing is sent while the test looks), and through gateways on a real broker."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.backhaul import subjects
from server.backhaul.dispatch import Dispatcher
from server.backhaul.subjects import EventMessage, WithdrawMessage, WithdrawReason
from server.commands.schemas import CommandIn
from server.commands.service import CommandDesk
from server.core.config import Settings
from server.core.db import make_engine, migrate, writing
from server.core.events import Bus
from server.routing.models import Dispatch, DispatchState
from server.routing.service import Routing
from server.vehicles.models import Vehicle as VehicleRow
from tacit import auth
from tacit import modem as mm
from tacit.packets import Command
from tests.integration.server.routing.test_choice import StandInModem, until
from tests.integration.server.routing.test_claims import running
from tests.support.api import OP, offline_settings
from tests.support.nats import Secured
from tests.support.shore import AckingModem, scripted_shore

READ = {"Authorization": "Bearer observer-token"}


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    with TestClient(create_app(offline_settings(tmp_path))) as client:
        answer = client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP)
        assert answer.status_code == 201, answer.text
        yield client


def hold(client: TestClient) -> dict[str, Any]:
    answer = client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=OP)
    assert answer.status_code == 202, answer.text
    return dict(answer.json())


def test_a_queued_command_is_cancelled_by_whom_and_when_and_never_signed(client: TestClient) -> None:
    command = hold(client)
    assert client.post(f"/api/v1/commands/{command['id']}/cancel", headers=READ).status_code == 403
    assert client.post("/api/v1/commands/99/cancel", headers=OP).status_code == 404
    answer = client.post(f"/api/v1/commands/{command['id']}/cancel", headers=OP)
    assert answer.status_code == 200, answer.text
    assert answer.json()["status"] == "cancelled"
    step = answer.json()["history"][-1]
    assert (step["status"], step["source"], step["via"], step["detail"]) == (
        "cancelled", "operator", "config-operator-1", "by config-operator-1",
    )  # fmt: skip
    assert step["at"] >= answer.json()["history"][0]["at"]
    desk = client.app.state.shore.commands  # type: ignore[attr-defined]
    record, _ = desk.get(command["id"])
    assert desk.frame(record) is None  # the link's attempt finds it cancelled: never on the air
    assert desk.get(command["id"])[0].frame == b""
    assert desk.next_to_send(1, 0.0) is None
    again = client.post(f"/api/v1/commands/{command['id']}/cancel", headers=OP)
    assert again.status_code == 409 and "cancelled: nothing left to cancel" in again.json()["detail"]


def test_on_the_single_shore_a_cancelled_command_never_goes_on_the_air(tmp_path: Path) -> None:
    """Three commands queued for rov1, the second cancelled: the link's slots send the first and the
    third (each ACKed) and never the second."""
    key = "11" * 32
    shore = scripted_shore(tmp_path, [key])
    desk, modem = shore.commands, AckingModem()
    queued = [desk.submit(1, CommandIn(command="hold"), "tester") for _ in range(3)]
    assert desk.cancel(queued[1].id, "alice").status == "cancelled"
    shore.link.driver = modem  # type: ignore[assignment]

    async def slots() -> None:
        for _ in range(20):  # a SYNC, then a command per slot: a handful is enough
            if desk.get(queued[2].id)[0].status != "queued":
                return
            plan = await shore.link._plan()
            await shore.link._slot(plan[0][0])

    asyncio.run(slots())
    sent = [auth.verify(frame, bytes.fromhex(key), 2) for frame in modem.sent]
    assert [p.seq for p in sent if p.command is not Command.SYNC] == [queued[0].seq, queued[2].seq]
    assert [desk.get(c.id)[0].status for c in queued] == ["acknowledged", "cancelled", "acknowledged"]


def test_a_cancel_that_loses_the_race_with_a_transmission_says_so(client: TestClient) -> None:
    command = hold(client)
    desk = client.app.state.shore.commands  # type: ignore[attr-defined]
    record, _ = desk.get(command["id"])
    assert desk.frame(record)  # the link signed it for an attempt: from here it goes
    answer = client.post(f"/api/v1/commands/{command['id']}/cancel", headers=OP)
    assert answer.status_code == 409
    assert answer.json()["detail"].endswith("too late to cancel, it goes on as sent")
    assert answer.json()["field"] == "command_id"
    assert client.get(f"/api/v1/commands/{command['id']}", headers=OP).json()["status"] == "queued"


def test_the_queue_cap_is_explained_and_shown(client: TestClient) -> None:
    queued = [hold(client) for _ in range(20)]
    fleet = client.get("/api/v1/fleet", headers=OP).json()["vehicles"][0]
    assert (fleet["queued"], fleet["queue_cap"]) == (20, 20)
    full = client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=OP)
    assert full.status_code == 429 and full.headers["Retry-After"]
    assert "its queue's cap (20" in full.json()["detail"] and "cancel queued ones" in full.json()["detail"]
    assert client.post(f"/api/v1/commands/{queued[-1]['id']}/cancel", headers=OP).status_code == 200
    assert client.get("/api/v1/fleet", headers=OP).json()["vehicles"][0]["queued"] == 19
    hold(client)  # room again


class RefusingModem(StandInModem):
    """A shore modem that refuses every cycle (busy): nothing it is given goes on the air."""

    async def send(
        self,
        dest: int,
        frames: list[bytes],
        rate: int = 0,
        ack: bool = True,
        ack_timeout: float | None = None,
    ) -> mm.TransmitResult:
        return mm.TransmitResult(dest, len(frames), transmitted=False, error="busy")


def test_through_gateways_a_held_command_is_withdrawn_and_one_not_yet_dispatched_never_is(
    secured: Secured, tmp_path: Path, sqlite_url: str
) -> None:
    """The first command is held by the ship, whose modem never gets it on the air: its cancel withdraws
    it (202, cancelling), and the ship's word ends it cancelled. The second waits behind it at the
    center: cancelled at once, it is never dispatched; the third, after them, is. A command the ship
    reports on the air is too late (409)."""
    with running(secured, tmp_path, sqlite_url, ship=RefusingModem, gateway_faulty_slots=1000) as shore:
        vehicle_id = shore.register()
        shore.heard({"ship": 20.0, "buoy": 12.0})
        until(lambda: shore.route(vehicle_id)["gateway"] == "ship", what="the ship to take the vehicle")
        routing = shore.client.app.state.shore.routing  # type: ignore[attr-defined]
        first = shore.command(vehicle_id)
        until(lambda: [d.state for d in routing.dispatches(first)] == ["stored"], what="the ship's receipt")
        second = shore.command(vehicle_id)
        assert shore.client.post(f"/api/v1/commands/{second}/cancel", headers=OP).status_code == 200
        held = shore.client.post(f"/api/v1/commands/{first}/cancel", headers=OP)
        assert held.status_code == 202 and held.json()["status"] == "cancelling"
        until(lambda: shore.detail(first)["status"] == "cancelled", what="the ship's word of the withdrawal")
        step = shore.detail(first)["history"][-1]
        assert (step["source"], step["via"], step["detail"]) == (
            "gateway",
            "ship",
            "withdrawn from ship: never sent",
        )
        assert [d.state for d in routing.dispatches(first)] == ["withdrawn"]
        assert shore.vehicle.received == []

        third = shore.command(vehicle_id)
        until(lambda: [d.state for d in routing.dispatches(third)] == ["stored"], what="the third dispatched")
        assert routing.dispatches(second) == []
        dispatch = routing.dispatches(third)[0].id
        shore.outboxes["ship"].add_event("attempt", {"command": dispatch, "outcome": "sent", "attempt": 1})
        until(lambda: shore.detail(third)["status"] == "sent", what="the ship's report of an attempt")
        late = shore.client.post(f"/api/v1/commands/{third}/cancel", headers=OP)
        assert late.status_code == 409 and late.json()["detail"].endswith(
            "is sent already: it goes on as sent"
        )


def test_a_cancel_a_gateway_answers_with_an_attempt_lost_the_race(tmp_path: Path) -> None:
    """The center's dispatcher on a SQLite store, its publishes collected: a cancel of a command the ship
    holds withdraws it once; the ship's report that it was on the air first makes it sent (the cancel
    lost, it goes on as sent), and the withdrawal's end changes nothing more."""
    url = f"sqlite:///{tmp_path}/center.db"
    migrate(url)
    db = make_engine(url)
    with writing(db) as s:
        s.add(VehicleRow(name="rov1", address=2, key_hex="11" * 32))
        s.commit()
    config = Settings(database_url=url)
    desk = CommandDesk(db, Bus(), lambda _address: None, config.max_queued_commands, withdrawable=True)
    routing = Routing(db, config)
    published: list[bytes] = []

    async def publish(subject: str, payload: bytes, message_id: str) -> None:
        published.append(payload)

    dispatcher = Dispatcher(desk, routing, config, publish)
    command = desk.submit(1, CommandIn(command="hold"), "tester")
    now = time.time()
    dispatch = f"cmd-{command.id}-1"
    routing.add_dispatch(
        Dispatch(id=dispatch, command_id=command.id, gateway="ship", start_by=now + 60, deadline=now + 600)
    )
    assert desk.frame(command)  # signed and handed to the ship
    routing.report(dispatch, DispatchState.STORED, 0, "ship")
    assert desk.cancel(command.id, "alice").status == "cancelling"
    asyncio.run(dispatcher.step())
    asyncio.run(dispatcher.step())
    assert [subjects.down(p) for p in published] == [
        WithdrawMessage(f"withdraw-{dispatch}", "ship", dispatch, WithdrawReason.CANCELLED)
    ]

    def said(detail: dict[str, Any]) -> None:
        asyncio.run(
            dispatcher.on_event(
                EventMessage(f"ship-x-{time.time_ns()}", "ship", "attempt", time.time(), detail)
            )
        )

    said({"command": dispatch, "outcome": "sent", "attempt": 1})
    record, steps = desk.get(command.id)
    assert (
        record.status == "sent"
        and steps[-1].detail == "attempt 1 via ship: on the air before its withdrawal, the cancel lost"
    )
    said({"command": dispatch, "outcome": "withdrawn", "final": True})
    assert desk.get(command.id)[0].status == "sent"  # it goes on as sent (through the next gateway)
    assert [d.state for d in routing.dispatches(command.id)] == ["withdrawn"]
