"""Three vehicles on one simulated channel: each reports from its own address and near its own home, a
command reaches only the vehicle it is for, and a vehicle holding another's key obeys none of its
commands."""

from __future__ import annotations

import json
import math
from pathlib import Path

from fastapi.testclient import TestClient

from launch.stack import Stack, StackConfig, wait_for
from server.app import create_app
from server.core.config import Settings

OP = {"Authorization": "Bearer operator"}
KEYS = ["a1" * 32, "b2" * 32, "c3" * 32]
DEPTH = {"command": "goto_depth", "depth": 1.0}


class Fleet:
    """The stack with three vehicles and the server in this process."""

    def __init__(self, tmp: Path) -> None:
        self.stack = Stack(
            StackConfig(
                tmp,
                range_m=150.0,
                time_scale=8.0,
                noise_db=95.0,
                seed=3,
                vehicles=3,
                keys=KEYS,
                write_tokens=["operator"],
            )
        )
        self.stack.start_sim()
        settings = Settings(
            **self.stack.server_settings(map_enabled=False, poll_interval=2.0, ping_interval=3600)
        )
        self.client = TestClient(create_app(settings))
        self.client.__enter__()
        self.ids = [self.post("/vehicles", m.registration())["id"] for m in self.stack.members]
        for member in self.stack.members:
            self.stack.write_agent_config(member.index, checkpoint_interval=20)
            self.stack.start_agent(member.index)

    def post(self, path: str, body: dict) -> dict:
        response = self.client.post(f"/api/v1{path}", json=body, headers=OP)
        assert response.status_code in (201, 202), response.text
        return response.json()

    def get(self, path: str, **params: object) -> dict:
        return self.client.get(f"/api/v1{path}", params=params, headers=OP).json()

    def status(self, command_id: int) -> str:
        return self.get(f"/commands/{command_id}")["status"]

    def close(self) -> None:
        self.client.__exit__(None, None, None)
        self.stack.close()


def test_three_vehicles_share_one_channel(tmp_path: Path) -> None:
    fleet = Fleet(tmp_path)
    try:
        link = lambda: fleet.get("/link")["vehicles"]  # noqa: E731
        wait_for(
            lambda: all(v["checkpoint"] for v in link().values()), timeout=30, what="a check-point from each"
        )
        for member, vehicle_id in zip(fleet.stack.members, fleet.ids, strict=True):
            assert link()[member.name]["address"] == member.address
            points = wait_for(  # the link's state shows a check-point while its batch is still committing
                lambda vid=vehicle_id: fleet.get("/packets", type="checkpoint", vehicle_id=vid)["items"],
                timeout=30,
                what="the check-point stored",
            )
            assert points and all(
                math.dist((p["body"]["north"], p["body"]["east"]), member.home) < 3.0 for p in points
            ), (member.home, [p["body"] for p in points])
        schedule = fleet.get("/link/schedule")["vehicles"]
        assert sorted(v["address"] for v in schedule) == [2, 3, 4] and all(v["last_polled"] for v in schedule)

        command = fleet.post(f"/vehicles/{fleet.ids[1]}/commands", DEPTH)["id"]
        wait_for(
            lambda: fleet.status(command) == "executed", timeout=30, what="vehicle 2 executed its command"
        )
        assert link()["rov2"]["checkpoint"]["last_command"] == 1
        assert (
            link()["rov1"]["checkpoint"]["last_command"] == link()["rov3"]["checkpoint"]["last_command"] == 0
        )

        fleet.stack.kill(
            fleet.stack.agents[2]
        )  # rov3 now holds rov2's key; the shore signs for rov3 with rov3's
        fleet.stack.write_agent_config(2, checkpoint_interval=20, key=KEYS[1])
        fleet.stack.start_agent(2)
        refused = fleet.post(f"/vehicles/{fleet.ids[2]}/commands", DEPTH)["id"]
        wait_for(lambda: fleet.status(refused) != "queued", timeout=30, what="the command on rov3's modem")
        rejected = "control frame rejected: control packet MAC does not match"
        wait_for(
            lambda: rejected in fleet.stack.log("agent-rov3.log"), timeout=60, what="rov3 rejecting the MAC"
        )
        log = fleet.stack.log("agent-rov3.log")
        assert "control seq 1 accepted" not in log
        assert json.loads((tmp_path / "agent-state-rov3.json").read_text())["mission"]["last_command"] == 0
        assert fleet.status(refused) not in ("executing", "executed")
    finally:
        fleet.close()
