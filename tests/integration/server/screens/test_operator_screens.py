"""The operator's screens through the API: bearings up to 360 accepted, the form from the vehicle's limits, the last
check-point and the prediction with its uncertainty (after a restart too), and the link's airtime shares."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlmodel import Session

from server.app import create_app
from server.core.config import Settings
from server.missions.models import Mission
from server.screens import form as operator
from server.telemetry.models import Frame, Packet, Telemetry
from tests.support.api import OP, offline_settings

OBS = {"Authorization": "Bearer observer-token"}


def settings(tmp_path: Path) -> Settings:
    return offline_settings(tmp_path, modem_log=str(tmp_path / "modem.log"))


def test_api_bearing_form_estimate_shares_and_state_after_restart(tmp_path: Path) -> None:
    with TestClient(create_app(settings(tmp_path))) as client:
        vehicle = client.post(
            "/api/v1/vehicles", json={"name": "rov1", "address": 2, "max_depth": 20}, headers=OP
        ).json()
        url = f"/api/v1/vehicles/{vehicle['id']}"
        sent = client.post(
            f"{url}/commands",
            json={"command": "move", "distance": 5, "angle": 270, "absolute_angle": True},
            headers=OP,
        )
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
            s.add(
                Mission(
                    vehicle_id=vehicle["id"],
                    name="line",
                    number=1,
                    status="started",
                    plan={
                        "waypoints": [
                            {"north": 0, "east": 0, "depth": 2},
                            {"north": 30, "east": 0, "depth": 2},
                        ]
                    },
                )
            )
            frame = Frame(direction="in", src=2, dest=1, data=b"x")
            s.add(frame)
            s.add(Frame(direction="out", src=1, dest=2, data=b"y"))
            s.flush()
            for i, (north, at) in enumerate(((0.0, now - 30), (5.0, now - 20))):
                s.add(
                    Packet(
                        frame_id=frame.id,
                        vehicle_id=vehicle["id"],
                        type="checkpoint",
                        seq=i,
                        at=at,
                        auth="verified",
                        body={
                            "north": north,
                            "east": 0.0,
                            "depth": 2.0,
                            "heading": 0.0,
                            "state": "awaiting_command",
                            "mission_id": 1,
                            "waypoint": 1,
                            "time": int(at),
                        },
                    )
                )
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
