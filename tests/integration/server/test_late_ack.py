"""A gateway's ACK that comes after the center gave the gateway up (its backhaul was cut): the gateway's
word wins, and a command the vehicle's modem acknowledged is never failed, only sent again, once per
confirmation timeout, while no check-point confirms it. The center's dispatcher and routing on a real
SQLite store; the gateway's reports as the broker delivers them (``Dispatcher.on_event``).

Before, the late ACK left the dispatch "unanswered": the re-send found every gateway tried and asked to
fail an acknowledged command, which the lifecycle refuses, twice a second for ever.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

from server.backhaul.dispatch import Dispatcher
from server.backhaul.relay import RelayIngest
from server.backhaul.subjects import CommandMessage, EventMessage, GatewayState
from server.commands.schemas import CommandIn
from server.core.config import Settings
from server.core.db import make_engine, migrate, saved_id
from server.routing.models import DispatchState
from server.shore import Shore
from server.vehicles.schemas import VehicleIn

CONFIRM = 1.0  # s: the confirmation timeout (time scale 1)


def test_a_late_ack_wins_and_an_acknowledged_command_is_sent_again_not_failed(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path}/center.db"
    migrate(url)
    settings = Settings(database_url=url, map_enabled=False, confirm_timeout=CONFIRM, gateway_timeout=1e6)
    shore = Shore.build(settings, make_engine(url), RelayIngest)
    published: list[str] = []

    async def publish(subject: str, payload: bytes, message_id: str) -> None:
        assert CommandMessage.decode(payload).id == message_id
        published.append(message_id)

    dispatcher = Dispatcher(shore.commands, shore.routing, settings, publish)
    shore.routing.beat("ship", time.time(), GatewayState("i1", 0, "ready"))
    vehicle = shore.vehicles.create(VehicleIn(name="rov1", address=2))
    shore.routing.pin(saved_id(vehicle), "ship")
    command = shore.commands.submit(saved_id(vehicle), CommandIn(command="hold"), "operator")
    one = f"cmd-{saved_id(command)}-1"

    def status() -> str:
        return str(shore.commands.get(saved_id(command))[0].status)

    def step() -> None:
        asyncio.run(dispatcher._vehicle(vehicle, time.time()))

    step()
    assert published == [one]
    shore.routing.set_dispatch(one, DispatchState.UNANSWERED)  # the ship's backhaul cut: given up
    for n, (outcome, final) in enumerate([("sent", False), ("acked", True)]):  # the ship's reports, once
        detail = {"command": one, "outcome": outcome, "final": final, "attempt": 1}  # its backhaul is back
        asyncio.run(dispatcher.on_event(EventMessage(f"e{n}", "ship", "attempt", time.time(), detail)))
    assert [d.state for d in shore.routing.dispatches(saved_id(command))] == [DispatchState.ACKED]
    assert status() == "acknowledged"

    step()  # no check-point yet, but not overdue: nothing
    assert published == [one]
    time.sleep(CONFIRM + 0.1)
    step()  # no check-point confirmed it: sent again, through the ship
    two = f"cmd-{saved_id(command)}-2"
    assert published == [one, two]
    shore.routing.set_dispatch(two, DispatchState.UNANSWERED)  # cut again: every gateway tried
    step()
    step()  # it waits, acknowledged (the vehicle's modem did ACK it): not failed, not sent
    assert published == [one, two] and status() == "acknowledged"
    time.sleep(CONFIRM + 0.1)
    step()  # overdue once more: a fresh round
    assert published == [one, two, f"cmd-{saved_id(command)}-3"] and status() == "acknowledged"
