"""Two simulated vehicles on one channel driven toward one point: the center refuses the command whose
path would bring the second into the first (naming it and how close), accepts one that stops a safe
distance short, and warns once the two vehicles' predicted positions, with their uncertainty, come within
the separation."""

from __future__ import annotations

import math
from pathlib import Path

from fastapi.testclient import TestClient

from launch.stack import Stack, StackConfig, wait_for
from server.app import create_app
from server.core.config import Settings
from server.core.events import Event, SeparationWarning

OP = {"Authorization": "Bearer operator"}
KEYS = ["d4" * 32, "e5" * 32]
POINT = (15.0, 15.0)  # both vehicles are sent here: rov1 from (0, 0), rov2 from (0, 30)


def move_to(start: tuple[float, float], end: tuple[float, float], depth: float = 1.0) -> dict:
    """A move on a true bearing from ``start`` to ``end`` (the fleet's frame), going ``depth`` m down."""
    bearing = math.degrees(math.atan2(end[1] - start[1], end[0] - start[0])) % 360
    distance = round(math.dist(start, end), 1)
    return {
        "command": "move",
        "distance": distance,
        "angle": round(bearing, 2),
        "absolute_angle": True,
        "depth": depth,
    }


def test_two_vehicles_toward_one_point_refused_then_warned(tmp_path: Path) -> None:
    stack = Stack(
        StackConfig(
            tmp_path,
            range_m=150.0,
            time_scale=8.0,
            noise_db=95.0,
            seed=5,
            vehicles=2,
            keys=KEYS,
            write_tokens=["operator"],
        )
    )
    stack.start_sim()
    settings = Settings(
        **stack.server_settings(map_enabled=False, poll_interval=2.0, ping_interval=3600),
        separation=5.0,
        separation_check_interval=2.0,
    )
    client = TestClient(create_app(settings))
    client.__enter__()
    seen: list[Event] = []
    client.app.state.shore.bus.on_event(seen.append)  # type: ignore[attr-defined]

    def get(path: str) -> dict:
        return client.get(f"/api/v1{path}", headers=OP).json()

    try:
        ids = [
            client.post("/api/v1/vehicles", json=m.registration(), headers=OP).json()["id"]
            for m in stack.members
        ]
        for member in stack.members:
            stack.write_agent_config(member.index, checkpoint_interval=10)
            stack.start_agent(member.index)
        wait_for(
            lambda: all(v["checkpoint"] for v in get("/link")["vehicles"].values()),
            timeout=60,
            what="both heard",
        )

        first = client.post(
            f"/api/v1/vehicles/{ids[0]}/commands", json=move_to((0.0, 0.0), POINT), headers=OP
        )
        assert first.status_code == 202, first.text
        wait_for(
            lambda: get(f"/commands/{first.json()['id']}")["status"] == "executed",
            timeout=90,
            what="rov1 there",
        )

        same = client.post(
            f"/api/v1/vehicles/{ids[1]}/commands", json=move_to((0.0, 30.0), POINT), headers=OP
        )
        assert same.status_code == 422, same.text
        detail = same.json()["detail"]
        assert detail.startswith("rov2's path from") and " m from rov1, which " in detail, detail
        assert detail.endswith("closer than the 5 m separation")
        assert get("/safety")["warnings"] == []

        short = (POINT[0], POINT[1] + 6.0)  # stops 6 m east of rov1: clear of it, within 5 m + both doubts
        second = client.post(
            f"/api/v1/vehicles/{ids[1]}/commands", json=move_to((0.0, 30.0), short), headers=OP
        )
        assert second.status_code == 202, second.text
        warned = wait_for(
            lambda: [e for e in seen if isinstance(e, SeparationWarning) and e.active],
            timeout=90,
            what="a warning",
        )
        assert warned[0].vehicles == ["rov1", "rov2"] and warned[0].distance_m < warned[0].limit_m
        assert [w["vehicles"] for w in get("/safety")["warnings"]] == [["rov1", "rov2"]]
    finally:
        client.__exit__(None, None, None)
        stack.close()
