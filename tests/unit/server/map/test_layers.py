"""The map's layers on a stand-in for viser's scene: each draws what it is given, in the right place
and colour, and takes away what is gone."""

from __future__ import annotations

import numpy as np

from server.core.events import PacketsSettled, TelemetryDecoded
from server.map.field import PENDING_COLOUR, FieldLayer
from server.map.gateways import GatewayLayer
from server.map.ground import Ground, water_extent
from server.map.plans import PlanLayer
from server.map.vehicles import OVERDUE_COLOUR, VehicleLayer
from server.missions.models import TeamMission, TeamStatus
from server.safety.paths import Planned
from server.telemetry.field import TemperatureField
from tests.support.viser import FakeScene

COLOURS = {"rov1": (1, 2, 3), "rov2": (4, 5, 6)}


def cp(north: float, east: float, heading: float = 0.0) -> dict:
    return {"north": north, "east": east, "depth": 2.0, "heading": heading, "state": "holding"}


def test_vehicles_are_placed_turned_greyed_when_overdue_and_their_labels_stacked() -> None:
    scene = FakeScene()
    layer = VehicleLayer(scene, COLOURS.__getitem__)
    layer.label_gap = 4.0
    layer.checkpoint("rov1", cp(10.0, 20.0, heading=90.0))
    frame = scene.nodes["/vehicles/rov1"]
    assert frame.position == (20.0, 10.0, -2.0) and np.allclose(frame.wxyz, (1.0, 0.0, 0.0, 0.0))  # east
    assert scene.nodes["/vehicles/rov1/body"].color == (1, 2, 3)
    layer.label("rov1", cp(10.0, 20.0), 42.0, overdue=True)
    assert "OVERDUE" in scene.nodes["/labels/rov1"].text
    assert scene.nodes["/vehicles/rov1/body"].color == OVERDUE_COLOUR
    layer.checkpoint("rov2", cp(11.0, 21.0, heading=0.0))  # a metre away: the labels would overlap
    first, second = scene.nodes["/labels/rov1"].position, scene.nodes["/labels/rov2"].position
    assert first[:2] == (20.0, 10.0) and second[:2] == (21.0, 14.0) and "/labels/rov2/leader" in scene.nodes
    layer.checkpoint("rov2", cp(11.0, 200.0))  # far apart: back on its vehicle, without a leader
    assert scene.nodes["/labels/rov2"].position[:2] == (200.0, 11.0)
    assert "/labels/rov2/leader" not in scene.nodes


def test_plans_draw_the_checked_paths_and_the_lanes_of_teams_that_may_run() -> None:
    scene = FakeScene()
    layer = PlanLayer(scene, COLOURS.__getitem__)
    path = Planned("rov1", (), (), ((0.0, 0.0, 2.0), (10.0, 5.0, 2.0)), 1.0, ())
    member = {"name": "rov2", "waypoints": [[0.0, 30.0, 3.0], [40.0, 30.0, 3.0]]}
    area = [[0.0, 25.0], [40.0, 25.0], [40.0, 35.0], [0.0, 35.0]]
    team = TeamMission(id=7, name="survey", area=area, spacing=5.0, depth=3.0, members=[member])
    ended = TeamMission(id=8, name="old", area=area, spacing=5.0, depth=3.0, members=[member],
                        status=TeamStatus.FINISHED)  # fmt: skip
    layer.draw([path], [team, ended])
    line = scene.nodes["/planned/rov1"]
    assert line.args[1] == (1, 2, 3) and tuple(line.args[0][0][1]) == (5.0, 10.0, -2.0)
    assert scene.nodes["/teams/7/lanes/rov2"].args[1] == (4, 5, 6)
    assert "team survey: created" in scene.nodes["/teams/7/label"].args[0]
    assert not [n for n in scene.nodes if n.startswith("/teams/8")]
    layer.draw([], [])
    assert not [n for n in scene.nodes if n.startswith(("/planned", "/teams"))]


def test_gateways_stand_at_their_places_in_their_colours_with_a_line_to_each_vehicle() -> None:
    scene = FakeScene()
    layer = GatewayLayer(scene, COLOURS.__getitem__)
    gateway = {"name": "ship", "alive": True, "for_s": 3.0, "colour": "#6a3d9a", "vehicles": [],
               "place": {"north": 0.0, "east": -300.0, "depth": 1.0}}  # fmt: skip
    vehicle = {"name": "rov1", "gateway": "ship", "reported": cp(5.0, 6.0)}
    layer.draw([gateway], [vehicle])
    assert scene.nodes["/gateways/ship"].color == (0x6A, 0x3D, 0x9A)
    assert scene.nodes["/gateways/ship/label"].args[0] == "Gateway ship: up for 3 s"
    assert tuple(scene.nodes["/gateway_links/rov1"].args[0][0][1]) == (-300.0, 0.0, -1.0)
    layer.draw([{**gateway, "place": None}], [vehicle])
    assert "/gateway_links/rov1" not in scene.nodes


def test_the_water_covers_every_gateway() -> None:
    east, north, width, height = water_extent([(0.0, -300.0), (0.0, 600.0)])
    assert east - width / 2 <= -350.0 and east + width / 2 >= 650.0 and height >= 300.0
    scene = FakeScene()
    ground = Ground(scene, "fleet origin (0, 0)")
    ground.build()
    ground.cover([(0.0, 600.0)])
    assert scene.nodes["/water"].width >= 650.0


def decoded(packet_id: int, temperature: float) -> TelemetryDecoded:
    return TelemetryDecoded(packet_id=packet_id, vehicle="rov1", stream="env", channels=["temperature", "depth"],
                            period=1.0, times=[0.0], values=[[temperature, 2.0]], lost=None)  # fmt: skip


def test_the_field_layer_draws_pending_grey_then_verified_coloured_and_the_suggestion() -> None:
    scene = FakeScene()
    layer = FieldLayer(scene, TemperatureField())
    layer.decoded(decoded(1, 20.0), cp(0.0, 0.0))
    assert scene.nodes["/temperature/pending"].args[1] == PENDING_COLOUR
    layer.settled(PacketsSettled(vehicle="rov1", verified=[1], forged=[], trusted=[1]))
    assert "/temperature/pending" not in scene.nodes and layer.range == (20.0, 20.0)
    assert not layer.fit() and layer.suggestion is None  # one sample: nothing to fit
    for north in range(0, 50, 5):
        layer.checkpoint({**cp(float(north), float(north % 20)), "temperature": 20.0 + north / 10})
    assert layer.fit() and layer.suggestion is not None and layer.estimate is not None
    north, east = layer.suggestion
    assert scene.nodes["/temperature/suggested"].position == (east, north, -2.0)
