"""A gateway's word is a claim, checked against what the center can check, integration tier: a real
nats-server with the accounts ``tacit broker-config`` writes (each gateway its own account and
credentials), the center (``tacit center``'s app, or its consumers alone) on a SQLite store, and gateways
whose modems are stand-ins that reach the vehicle, lie about it, or never transmit.

A gateway's report counts only for the commands that went through it; routing and "last heard" move
only on frames that verified; a frame from the future is refused; a gateway whose ACK the vehicle's
check-points refute, or that holds a command without a word, is routed around and shown faulty.
"""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.backhaul.center import Center, serve
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.relay import RelayIngest
from server.core.db import make_engine, writing
from server.core.events import Bus
from server.routing.service import ARRIVAL_SLACK
from server.vehicles.models import Vehicle as VehicleRow
from tacit import auth
from tacit import modem as mm
from tacit.packets import CheckpointPacket, MissionState
from tacit.streams import default_streams
from tests.integration.server.routing.test_choice import (
    ADDRESS,
    FAST,
    OP,
    StandInModem,
    Vehicle,
    settings,
    until,
)
from tests.support.nats import NATS_SERVER, Secured

pytestmark = pytest.mark.skipif(not Path(NATS_SERVER).exists(), reason="nats-server is not installed")

DAY = 86400.0


class LyingModem(StandInModem):
    """A shore modem that says every frame was ACKed and delivers none (a gateway that lies)."""

    async def send(
        self,
        dest: int,
        frames: list[bytes],
        rate: int = 0,
        ack: bool = True,
        ack_timeout: float | None = None,
    ) -> mm.TransmitResult:
        return mm.TransmitResult(
            dest, len(frames), transmitted=True, acked=frozenset(range(1, len(frames) + 1))
        )


class MuteModem(StandInModem):
    """A shore modem that never transmits: a send waits for ever (a gateway that holds what it gets)."""

    async def send(
        self,
        dest: int,
        frames: list[bytes],
        rate: int = 0,
        ack: bool = True,
        ack_timeout: float | None = None,
    ) -> mm.TransmitResult:
        await asyncio.Event().wait()
        raise AssertionError("unreachable")


class Shore:
    """The center's app on a client, the ``ship`` and ``buoy`` gateways with their own credentials, and
    the vehicle's end of the link."""

    def __init__(self, client: TestClient, server: Secured, tmp_path: Path, ship: type[StandInModem]) -> None:
        self.client = client
        self.vehicle = Vehicle()
        self.seq = 0
        self.outboxes = {name: Outbox(tmp_path / f"{name}.db", name) for name in ("ship", "buoy")}
        modems = {"ship": ship("ship", self.vehicle), "buoy": StandInModem("buoy", self.vehicle)}
        self.gateways = {
            name: Gateway(outbox, server.url, modems[name], heartbeat=0.2, timing=FAST,  # type: ignore[arg-type]
                          auth=server.credentials(f"gateway-{name}"))
            for name, outbox in self.outboxes.items()
        }  # fmt: skip

    def call(self, what: Any) -> None:
        assert self.client.portal is not None
        self.client.portal.call(what)

    def register(self) -> int:
        answer = self.client.post("/api/v1/vehicles", json={"name": "rov1", "address": ADDRESS}, headers=OP)
        assert answer.status_code == 201, answer.text
        self.vehicle.key = bytes.fromhex(answer.json()["key"])
        return int(answer.json()["id"])

    def heard(self, snr: dict[str, float], at: float | None = None, last_command: int = 0) -> None:
        """The vehicle sends a check-point stamped ``at``; each gateway in ``snr`` hears it at that SNR."""
        self.seq += 1
        at = time.time() if at is None else at
        cp = CheckpointPacket(
            seq=self.seq, time=int(at), state=MissionState.PREPROGRAMMED, last_command=last_command
        )
        data = auth.sign_checkpoint(cp, self.vehicle.key, 1, ADDRESS, [])
        for name, value in snr.items():
            self.outboxes[name].add_frame(ADDRESS, 0, data, rate=0, snr_in=value, at=at)

    def route(self, vehicle_id: int) -> dict[str, Any]:
        return next(
            r for r in self.client.get("/api/v1/routing", headers=OP).json() if r["vehicle_id"] == vehicle_id
        )

    def gateway(self, name: str) -> dict[str, Any]:
        return next(g for g in self.client.get("/api/v1/gateways", headers=OP).json() if g["name"] == name)

    def command(self, vehicle_id: int) -> int:
        answer = self.client.post(
            f"/api/v1/vehicles/{vehicle_id}/commands", json={"command": "hold"}, headers=OP
        )
        assert answer.status_code == 202, answer.text
        return int(answer.json()["id"])

    def detail(self, command_id: int) -> dict[str, Any]:
        return dict(self.client.get(f"/api/v1/commands/{command_id}", headers=OP).json())


@contextmanager
def running(
    secured: Secured, tmp_path: Path, sqlite_url: str, ship: type[StandInModem] = StandInModem, **changes: Any
) -> Iterator[Shore]:
    """The center (the broker's ``center`` user) on the SQLite store, and both gateways started."""
    app = create_app(
        settings(sqlite_url, **changes),
        RelayIngest,
        [lambda shore: serve(shore, secured.url, auth=secured.credentials("center"))],
    )
    with TestClient(app) as client:
        shore = Shore(client, secured, tmp_path, ship)
        for gateway in shore.gateways.values():
            shore.call(gateway.start)
        try:
            yield shore
        finally:
            for gateway in shore.gateways.values():
                shore.call(gateway.stop)


def test_a_forged_ack_from_another_gateway_leaves_the_command_alone(
    secured: Secured, tmp_path: Path, sqlite_url: str
) -> None:
    """The command goes through the ship, whose modem never gets to send it; the buoy, with its own
    credentials, reports it acked: ignored and counted, the command stays where it was."""
    with running(secured, tmp_path, sqlite_url, ship=MuteModem, gateway_faulty_slots=1000) as shore:
        vehicle_id = shore.register()
        shore.heard({"ship": 20.0, "buoy": 12.0})
        until(lambda: shore.route(vehicle_id)["gateway"] == "ship", what="the ship to take the vehicle")
        command = shore.command(vehicle_id)
        routing = shore.client.app.state.shore.routing  # type: ignore[attr-defined]
        until(lambda: [d.state for d in routing.dispatches(command)] == ["stored"], what="the ship's receipt")
        dispatch = routing.dispatches(command)[0].id
        for outcome in ("sent", "acked"):
            shore.outboxes["buoy"].add_event(
                "attempt", {"command": dispatch, "outcome": outcome, "attempt": 1}
            )
        shore.outboxes["buoy"].add_event("attempt", {"command": dispatch, "outcome": "acked", "final": True})
        until(lambda: shore.gateway("buoy")["foreign_reports"] == 3, what="the buoy's reports counted")
        assert shore.detail(command)["status"] == "queued"
        assert [(d.gateway, d.state) for d in routing.dispatches(command)] == [("ship", "stored")]
        assert [h["status"] for h in shore.detail(command)["history"]] == ["queued"]
        assert shore.gateway("ship")["foreign_reports"] == 0

        shore.outboxes["ship"].add_event("attempt", {"command": dispatch, "outcome": "sent", "attempt": 1})
        shore.outboxes["ship"].add_event("attempt", {"command": dispatch, "outcome": "acked", "final": True})
        until(
            lambda: shore.detail(command)["status"] == "acknowledged", what="the ship's own report"
        )  # the control
        step = shore.detail(command)["history"][-1]
        assert (step["status"], step["source"], step["via"]) == ("acknowledged", "gateway", "ship")


def test_random_bytes_at_a_claimed_30_db_do_not_move_routing(
    secured: Secured, tmp_path: Path, sqlite_url: str
) -> None:
    """The buoy publishes random bytes as the vehicle's frames at 30 dB: stored, but routing and the
    vehicle's last heard do not move; the vehicle's own check-point heard loud through the buoy does."""
    with running(secured, tmp_path, sqlite_url) as shore:
        vehicle_id = shore.register()
        shore.heard({"ship": 12.0})
        until(lambda: shore.route(vehicle_id)["gateway"] == "ship", what="the ship to take the vehicle")
        link = shore.client.app.state.shore.ingest  # type: ignore[attr-defined]
        heard = link.vehicles[ADDRESS].last_heard
        for _ in range(5):
            shore.outboxes["buoy"].add_frame(
                ADDRESS, 0, os.urandom(32), rate=0, snr_in=30.0, at=time.time() + 60
            )
        until(lambda: shore.gateway("buoy")["frames"] == 5, what="the random frames stored")
        routing = shore.client.app.state.shore.routing  # type: ignore[attr-defined]
        routing.update()  # with the frames stored (the dispatcher's tick does the same)
        route = shore.route(vehicle_id)
        assert route["gateway"] == "ship"
        assert [h["gateway"] for h in route["heard"]] == ["ship"]
        assert link.vehicles[ADDRESS].last_heard == heard

        shore.heard({"ship": 12.0, "buoy": 40.0})  # the vehicle's own word, loud through the buoy: it moves
        until(lambda: shore.route(vehicle_id)["gateway"] == "buoy", what="the buoy to take the vehicle")
        buoy = next(h for h in shore.route(vehicle_id)["heard"] if h["gateway"] == "buoy")
        assert buoy["frames"] == 1 and buoy["snr"] == 30.0  # capped at routing_snr_cap


def test_a_frame_from_the_future_is_refused_and_a_late_one_is_stored(
    secured: Secured, tmp_path: Path, sqlite_url: str
) -> None:
    """A genuine check-point stamped 30 days ahead is refused and counted, and does not move last
    heard; one heard 3 days ago (a backlog after an outage) is stored and verified."""
    config = settings(sqlite_url)
    key = bytes(range(32))

    def frame(seq: int, at: float) -> bytes:
        cp = CheckpointPacket(seq=seq, time=int(at), state=MissionState.PREPROGRAMMED)
        return auth.sign_checkpoint(cp, key, 1, ADDRESS, [])

    async def main() -> tuple[Center, RelayIngest]:
        ingest = RelayIngest(make_engine(sqlite_url), Bus(), default_streams(), config)
        with writing(ingest.db) as s:
            s.add(VehicleRow(name="rov1", address=ADDRESS, key_hex=key.hex()))
            s.commit()
        ingest.load_vehicles()
        outbox = Outbox(tmp_path / "ship.db", "ship")
        gateway = Gateway(outbox, secured.url, auth=secured.credentials("gateway-ship"))
        center = Center(ingest, secured.url, auth=secured.credentials("center"))
        await gateway.start()
        await center.connect()
        try:
            now = time.time()
            outbox.add_frame(ADDRESS, 0, frame(1, now - 3 * DAY), snr_in=10.0, at=now - 3 * DAY)
            outbox.add_frame(ADDRESS, 0, frame(2, now + 30 * DAY), snr_in=10.0, at=now + 30 * DAY)
            deadline = time.monotonic() + 15
            while center.counters["messages"] < 2:
                assert time.monotonic() < deadline, "timed out"
                await center.step()
        finally:
            await center.close()
            await gateway.stop()
        return center, ingest

    center, ingest = asyncio.run(main())
    assert center.guard.refused["future"] == 1
    assert ingest.stats["frames"] == 1
    last = ingest.vehicles[ADDRESS].last_heard
    assert last is not None and last < time.time() - 2 * DAY  # the late frame's time, not the future's


def test_a_gateway_whose_acks_the_vehicle_refutes_is_routed_around(
    secured: Secured, tmp_path: Path, sqlite_url: str
) -> None:
    """The ship hears the vehicle best and says it delivered the command; the vehicle's check-points,
    heard through the buoy, say it never arrived: the ship is shown faulty, the vehicle moves to the
    buoy and the command reaches it through the buoy."""
    with running(secured, tmp_path, sqlite_url, ship=LyingModem) as shore:
        vehicle_id = shore.register()
        shore.vehicle.reaches = {"buoy"}
        shore.heard({"ship": 20.0, "buoy": 12.0})
        until(lambda: shore.route(vehicle_id)["gateway"] == "ship", what="the ship to take the vehicle")
        command = shore.command(vehicle_id)
        until(lambda: shore.detail(command)["status"] == "acknowledged", what="the ship's claimed ACK")
        assert shore.vehicle.received == []
        assert shore.gateway("ship")["faulty"] == ""

        # stamped ARRIVAL_SLACK and heard a frame of slots after the ACK, and no later: the check-point
        # dates its frame itself (a gateway's claim), so a later date would also refute the buoy's ACK
        shore.heard({"buoy": 12.0}, at=time.time() + ARRIVAL_SLACK + 1.0, last_command=0)
        until(lambda: shore.gateway("ship")["faulty"] != "", what="the ship found faulty")
        assert "never arrived" in shore.gateway("ship")["faulty"]
        until(lambda: shore.detail(command)["status"] == "acknowledged" and shore.vehicle.received,
              what="the command through the buoy")  # fmt: skip
        seq = shore.detail(command)["seq"]
        assert shore.vehicle.received == [("buoy", seq)]
        assert shore.route(vehicle_id)["gateway"] == "buoy"
        steps = [(h["status"], h["source"], h["via"]) for h in shore.detail(command)["history"]]
        assert steps[0] == ("queued", "operator", "config-operator-1")  # the token's name
        assert ("acknowledged", "gateway", "ship") in steps
        assert ("sent", "vehicle", "") in steps  # the refutation: the command is the link's again
        assert steps[-1] == ("acknowledged", "gateway", "buoy")


def test_a_gateway_that_holds_a_command_without_a_word_is_routed_around_within_its_slots(
    secured: Secured, tmp_path: Path, sqlite_url: str
) -> None:
    """The ship stores the command and never transmits: after gateway_faulty_slots (3) of its slots it
    is faulty and the command goes through the buoy."""
    with running(secured, tmp_path, sqlite_url, ship=MuteModem, gateway_faulty_slots=3) as shore:
        vehicle_id = shore.register()
        shore.vehicle.reaches = {"ship", "buoy"}
        shore.heard({"ship": 20.0, "buoy": 12.0})
        until(lambda: shore.route(vehicle_id)["gateway"] == "ship", what="the ship to take the vehicle")
        command = shore.command(vehicle_id)
        until(lambda: shore.detail(command)["status"] == "acknowledged", timeout=30, what="the buoy's ACK")
        assert shore.vehicle.received == [("buoy", shore.detail(command)["seq"])]
        faulty = shore.gateway("ship")["faulty"]
        assert "held command" in faulty and "3 slots" in faulty
        routing = shore.client.app.state.shore.routing  # type: ignore[attr-defined]
        assert [(d.gateway, d.state) for d in routing.dispatches(command)] == [
            ("ship", "unanswered"),
            ("buoy", "acked"),
        ]
