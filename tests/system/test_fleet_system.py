"""Three vehicles on one simulated channel, one stack for the whole module (the tests run in order, each
leaving the fleet running): each reports from its own address and near its own home, and a command
reaches only the vehicle it is for; a vehicle taken out of range is greyed while the others keep their
place in the schedule, and comes back; a vehicle whose agent is killed (SIGKILL) and restarted rejoins,
its check-points verified again and a command sent while it was down executed once; two vehicles whose
keys are swapped in their agents' configurations execute no command: their check-points are refused on
the shore, whose link events name the vehicle whose key signed them, and each refuses its commands."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterator
from functools import partial
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from pymavlink import mavutil

from launch.stack import Stack, StackConfig, wait_for
from server.app import create_app
from server.core.config import Settings
from server.core.events import Event, LinkNotice
from simulators.parameters import MODEM_LOSS

OP = {"Authorization": "Bearer operator"}
KEYS = ["a1" * 32, "b2" * 32, "c3" * 32]
DEPTH = {"command": "goto_depth", "depth": 1.0}
LONG = 180.0  # s: three vehicles share a rate-0 channel on 2 busy cores


class Fleet:
    """The stack with three vehicles, the server in this process, and every event its bus published."""

    def __init__(self, tmp: Path) -> None:
        self.dir = tmp
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
            **self.stack.server_settings(map_enabled=False, poll_interval=2.0, ping_interval=3600),
            confirm_timeout=30.0,  # a command the modem ACKed for a dead agent goes again after 30 s
        )
        self.client = TestClient(create_app(settings))
        self.client.__enter__()
        self.seen: list[Event] = []
        self.client.app.state.shore.bus.on_event(self.seen.append)  # type: ignore[attr-defined]
        self.ids = [self.post("/vehicles", m.registration())["id"] for m in self.stack.members]
        for member in self.stack.members:
            self.stack.write_agent_config(member.index, checkpoint_interval=20)
            self.stack.start_agent(member.index)

    def post(self, path: str, body: dict) -> dict:
        response = self.client.post(f"/api/v1{path}", json=body, headers=OP)
        assert response.status_code in (201, 202), response.text
        return response.json()

    def get(self, path: str, **params: object) -> Any:
        return self.client.get(f"/api/v1{path}", params=params, headers=OP).json()

    def status(self, command_id: int) -> str:
        return self.get(f"/commands/{command_id}")["status"]

    def link(self) -> dict:
        return self.get("/link")["vehicles"]

    def checkpoints(self, index: int) -> list[dict]:
        """The vehicle's stored check-points, newest first, with their trust (``auth``)."""
        return self.get("/packets", type="checkpoint", vehicle_id=self.ids[index], limit=1000)["items"]

    def reports(self, index: int) -> int:
        """How many packets (check-points and data) the shore has stored from the vehicle."""
        return int(self.get("/packets", vehicle_id=self.ids[index], limit=1)["total"])

    def overdue(self) -> dict[str, bool]:
        return {v["name"]: v["overdue"] for v in self.get("/fleet")["vehicles"]}

    def polls(self) -> dict[str, int]:
        return {v["name"]: v["polls"] for v in self.get("/link/schedule")["vehicles"]}

    def log(self, index: int, since: int = 0) -> str:
        """The vehicle's agent log (each run of the agent appends to it) from character ``since`` on."""
        return self.stack.log(self.stack.members[index].file("agent.log"))[since:]

    def executed(self, index: int, since: int = 0) -> list[int]:
        """The command seqs the vehicle's agent accepted, from character ``since`` of its log on."""
        return [int(seq) for seq in re.findall(r"control seq (\d+) accepted", self.log(index, since))]

    def last_command(self, index: int) -> int:
        state = self.dir / self.stack.members[index].file("agent-state.json")
        return int(json.loads(state.read_text())["mission"]["last_command"])

    def restart_agent(self, index: int, **values: Any) -> int:
        """SIGKILL the vehicle's agent and start it again (``values`` change its configuration); where
        its log stood when it was killed."""
        self.stack.kill(self.stack.agents[index])
        since = len(self.log(index))
        self.stack.write_agent_config(index, checkpoint_interval=20, **values)
        self.stack.start_agent(index)
        return since

    def close(self) -> None:
        self.client.__exit__(None, None, None)
        self.stack.close()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fleet]:
    running = Fleet(tmp_path_factory.mktemp("fleet"))
    try:
        wait_for(
            lambda: all(v["checkpoint"] for v in running.link().values()),
            timeout=LONG,
            what="a check-point from each",
        )
        yield running
    finally:
        running.close()


def set_modem_loss(stack: Stack, index: int, loss: float) -> None:
    """The simulator's ``SIM_MODEM_LOSS`` on the vehicle (over its MAVLink, beside its agent): 1 takes
    the modem riding it out of range of every other modem, 0 brings it back."""
    conn = mavutil.mavlink_connection(stack.mavlink_of(index), source_system=250)
    try:

        def echoed() -> bool:
            conn.mav.param_set_send(1, 1, MODEM_LOSS.encode(), loss, mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
            reply = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=2)
            return reply is not None and reply.param_id == MODEM_LOSS and reply.param_value == loss

        wait_for(echoed, timeout=60, every=0, what=f"{MODEM_LOSS} = {loss} on rov{index + 1}")
    finally:
        conn.close()


def test_three_vehicles_share_one_channel(fleet: Fleet) -> None:
    for member in fleet.stack.members:
        assert fleet.link()[member.name]["address"] == member.address
        points = wait_for(  # the link's state shows a check-point while its batch is still committing
            partial(fleet.checkpoints, member.index),
            timeout=LONG,
            what="the check-point stored",
        )
        assert points and all(
            math.dist((p["body"]["north"], p["body"]["east"]), member.home) < 3.0 for p in points
        ), (member.home, [p["body"] for p in points])
    schedule = fleet.get("/link/schedule")["vehicles"]
    assert sorted(v["address"] for v in schedule) == [2, 3, 4] and all(v["last_polled"] for v in schedule)

    command = fleet.post(f"/vehicles/{fleet.ids[1]}/commands", DEPTH)["id"]
    wait_for(lambda: fleet.status(command) == "executed", timeout=LONG, what="vehicle 2 executed its command")
    assert fleet.link()["rov2"]["checkpoint"]["last_command"] == 1
    assert fleet.executed(0) == fleet.executed(2) == [] and fleet.executed(1) == [1]
    assert fleet.last_command(0) == fleet.last_command(2) == 0


def test_a_vehicle_out_of_range_is_greyed_and_the_others_keep_their_schedule(fleet: Fleet) -> None:
    wait_for(lambda: len(fleet.checkpoints(2)) >= 2, timeout=LONG, what="rov3's report gap known")
    set_modem_loss(fleet.stack, 2, 1.0)
    try:
        wait_for(  # greyed while the others are not
            lambda: fleet.overdue() == {"rov1": False, "rov2": False, "rov3": True},
            timeout=LONG,
            what="rov3 greyed, rov1 and rov2 not",
        )
        polls, heard = fleet.polls(), [fleet.reports(i) for i in (0, 1)]

        def carried_on() -> bool:
            now, overdue = fleet.polls(), fleet.overdue()
            return (
                all(now[name] >= polls[name] + 2 for name in ("rov1", "rov2"))
                and all(fleet.reports(i) > heard[i] for i in (0, 1))
                and overdue == {"rov1": False, "rov2": False, "rov3": True}
            )

        wait_for(carried_on, timeout=LONG, what="rov1 and rov2 polled and reporting while rov3 is silent")
    finally:
        set_modem_loss(fleet.stack, 2, 0.0)
    wait_for(lambda: not any(fleet.overdue().values()), timeout=LONG, what="rov3 back in range")


def test_a_killed_agent_restarted_rejoins_and_executes_once(fleet: Fleet) -> None:
    first = fleet.post(f"/vehicles/{fleet.ids[0]}/commands", DEPTH)["id"]
    wait_for(lambda: fleet.status(first) == "executed", timeout=LONG, what="rov1 executed its command")
    heard = max(p["id"] for p in fleet.checkpoints(0))

    fleet.stack.kill(fleet.stack.agents[0])  # no chance to save anything
    down = fleet.post(f"/vehicles/{fleet.ids[0]}/commands", {**DEPTH, "depth": 2.0})["id"]
    wait_for(
        lambda: fleet.status(down) == "acknowledged",
        timeout=LONG,
        what="the modem's ACK with nobody listening",
    )
    fleet.stack.write_agent_config(0, checkpoint_interval=20)
    fleet.stack.start_agent(0)
    wait_for(
        lambda: any(p["id"] > heard and p["auth"] == "verified" for p in fleet.checkpoints(0)),
        timeout=LONG,
        what="a verified check-point from the restarted agent",
    )
    wait_for(
        lambda: fleet.status(down) == "executed", timeout=LONG, what="the command sent while it was down"
    )
    assert fleet.executed(0) == [1, 2]  # each once, across both runs of the agent
    assert fleet.last_command(0) == 2
    assert fleet.executed(2) == [] and fleet.executed(1) == [1]  # the others executed none of them


def test_keys_swapped_between_two_agents_execute_nothing(fleet: Fleet) -> None:
    """rov2's agent gets rov3's key and rov3's agent rov2's; the shore signs for each with its own."""
    before = len(fleet.seen)
    since = [fleet.restart_agent(1, key=KEYS[2]), fleet.restart_agent(2, key=KEYS[1])]
    commands = [fleet.post(f"/vehicles/{fleet.ids[i]}/commands", DEPTH)["id"] for i in (1, 2)]

    def said_on_the_link() -> set[str]:
        return {
            f"{e.vehicle}: {e.detail['error'].partition(': ')[2]}"
            for e in fleet.seen[before:]
            if isinstance(e, LinkNotice) and e.event == "forged_checkpoint"
        }

    wait_for(
        lambda: (
            {
                "rov2: signed with rov3's key, not rov2's: is rov2's agent configured with rov3's key?",
                "rov3: signed with rov2's key, not rov3's: is rov3's agent configured with rov2's key?",
            }
            <= said_on_the_link()
        ),
        timeout=LONG,
        what="the shore refusing both vehicles' check-points, saying whose key signed them",
    )
    rejected = "control frame rejected: control packet MAC does not match"
    for index, mark in zip((1, 2), since, strict=True):
        wait_for(
            lambda: rejected in fleet.log(index, mark),  # noqa: B023 (waited for here, in this pass)
            timeout=LONG,
            what=f"rov{index + 1} refusing its command, signed with the key the shore has for it",
        )
        assert fleet.executed(index, since=mark) == []
    assert [fleet.last_command(i) for i in (1, 2)] == [1, 0]  # as they were before the swap
    assert fleet.executed(0) == [1, 2]  # nor did the third vehicle execute either command
    assert all(fleet.status(c) not in ("executing", "executed") for c in commands)
    newest = [fleet.checkpoints(i)[0] for i in (1, 2)]
    assert all(p["auth"] in ("forged", "unverifiable") for p in newest), newest
