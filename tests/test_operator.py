"""What the operator's screens share: one command form from the packet table and the vehicle's limits,
the form's rules (blank or out-of-range fields refused before sending), bearings up to 360 accepted by
the API, the last check-point and the shore's prediction with its uncertainty (after a restart too),
and the link's airtime shares."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlmodel import Session

from server import operator
from server.app import create_app
from server.models import Frame, Mission, Packet, Telemetry
from server.schemas import CommandIn
from server.settings import Settings
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
    target = operator.target_of(
        cp, [{"north": 0, "east": 0, "depth": 2}, {"north": 20, "east": 0, "depth": 2}], None
    )
    assert target == (20, 0, 2)
    early, late = (
        operator.estimate(cp, 100.0, 110.0, target, 0.5),
        operator.estimate(cp, 100.0, 200.0, target, 0.5),
    )
    assert early.north == pytest.approx(5.0) and late.north == pytest.approx(20.0)  # stops at the waypoint
    assert late.radius > early.radius > operator.BASE_UNCERTAINTY
    holding = operator.estimate({**cp, "state": "holding"}, 100.0, 200.0, target, 0.5)
    assert (holding.north, holding.target) == (0.0, None)
    commanded = {**cp, "state": "commanded"}
    move = {"command": "move", "distance": 10.0, "angle": 90.0, "depth": 1.0, "absolute_angle": True,
            "from": {"north": 0.0, "east": 0.0, "depth": 2.0, "heading": 0.0}}  # fmt: skip
    assert operator.target_of(commanded, None, move) == pytest.approx((0.0, 10.0, 3.0))


def test_link_shares_add_up() -> None:
    shares = operator.link_shares(commands_sent=2, polls=10, checkpoints=3, priority=5, samples=3000)
    assert sum(shares["shares"].values()) == pytest.approx(1.0, abs=1e-3)
    assert shares["bits"]["saved_share"] == pytest.approx(1 - 5 * 256 / 48000, abs=1e-4)


def settings(tmp_path: Path) -> Settings:
    return Settings(database_url=f"sqlite:///{tmp_path}/tacit.db", modem_url="", map_enabled=False,
                    modem_log=str(tmp_path / "modem.log"), write_tokens=["operator-token"],
                    read_tokens=["observer-token"])  # fmt: skip


def test_api_bearing_form_estimate_shares_and_state_after_restart(tmp_path: Path) -> None:
    with TestClient(create_app(settings(tmp_path))) as client:
        vehicle = client.post(
            "/api/v1/vehicles", json={"name": "rov1", "address": 2, "max_depth": 20}, headers=OP
        ).json()
        url = f"/api/v1/vehicles/{vehicle['id']}"
        sent = client.post(f"{url}/commands", json={"command": "move", "distance": 5, "angle": 270,
                                                   "absolute_angle": True}, headers=OP)  # fmt: skip
        assert sent.status_code == 202, sent.text
        assert (sent.json()["angle"], sent.json()["absolute_angle"]) == (-90.0, True)
        assert (
            client.post(f"{url}/commands", json={"command": "move", "angle": 361}, headers=OP).status_code
            == 422
        )
        form = client.get(f"{url}/form", headers=OBS).json()
        assert operator.field_specs(form, "goto_depth")[0]["max"] == 20.0
        config = client.get("/api/v1/config").json()
        assert config["states"]["awaiting_command"]["label"].startswith("following waypoints")
        assert config["streams"]["env"]["units"] == ["°C", "m", "mg/L"]
        assert client.get(f"{url}/estimate", headers=OBS).json()["reported"] is None
        db = client.app.state.shore.db
        now = time.time()
        with Session(db) as s:
            s.add(Mission(vehicle_id=vehicle["id"], name="line", number=1, status="started",
                          plan={"waypoints": [{"north": 0, "east": 0, "depth": 2}, {"north": 30, "east": 0, "depth": 2}]}))  # fmt: skip
            frame = Frame(direction="in", src=2, dest=1, data=b"x")
            s.add(frame)
            s.add(Frame(direction="out", src=1, dest=2, data=b"y"))
            s.flush()
            for i, (north, at) in enumerate(((0.0, now - 30), (5.0, now - 20))):
                s.add(Packet(frame_id=frame.id, vehicle_id=vehicle["id"], type="checkpoint", seq=i, at=at, auth="verified",
                             body={"north": north, "east": 0.0, "depth": 2.0, "heading": 0.0, "state": "awaiting_command",
                                   "mission_id": 1, "waypoint": 1, "time": int(at)}))  # fmt: skip
            s.add(
                Packet(frame_id=frame.id, vehicle_id=vehicle["id"], type="priority", seq=3, at=now, body={})
            )
            s.add(Telemetry(vehicle_id=vehicle["id"], stream="env", tick=1, time=1.0, values=[1, 2, 3]))
            s.commit()
        known = client.get(f"{url}/estimate", headers=OBS).json()
        assert known["reported"]["north"] == 5.0 and 19 < known["age_s"] < 40
        assert known["state_label"] == "following waypoints (unusual data)"
        assert known["speed_mps"] == pytest.approx(0.5, abs=0.01)
        assert 12 < known["predicted"]["north"] < 20 and known["predicted"]["radius_m"] > 1.9
        shares = client.get("/api/v1/link/shares", headers=OBS).json()
        assert shares["counts"] == {"commands": 1, "polls": 0, "checkpoints": 2, "priority": 1, "samples": 3}
    with TestClient(create_app(settings(tmp_path))) as client:  # a restarted shore knows the last check-point
        link = client.get("/api/v1/link", headers=OBS).json()
        assert link["vehicles"]["rov1"]["checkpoint"]["north"] == 5.0
        assert link["vehicles"]["rov1"]["last_heard"] == pytest.approx(now - 20)
