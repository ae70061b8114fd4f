"""The screens' gateways, integration tier: the center's app on PostgreSQL with a real
nats-server and two gateways on the routing tests' stand-in modems (``routing/test_choice``'s rig), each told
where its modem is. ``GET /api/v1/gateways`` (what the dashboard and the map both show) says each
gateway's place, modem, outbox, backhaul state and since when, its last outage with the backlog it came
back with, its frames and vehicles; ``GET /fleet`` each vehicle's gateway and pin; ``GET /packets`` which
gateways heard a frame, with their SNR, the kept copy marked; the map stands the gateways at their places
with a line from each vehicle to its gateway. ``tacit serve`` (one shore modem) lists no gateway and
shows its modem's SNR. A heartbeat whose detail is not one is a logged refusal."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.backhaul import subjects
from server.backhaul.guard import Guard
from server.backhaul.subjects import EventMessage, Place
from server.link.state import IncomingFrame
from server.map.scene import OperatorMap
from server.screens.fleet import GATEWAYS, PALETTE, rgb
from tacit import auth
from tacit.packets import CheckpointPacket, MissionState
from tests.integration.server.map.test_panel import panel_for
from tests.integration.server.routing.test_choice import ADDRESS, OP, Layout, running_center, until
from tests.support.api import offline_settings
from tests.support.nats import NATS_SERVER, NatsServer
from tests.support.viser import fake_server

needs_nats = pytest.mark.skipif(not Path(NATS_SERVER).exists(), reason="nats-server is not installed")
PLACES = {"ship": (Place(0.0, -300.0, 1.0), 1), "buoy": (Place(0.0, 600.0, 1.0), 101)}


@pytest.fixture
def layout(broker: NatsServer, tmp_path: Path, postgres_server: str) -> Iterator[Layout]:
    """The center (the fleet's origin known) and its two gateways, each told its modem's place."""

    def placed(layout: Layout) -> None:
        for name, (place, address) in PLACES.items():
            layout.gateways[name].place, layout.gateways[name].address = place, address

    with running_center(broker, tmp_path, postgres_server, placed, origin=(40.0, -74.0)) as layout:
        yield layout


def gateways(layout: Layout) -> dict[str, dict[str, Any]]:
    answer = layout.client.get("/api/v1/gateways", headers=OP)
    assert answer.status_code == 200, answer.text
    return {g["name"]: g for g in answer.json()}


def fleet_row(layout: Layout) -> dict[str, Any]:
    return dict(layout.client.get("/api/v1/fleet", headers=OP).json()["vehicles"][0])


@needs_nats
def test_every_gateway_its_place_state_outbox_frames_and_vehicles_on_the_api_and_the_map(
    layout: Layout,
) -> None:
    vehicle_id = layout.register()
    for _ in range(3):
        layout.heard({"ship": 12.0, "buoy": 4.0})
    until(lambda: fleet_row(layout)["gateway"] == "ship", what="rov1 on the ship")
    until(lambda: all(g["frames"] == 3 for g in gateways(layout).values()), what="the frames counted")
    ship, buoy = gateways(layout)["ship"], gateways(layout)["buoy"]
    assert ship["alive"] and ship["state"] == "up" and ship["for_s"] >= 0 and ship["since"] <= time.time()
    assert ship["place"] == {"north": 0.0, "east": -300.0, "depth": 1.0} and buoy["place"]["east"] == 600.0
    assert ship["latlon"][0] == pytest.approx(40.0, abs=1e-4) and ship["latlon"][1] < -74.0  # west of it
    assert (ship["address"], ship["modem"], buoy["address"]) == (1, "ready", 101)
    assert ship["outbox"] == 0 and ship["last_outage"] is None and ship["colour"] == GATEWAYS[1]
    until(
        lambda: "poll" in (gateways(layout)["ship"]["mac"] or {}).get("exchanges", {}), what="the ship's MAC"
    )
    mac = gateways(layout)["ship"]["mac"]  # its MAC's status, from its heartbeat: polling rov1 at rate 0
    assert mac["refused"] == "" and mac["vehicles"][str(ADDRESS)]["rate"] == 0
    assert (
        ship["vehicles"] == [{"id": vehicle_id, "name": "rov1", "pinned": False}] and buoy["vehicles"] == []
    )

    # a frame's row: every gateway that heard it with its SNR, the kept copy (the best) marked
    packets = layout.client.get("/api/v1/packets", headers=OP).json()["items"]
    assert len(packets) == 3
    for packet in packets:
        assert packet["snr"] == 12.0
        assert sorted((c["gateway"], c["snr"], c["kept"]) for c in packet["heard"]) == [
            ("buoy", 4.0, False),
            ("ship", 12.0, True),
        ]

    # the map: each gateway at its place, a line in the vehicle's colour from it to its gateway
    shore = layout.client.app.state.shore
    owner = OperatorMap(
        shore.screens,
        shore.commands,
        shore.bus,
        shore.settings,
        shore.operators.actor,
        shore.safety.paths,
        shore.teams.every,
    )
    owner.attach(fake_server())
    panel = owner.panels[1] = panel_for(owner)
    owner.tick()
    assert (
        "via gateway ship" in panel.fleet_html.content and "**Gateway buoy**: up for" in panel.link_md.content
    )
    nodes = owner.server.scene.nodes
    assert nodes["/gateways/ship"].position == (-300.0, 0.0, -1.0)  # (east, north, -depth)
    assert nodes["/gateways/buoy"].position == (600.0, 0.0, -1.0)
    assert nodes["/gateways/ship"].color == rgb(GATEWAYS[1]) and nodes["/gateways/buoy"].color == rgb(
        GATEWAYS[0]
    )
    assert "Gateway ship: up for" in nodes["/gateways/ship/label"].args[0]
    line = nodes["/gateway_links/rov1"]
    assert line.args[1] == rgb(PALETTE[0]) and tuple(line.args[0][0][1]) == (-300.0, 0.0, -1.0)

    # a pin shows on both lists
    assert layout.client.put(
        f"/api/v1/vehicles/{vehicle_id}/gateway", json={"gateway": "buoy"}, headers=OP
    ).is_success
    assert (fleet_row(layout)["gateway"], fleet_row(layout)["gateway_pinned"]) == ("buoy", True)
    assert gateways(layout)["buoy"]["vehicles"] == [{"id": vehicle_id, "name": "rov1", "pinned": True}]
    owner.tick()
    assert tuple(nodes["/gateway_links/rov1"].args[0][0][1]) == (600.0, 0.0, -1.0)


@needs_nats
def test_a_silent_gateway_and_an_outage_the_gateway_reports_with_its_backlog(
    layout: Layout, broker: NatsServer
) -> None:
    layout.register()
    until(lambda: len(gateways(layout)) == 2, what="both gateways heard from")
    broker.stop()  # every backhaul down: the ship's modem goes on hearing, its outbox fills
    for _ in range(4):
        layout.heard({"ship": 10.0})
    assert layout.outboxes["ship"].depth() >= 4
    until(lambda: layout.gateways["ship"].down_since is not None, what="the ship noticing the outage")
    broker.start()
    until(lambda: gateways(layout)["ship"]["last_outage"] is not None, what="the ship's outage reported")
    outage = gateways(layout)["ship"]["last_outage"]
    assert outage["lasted_s"] > 0 and outage["backlog"] >= 4 and outage["ended"] <= time.time()
    until(lambda: gateways(layout)["ship"]["outbox"] == 0, what="the backlog sent")
    assert gateways(layout)["ship"]["frames"] == 4

    layout.stop("buoy")  # silent: no heartbeat for the gateway timeout (5 s here)
    until(lambda: not gateways(layout)["buoy"]["alive"], what="the buoy silent")
    buoy, ship = gateways(layout)["buoy"], gateways(layout)["ship"]
    assert buoy["state"] == "silent" and buoy["since"] == buoy["last_seen"] and buoy["for_s"] >= 5.0
    assert buoy["colour"] not in GATEWAYS and ship["state"] == "up"


def test_a_heartbeat_that_is_not_one_is_refused() -> None:
    guard = Guard()
    for detail in ({"incarnation": "a", "outbox": "many"}, {"incarnation": "a", "outbox": 0, "place": "here"},
                   {"incarnation": "a", "outbox": 0, "place": {"north": 1, "east": float("nan"), "depth": 0}}):  # fmt: skip
        beat = EventMessage("ship-beat-1", "ship", "heartbeat", time.time(), detail)
        assert guard.event(subjects.events("ship"), beat.encode(), time.time()) is None
    assert guard.refused["malformed"] == 3
    good = EventMessage("ship-beat-2", "ship", "heartbeat", time.time(), {"incarnation": "a", "outbox": 0})
    assert guard.event(subjects.events("ship"), good.encode(), time.time()) is not None


def test_one_shore_modem_lists_no_gateway_and_shows_its_snr(tmp_path: Path) -> None:
    with TestClient(create_app(offline_settings(tmp_path))) as client:
        answer = client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP)
        key = bytes.fromhex(answer.json()["key"])
        cp = CheckpointPacket(seq=1, time=int(time.time()), state=MissionState.PREPROGRAMMED)
        shore = client.app.state.shore
        shore.ingest.handle(IncomingFrame(2, 1, auth.sign_checkpoint(cp, key, 1, 2, []), snr_in=9.5))
        assert client.get("/api/v1/gateways", headers=OP).json() == []
        row = client.get("/api/v1/fleet", headers=OP).json()["vehicles"][0]
        assert (row["gateway"], row["gateway_pinned"]) == (None, False)
        [packet] = client.get("/api/v1/packets", headers=OP).json()["items"]
        assert (packet["snr"], packet["heard"]) == (9.5, [])
        owner = OperatorMap(
            shore.screens,
            shore.commands,
            shore.bus,
            shore.settings,
            shore.operators.actor,
            shore.safety.paths,
            shore.teams.every,
        )
        owner.attach(fake_server())
        owner.tick()
        assert not [n for n in owner.server.scene.nodes if n.startswith(("/gateways", "/gateway_links"))]


def test_a_gateway_is_told_its_place_as_every_position_in_the_fleet() -> None:
    assert Place.parse("5,3") == Place(5.0, 3.0, 0.0) and Place.parse("-300,0,1") == Place(-300.0, 0.0, 1.0)
    for wrong in ("here", "1", "1,nan", "1,2,3,4"):
        with pytest.raises(ValueError, match="NORTH,EAST"):
            Place.parse(wrong)
