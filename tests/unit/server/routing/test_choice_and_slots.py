"""The assignment rule (``server.routing.choice``) and the gateways' TDMA frame (``gateway.slots``)."""

from __future__ import annotations

import math

import pytest

from gateway.slots import Schedule, SlotPlan, guard_for
from server.routing.choice import Current, Quality, choose

ALIVE = {"ship", "buoy"}


def heard(**snr: float) -> dict[str, Quality]:
    return {gateway: Quality(10, value, 1.0) for gateway, value in snr.items()}


def test_a_gateway_that_misses_frames_scores_lower() -> None:
    assert Quality(5, 20.0, 0.5).score == pytest.approx(20.0 - 10 * math.log10(2))
    assert Quality(0, 20.0, 0.0).score == -math.inf


def test_the_first_gateway_to_hear_a_vehicle_takes_it() -> None:
    decision = choose(None, heard(ship=10.0, buoy=14.0), ALIVE, 0.0, 3.0, 60.0)
    assert decision.gateway == "buoy" and decision.moved


def test_a_better_gateway_takes_the_vehicle_only_by_the_margin_and_after_the_dwell() -> None:
    on_ship = Current("ship", since=100.0)
    within = choose(on_ship, heard(ship=10.0, buoy=12.9), ALIVE, 1000.0, 3.0, 60.0)
    assert within.gateway == "ship" and not within.moved and "margin" in within.reason
    early = choose(on_ship, heard(ship=10.0, buoy=20.0), ALIVE, 159.0, 3.0, 60.0)
    assert early.gateway == "ship" and "dwell" in early.reason
    late = choose(on_ship, heard(ship=10.0, buoy=20.0), ALIVE, 160.0, 3.0, 60.0)
    assert late.gateway == "buoy" and late.moved


def test_a_silent_gateway_loses_its_vehicle_at_once_a_deaf_one_after_the_dwell() -> None:
    on_ship = Current("ship", since=100.0)
    silent = choose(on_ship, heard(ship=30.0, buoy=5.0), {"buoy"}, 101.0, 3.0, 60.0)
    assert silent.gateway == "buoy" and silent.moved and "silent" in silent.reason
    early = choose(on_ship, heard(buoy=5.0), ALIVE, 101.0, 3.0, 60.0)  # frames lost, or out of reach
    assert early.gateway == "ship" and not early.moved and "dwell" in early.reason
    deaf = choose(on_ship, heard(buoy=5.0), ALIVE, 160.0, 3.0, 60.0)
    assert deaf.gateway == "buoy" and deaf.moved


def test_a_pin_holds_whatever_the_scores() -> None:
    pinned = Current("ship", since=0.0, pinned=True)
    decision = choose(pinned, heard(ship=1.0, buoy=40.0), {"buoy"}, 1e6, 3.0, 60.0)
    assert decision.gateway == "ship" and not decision.moved


def test_slots_go_round_the_gateways_within_their_guards() -> None:
    plan = SlotPlan(epoch=1000.0, slot=10.0, guard=1.0, order=("buoy", "ship"))
    assert plan.owner(1000.0) == "buoy" and plan.owner(1015.0) == "ship" and plan.owner(1020.0) == "buoy"
    assert plan.next_start("ship", 1000.0, 5.0) == 1011.0  # its slot, after the guard
    assert plan.next_start("ship", 1013.0, 5.0) == 1013.0  # inside its slot, with room left
    assert plan.next_start("ship", 1014.5, 5.0) == 1031.0  # too late for this one: the next
    with pytest.raises(ValueError):
        plan.next_start("ship", 1000.0, 8.5)  # longer than the slot less its guards
    with pytest.raises(ValueError):
        plan.next_start("pier", 1000.0, 1.0)


def test_a_sync_is_stamped_for_the_opening_of_the_gateways_next_slot_as_its_gateway_will_send_it() -> None:
    schedule = Schedule()
    assert schedule.opening("ship", 5.0) == 5.0  # no plan: at will, at once
    schedule.receive(SlotPlan(epoch=0.0, slot=10.0, guard=1.0, order=("ship", "buoy")), now=5.0)
    schedule.receive(SlotPlan(epoch=40.0, slot=10.0, guard=1.0, order=("buoy", "pier", "ship")), now=6.0)
    assert schedule.opening("ship", 1.0) == 1.0  # a slot opening then
    assert schedule.opening("ship", 6.0) == 21.0  # its slot opened already: the next one's opening
    assert schedule.opening("buoy", 6.0) == 11.0
    assert schedule.opening("ship", 27.0) == 61.0  # the new plan's slot
    for after in (6.0, 12.5, 27.0, 45.0):  # the slot the gateway's MAC picks when it comes to it
        opening = schedule.opening("ship", after)
        assert schedule.start("ship", opening - 0.5, 3.0) == opening
    later = Schedule()  # only a plan to come: its first slot of the gateway's
    later.receive(SlotPlan(epoch=40.0, slot=10.0, guard=1.0, order=("buoy", "ship")), now=5.0)
    assert later.opening("ship", 6.0) == 51.0 == later.start("ship", 6.0, 3.0)


def test_the_guard_covers_half_the_travel_time_and_the_clock_error() -> None:
    assert guard_for(3000.0, 0.1) == pytest.approx(1.1)
    assert guard_for(3000.0, 1e-6, sound_speed=1500.0) == pytest.approx(1.0, abs=1e-5)


def test_a_new_plan_applies_at_its_epoch_and_no_transmission_straddles_it() -> None:
    schedule = Schedule()
    assert schedule.start("ship", 5.0, 3.0) == 5.0  # no plan: at will
    schedule.receive(SlotPlan(epoch=0.0, slot=10.0, guard=1.0, order=("ship", "buoy")), now=5.0)
    schedule.receive(SlotPlan(epoch=40.0, slot=10.0, guard=1.0, order=("buoy", "pier", "ship")), now=6.0)
    assert schedule.start("ship", 6.0, 3.0) == 6.0  # the plan in force until 40
    assert schedule.start("ship", 21.0, 3.0) == 21.0
    assert schedule.start("ship", 27.0, 3.0) == 61.0  # its next slot (40) is the new plan's buoy's
    assert schedule.start("ship", 45.0, 3.0) == 61.0
    assert schedule.current is not None and schedule.current.epoch == 40.0 and schedule.coming is None


def test_a_gateway_with_only_a_plan_to_come_transmits_nothing_before_its_epoch() -> None:
    """A gateway that starts after the center handed out a plan for a later epoch: until then the others
    follow a plan it does not know, so it waits (before, it took the plan at once, on a grid that could
    give it the others' slots)."""
    schedule = Schedule()
    schedule.receive(SlotPlan(epoch=40.0, slot=10.0, guard=1.0, order=("buoy", "ship")), now=6.0)
    assert schedule.current is None and schedule.start("ship", 6.0, 3.0) == 51.0  # its first slot
    assert schedule.start("pier", 6.0, 3.0) == 40.0  # not in it: at will, from the epoch on
    assert schedule.plan(39.0) is None and schedule.plan(40.0) is not None


def test_a_second_plan_from_the_same_epoch_is_not_taken_for_a_duplicate() -> None:
    """The broker drops a message whose id it has seen: each plan's messages have ids of their own (a
    gateway joining a second after the first had its plan still reaches the first)."""
    import asyncio

    from server.backhaul.dispatch import Dispatcher
    from server.backhaul.subjects import ScheduleMessage
    from server.core.config import Settings
    from server.routing.service import Route
    from server.vehicles.models import Vehicle

    class Alive:
        gateways: set[str] = {"ship"}

        def alive(self, now: float) -> set[str]:
            return self.gateways

    sent: list[tuple[str, ScheduleMessage]] = []

    async def publish(subject: str, payload: bytes, message_id: str) -> None:
        message = ScheduleMessage.decode(payload)
        assert message.id == message_id
        sent.append((subject, message))

    routing = Alive()
    dispatcher = Dispatcher(None, routing, Settings(tdma_slot=10.0), publish)  # type: ignore[arg-type]
    routes = [Route(Vehicle(name="rov1", address=2, key_hex="00" * 32), "ship", False, None, "heard")]
    asyncio.run(dispatcher._schedule(1000.2, routes))
    routing.gateways = {"ship", "buoy"}
    asyncio.run(dispatcher._schedule(1000.7, routes))  # the same epoch
    asyncio.run(dispatcher._schedule(1000.9, routes))  # nothing changed: nothing sent
    assert [(s, m.order, m.epoch) for s, m in sent] == [
        ("tacit.v1.schedule.ship", ("ship",), 1020.0),
        ("tacit.v1.schedule.buoy", ("buoy", "ship"), 1020.0),
        ("tacit.v1.schedule.ship", ("buoy", "ship"), 1020.0),
    ]
    assert len({m.id for _, m in sent}) == 3


def test_a_vehicle_is_commanded_by_the_process_that_decodes_it_once_a_sync_answered_it() -> None:
    """Of several center processes only the one holding a vehicle's link state knows whether a SYNC has
    answered its check-points: another, the coordinator too, does not send it commands (the vehicle
    would refuse one that came before the answer). A center that sends no SYNCs commands from its
    coordinator alone."""
    import time

    from server.backhaul.dispatch import Dispatcher
    from server.core.config import Settings
    from server.link.heartbeat import Heartbeat
    from server.link.state import VehicleState
    from server.routing.service import Route
    from server.vehicles.models import Vehicle

    states: list[VehicleState] = []
    heartbeat = Heartbeat(Settings(), None, None, None, lambda state, floor: floor)  # type: ignore[arg-type]

    async def publish(subject: str, payload: bytes, message_id: str) -> None:
        raise AssertionError("nothing is published here")

    dispatcher = Dispatcher(None, None, Settings(), publish, heartbeat, lambda: states)  # type: ignore[arg-type]
    routes = [Route(Vehicle(id=1, name="auv2", address=2, key_hex="00" * 32), "ship", False, None, "best")]
    assert dispatcher._commandable(routes, coordinating=True) == set()  # another process decodes it
    state = VehicleState(1, "auv2", 2, {})  # type: ignore[arg-type]
    states.append(state)
    assert dispatcher._commandable(routes, coordinating=False) == set()  # decoded here, not heard yet
    state.link.checkpoint, state.link.echo = {"seq": 1}, b"challenge"
    assert dispatcher._commandable(routes, coordinating=False) == set()  # its challenge waits for its answer
    state.link.echo = None
    assert dispatcher._commandable(routes, coordinating=False) == {2}
    dispatcher._answer_at[2] = time.time() + 60.0
    assert dispatcher._commandable(routes, coordinating=False) == set()  # the answer's slot is still ahead
    dispatcher._answer_at.clear()
    dispatcher.decoding = lambda address: False  # its partition's lease not renewed: another may hold it
    assert dispatcher._commandable(routes, coordinating=False) == set()
    no_syncs = Dispatcher(None, None, Settings(), publish)  # type: ignore[arg-type]
    assert no_syncs._commandable(routes, coordinating=True) == {2}
    assert no_syncs._commandable(routes, coordinating=False) == set()
