"""What the operator's screens share: one command form from the packet table and the vehicle's limits,
the form's rules (blank or out-of-range fields refused before sending), bearings up to 360 accepted by
the API, the last check-point and the shore's prediction with its uncertainty (after a restart too),
and the link's airtime shares."""

from __future__ import annotations

import pytest

from server.commands.schemas import CommandIn
from server.screens import airtime, estimate
from server.screens import form as operator
from tacit.limits import Limits
from tacit.packets import ControlPacket

OP = {"Authorization": "Bearer operator-token"}
OBS = {"Authorization": "Bearer observer-token"}


def test_the_form_comes_from_the_packet_table_and_the_vehicle_limits() -> None:
    wire = {f.name: f for f in ControlPacket.FIELDS}
    bare = operator.command_form()
    move = operator.field_specs(bare, "move")
    assert [f["name"] for f in move] == ["distance", "angle", "depth", "speed"]
    assert (move[0]["max"], move[0]["step"], move[0]["unit"]) == (wire["distance"].hi, 0.1, "m")
    assert move[1]["label"] == "Turn from heading" and (move[1]["min"], move[1]["max"]) == (-180, 180)
    bearing = operator.field_specs(bare, "move", "bearing")[1]
    assert bearing["label"] == "Bearing (true)" and (bearing["min"], bearing["max"]) == (0, 360)
    assert move[2]["label"] == "Depth change"
    assert operator.field_specs(bare, "goto_depth")[0]["label"] == "Target depth"
    assert operator.field_specs(bare, "hold") == []
    limited = operator.command_form(Limits(max_depth=20.0, max_distance=50.0, max_speed=0.8))
    distance, _, depth, speed = operator.field_specs(limited, "move")
    assert (distance["max"], depth["min"], depth["max"], speed["max"]) == (50.0, -20.0, 20.0, 0.8)
    assert operator.field_specs(limited, "goto_depth")[0]["max"] == 20.0
    # the API's ranges are the packet's (one source: a change to one shows here)
    schema = CommandIn.model_json_schema()["properties"]
    assert schema["distance"]["maximum"] == wire["distance"].hi
    assert schema["depth"]["minimum"] == wire["depth"].lo and schema["depth"]["maximum"] == wire["depth"].hi


def test_the_form_refuses_blank_and_out_of_range_fields() -> None:
    form = operator.command_form(Limits(max_depth=20.0, max_distance=50.0))
    with pytest.raises(ValueError, match="distance: Distance is required"):
        operator.check_form(form, "move", {"distance": None, "angle": 0, "depth": 0})
    with pytest.raises(ValueError, match="distance: Distance must be 0 .. 50 m"):
        operator.check_form(form, "move", {"distance": 60, "angle": 0, "depth": 0})
    with pytest.raises(ValueError, match="angle"):
        operator.check_form(form, "move", {"distance": 5, "angle": 200, "depth": 0})
    with pytest.raises(ValueError, match="depth: Target depth"):
        operator.check_form(form, "goto_depth", {"depth": 25})
    body = operator.check_form(
        form, "move", {"distance": 5, "angle": 270, "depth": 1, "speed": None}, "bearing"
    )
    assert body == {"command": "move", "distance": 5.0, "angle": 270.0, "depth": 1.0, "absolute_angle": True}
    assert CommandIn(**body).angle == -90.0  # the same direction, as the packet's field holds it
    assert operator.check_form(form, "hold", {"distance": None}) == {"command": "hold"}
    assert operator.check_form(form, "start_mission", {"param_id": 3}) == {
        "command": "start_mission",
        "param_id": 3,
    }


def test_prediction_moves_toward_the_target_and_grows_uncertain() -> None:
    cp = {"north": 0.0, "east": 0.0, "depth": 2.0, "heading": 0.0, "state": "preprogrammed", "waypoint": 1}
    target = estimate.target_of(
        cp, [{"north": 0, "east": 0, "depth": 2}, {"north": 20, "east": 0, "depth": 2}], None
    )
    assert target == (20, 0, 2)
    early, late = (
        estimate.estimate(cp, 100.0, 110.0, target, 0.5),
        estimate.estimate(cp, 100.0, 200.0, target, 0.5),
    )
    assert early.north == pytest.approx(5.0) and late.north == pytest.approx(20.0)  # stops at the waypoint
    assert late.radius > early.radius > estimate.BASE_UNCERTAINTY
    holding = estimate.estimate({**cp, "state": "holding"}, 100.0, 200.0, target, 0.5)
    assert (holding.north, holding.target) == (0.0, None)
    commanded = {**cp, "state": "commanded"}
    move = {
        "command": "move",
        "distance": 10.0,
        "angle": 90.0,
        "depth": 1.0,
        "absolute_angle": True,
        "from": {"north": 0.0, "east": 0.0, "depth": 2.0, "heading": 0.0},
    }
    assert estimate.target_of(commanded, None, move) == pytest.approx((0.0, 10.0, 3.0))


def test_a_fleet_vehicles_targets_are_in_the_fleets_frame_around_its_own_home() -> None:
    """A plan's waypoints and a return home are relative to the vehicle's home; check-points and the
    screens are in the fleet's one frame."""
    home = (0.0, 30.0)
    cp = {"north": 5.0, "east": 30.0, "depth": 2.0, "heading": 0.0, "state": "preprogrammed", "waypoint": 1}
    square = [{"north": 0, "east": 0, "depth": 2}, {"north": 20, "east": 0, "depth": 2}]
    assert estimate.target_of(cp, square, None, home) == (20.0, 30.0, 2)
    assert estimate.target_of({**cp, "state": "returning"}, square, None, home) == (0.0, 30.0, 2.0)


def test_link_shares_add_up() -> None:
    shares = airtime.link_shares(commands_sent=2, polls=10, checkpoints=3, priority=5, samples=3000)
    assert sum(shares["shares"].values()) == pytest.approx(1.0, abs=1e-3)
    assert shares["bits"]["saved_share"] == pytest.approx(1 - 5 * 256 / 48000, abs=1e-4)
