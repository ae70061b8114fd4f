"""The center's SYNC sets the vehicle's clock to within seconds of the shore's, however long it waits at
its gateway for a slot: the center stamps it for the opening of the gateway's next slot, and the gateway
sends it only then (``server.backhaul.dispatch``, ``server.backhaul.gateway``).

A gateway on a simulated Micro-Modem, 10 s TDMA slots, a vehicle's agent on another modem.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from tacit.packets import ControlPacket
from tests.integration.server.backhaul.test_budget import (
    ADDRESS,
    answered,
    scheduled,
    ship_and_rov1,
    until,
)
from tests.support.nats import NATS_SERVER, NatsServer
from vehicle_agent.agent import Agent

pytestmark = pytest.mark.skipif(not Path(NATS_SERVER).exists(), reason="nats-server is not installed")

SLOT = 10.0  # s of wall time: a SYNC signed just after the gateway's slot opened waits most of one


@contextmanager
def rig(
    broker: NatsServer, tmp_path: Path, prepare: Callable[[Agent], None]
) -> Iterator[tuple[TestClient, Agent, Callable[[], None], list[tuple[ControlPacket, float]]]]:
    """The center, the ship's gateway and the agent (``prepare``d before its modem starts); yields the
    client, the agent, what makes the ship hear the agent's next check-point just after the ship's slot
    opened (a SYNC signed then waits most of a slot), and each packet the agent accepted with its clock
    offset then."""
    accepted: list[tuple[ControlPacket, float]] = []

    def heard(agent: Agent, packet: ControlPacket) -> None:
        accepted.append((packet, agent.link.offset))

    with ship_and_rov1(broker, tmp_path, SLOT, prepare, heard) as (client, gateway, outbox, agent):

        def checkpoint_heard() -> None:
            plan = gateway.schedule.plan(time.time())
            assert plan is not None
            time.sleep(max(0.0, plan.next_slot("ship", time.time()) + 0.5 - time.time()))  # just opened
            agent._send_checkpoint()
            report = agent.link.queue.pop().data
            outbox.add_frame(ADDRESS, 0, report, snr_in=20.0)

        until(lambda: gateway.schedule.plan(time.time()) is not None, what="the ship's slots")
        yield client, agent, checkpoint_heard, accepted


def test_the_centers_sync_sets_the_vehicles_clock_to_within_seconds_after_waiting_for_its_slot(
    broker: NatsServer, tmp_path: Path
) -> None:
    """The agent's clock five minutes ahead; the center hears its check-point just after the ship's slot
    opened and sends its SYNC at once: the first SYNC the agent hears sets its clock to within 3 s."""

    def ahead(agent: Agent) -> None:
        answered(agent, time.time())
        agent.link.offset = 300.0  # its clock stepped five minutes ahead since

    with rig(broker, tmp_path, ahead) as (_, _, checkpoint_heard, accepted):
        checkpoint_heard()  # the center's SYNC is due
        until(lambda: any(not scheduled(p) for p, _ in accepted), timeout=60, what="the center's SYNC")
    offset = next(offset for packet, offset in accepted if not scheduled(packet))
    assert abs(offset) <= 3.0, f"the vehicle's clock is {offset:+.1f} s from the shore's after its SYNC"
