"""The center's dispatcher and routing on a real SQLite store, the ship's reports as the broker delivers
them (``Dispatcher.on_event``):

- a gateway's ACK that comes after the center gave the gateway up (its backhaul was cut) wins, and a
  command the vehicle's modem acknowledged is never failed, only sent again, once per confirmation
  timeout, while no check-point confirms it (before, the late ACK left the dispatch "unanswered": the
  re-send found every gateway tried and asked to fail an acknowledged command, twice a second for ever);
- a command whose frame was signed before a SYNC that answered the vehicle's later challenge goes again,
  signed anew (before, the vehicle refused it while its modem ACKed it, until the confirmation timeout),
  and the stale frame is withdrawn from the gateway holding it;
- a command acknowledged through one gateway is withdrawn from every other gateway holding it.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass
from pathlib import Path

from server.backhaul import subjects
from server.backhaul.dispatch import Dispatcher
from server.backhaul.relay import RelayIngest
from server.backhaul.subjects import EventMessage, GatewayState, WithdrawMessage, WithdrawReason
from server.commands.models import CommandRecord
from server.commands.schemas import CommandIn
from server.core.config import Settings
from server.core.db import make_engine, migrate, saved_id
from server.routing.models import Dispatch, DispatchState
from server.shore import Shore
from server.vehicles.models import Vehicle
from server.vehicles.schemas import VehicleIn
from tacit import auth

CONFIRM = 1.0  # s: the confirmation timeout (time scale 1)


@dataclass
class Center:
    """The center's dispatcher and routing on a SQLite store, one vehicle pinned to the ship, one command
    queued; what it published, by message id."""

    shore: Shore
    dispatcher: Dispatcher
    vehicle: Vehicle
    command: CommandRecord
    published: list[str]
    withdrawn: list[tuple[str, str, WithdrawReason]]  # (gateway, dispatch, why)

    def dispatch(self, n: int) -> str:
        return f"cmd-{saved_id(self.command)}-{n}"

    def status(self) -> str:
        return str(self.shore.commands.get(saved_id(self.command))[0].status)

    def step(self) -> None:
        asyncio.run(self.dispatcher._vehicle(self.vehicle, time.time()))

    def reports(self, dispatch: str, *outcomes: tuple[str, bool]) -> None:
        """The ship's attempt reports of ``dispatch`` (outcome, final), as the broker delivers them."""
        for n, (outcome, final) in enumerate(outcomes):
            detail = {"command": dispatch, "outcome": outcome, "final": final, "attempt": 1}
            event = EventMessage(f"{dispatch}-e{n}", "ship", "attempt", time.time(), detail)
            asyncio.run(self.dispatcher.on_event(event))


def center(tmp_path: Path) -> Center:
    url = f"sqlite:///{tmp_path}/center.db"
    migrate(url)
    settings = Settings(database_url=url, map_enabled=False, confirm_timeout=CONFIRM, gateway_timeout=1e6)
    shore = Shore.build(settings, make_engine(url), RelayIngest)
    published: list[str] = []
    withdrawn: list[tuple[str, str, WithdrawReason]] = []

    async def publish(subject: str, payload: bytes, message_id: str) -> None:
        message = subjects.down(payload)
        assert message.id == message_id and subject == subjects.commands(message.gateway)
        published.append(message_id)
        if isinstance(message, WithdrawMessage):
            withdrawn.append((message.gateway, message.command, message.reason))

    dispatcher = Dispatcher(shore.commands, shore.routing, settings, publish)
    shore.routing.beat("ship", time.time(), GatewayState("i1", 0, "ready"))
    vehicle = shore.vehicles.create(VehicleIn(name="rov1", address=2))
    shore.routing.pin(saved_id(vehicle), "ship")
    command = shore.commands.submit(saved_id(vehicle), CommandIn(command="hold"), "operator")
    return Center(shore, dispatcher, vehicle, command, published, withdrawn)


def test_a_late_ack_wins_and_an_acknowledged_command_is_sent_again_not_failed(tmp_path: Path) -> None:
    c = center(tmp_path)
    one, two = c.dispatch(1), c.dispatch(2)
    c.step()
    assert c.published == [one]
    c.shore.routing.set_dispatch(one, DispatchState.UNANSWERED)  # the ship's backhaul cut: given up
    c.reports(one, ("sent", False), ("acked", True))  # the ship's reports, once its backhaul is back
    assert [d.state for d in c.shore.routing.dispatches(saved_id(c.command))] == [DispatchState.ACKED]
    assert c.status() == "acknowledged"

    c.step()  # no check-point yet, but not overdue: nothing
    assert c.published == [one]
    time.sleep(CONFIRM + 0.1)
    c.step()  # no check-point confirmed it: sent again, through the ship
    assert c.published == [one, two]
    c.shore.routing.set_dispatch(two, DispatchState.UNANSWERED)  # cut again: every gateway tried
    c.step()
    c.step()  # it waits, acknowledged (the vehicle's modem did ACK it): not failed, not sent
    assert c.published == [one, two] and c.status() == "acknowledged"
    time.sleep(CONFIRM + 0.1)
    c.step()  # overdue once more: a fresh round
    assert c.published == [one, two, c.dispatch(3)] and c.status() == "acknowledged"


def test_a_command_signed_before_a_later_answering_sync_goes_again_signed_anew(tmp_path: Path) -> None:
    """The ship holds the command's frame when the vehicle challenges again (its SYNC answer lost): the
    SYNC answering the new challenge moves the vehicle's replay floor past the frame's stamp, so the
    vehicle would refuse it though its modem ACKs it. The dispatch is superseded (not the ship's
    failure: it goes through the ship again), and what the ship reports of the old frame moves nothing."""
    c = center(tmp_path)
    one, two = c.dispatch(1), c.dispatch(2)
    c.step()
    c.reports(one, ("stored", False))
    c.dispatcher._answer_at[2] = time.time() + auth.FLOOR_SLACK + 1.0  # the answer to the new challenge
    c.step()
    states = [(d.gateway, d.state) for d in c.shore.routing.dispatches(saved_id(c.command))]
    assert c.published == [one, subjects.withdraw_id(one), two]  # the stale frame taken back first
    assert c.withdrawn == [("ship", one, WithdrawReason.SUPERSEDED)]
    assert states == [("ship", DispatchState.SUPERSEDED), ("ship", DispatchState.PUBLISHED)]
    c.reports(one, ("sent", False), ("acked", True))  # the old frame went out: refused, modem-ACKed
    assert c.status() == "queued"
    c.reports(two, ("sent", False), ("acked", True))
    assert c.status() == "acknowledged"
    c.step()
    assert c.published == [one, subjects.withdraw_id(one), two]  # once each


def test_an_ack_being_recorded_starts_no_new_round(tmp_path: Path) -> None:
    """The gateway's final ACK is recorded in two steps (the dispatch, then the command), in the events'
    task, beside the dispatcher's: between them the dispatcher must not take the command, still "sent",
    for one to dispatch through a new round (it did, through a gateway just killed, under load)."""
    c = center(tmp_path)
    c.step()
    c.reports(c.dispatch(1), ("sent", False))
    c.shore.routing.set_dispatch(c.dispatch(1), DispatchState.ACKED)  # the first of the two steps
    c.step()
    assert c.published == [c.dispatch(1)] and c.status() == "sent"


def test_a_command_acknowledged_through_one_gateway_is_withdrawn_from_the_others(tmp_path: Path) -> None:
    """The buoy holds a second dispatch of the command when the ship's ACK comes: the buoy's is
    superseded and withdrawn, the command acknowledged once."""
    c = center(tmp_path)
    c.step()
    other = Dispatch(
        id=c.dispatch(2), command_id=saved_id(c.command), gateway="buoy", start_by=time.time() + 60,
        deadline=time.time() + 600,
    )  # fmt: skip
    c.shore.routing.add_dispatch(other)
    c.reports(c.dispatch(1), ("sent", False), ("acked", True))
    assert c.status() == "acknowledged"
    assert c.withdrawn == [("buoy", c.dispatch(2), WithdrawReason.ACKNOWLEDGED)]
    states = {d.id: d.state for d in c.shore.routing.dispatches(saved_id(c.command))}
    assert states == {c.dispatch(1): DispatchState.ACKED, c.dispatch(2): DispatchState.SUPERSEDED}
