"""A fleet on one acoustic channel: registration refuses shared addresses and keys, the polled MAC
shares the channel fairly between vehicles, and an operator can change a vehicle's share at run time."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from launch.stack import SPACING_M, Stack, StackConfig, StackError
from server.app import create_app
from server.commands.schemas import CommandIn
from server.link.schedule import SlotReason
from server.shore import Shore
from simulators.run import SimConfig
from tacit import modem as mm
from tacit.packets import Command
from tests.support.api import OP, offline_settings
from tests.support.shore import scripted_shore

KEY = "ab" * 32


@pytest.fixture
def client(tmp_path: Path):
    settings = offline_settings(tmp_path)
    with TestClient(create_app(settings)) as c:
        assert (
            c.post(
                "/api/v1/vehicles", json={"name": "rov1", "address": 2, "key": KEY}, headers=OP
            ).status_code
            == 201
        )
        yield c


def test_a_second_vehicle_with_the_same_address_or_key_is_refused(client: TestClient) -> None:
    same_address = client.post("/api/v1/vehicles", json={"name": "rov2", "address": 2}, headers=OP)
    assert same_address.status_code == 409 and same_address.json()["field"] == "address"
    same_key = client.post(
        "/api/v1/vehicles", json={"name": "rov2", "address": 3, "key": KEY.upper()}, headers=OP
    )
    assert same_key.status_code == 409
    assert (
        same_key.json()["detail"] == "key already used by vehicle rov1" and same_key.json()["field"] == "key"
    )
    other = client.post("/api/v1/vehicles", json={"name": "rov2", "address": 3}, headers=OP)
    assert other.status_code == 201
    taken = client.post(f"/api/v1/vehicles/{other.json()['id']}/key", json={"key": KEY}, headers=OP)
    assert taken.status_code == 409 and taken.json()["field"] == "key"  # rotating onto another's key too
    assert client.post("/api/v1/vehicles/9/commands", json={"command": "hold"}, headers=OP).status_code == 404


def test_duplicate_addresses_or_keys_are_refused_before_anything_starts(tmp_path: Path) -> None:
    with pytest.raises(StackError, match="^two vehicles with the same key: ab"):
        Stack(StackConfig(tmp_path, vehicles=2, keys=[KEY, KEY.upper()]))
    with pytest.raises(StackError, match="^two vehicles with the same modem address: 3$"):
        Stack(StackConfig(tmp_path, vehicles=2, addresses=[3, 3]))
    with pytest.raises(StackError, match="^modem address 1 is the shore's"):
        Stack(StackConfig(tmp_path, vehicles=1, addresses=[1]))
    modems = [{"address": 2, "name": "a"}, {"address": 2, "name": "b"}]
    with pytest.raises(ValueError, match="modem addresses must be unique"):
        SimConfig.from_dict({"modems": modems})
    fleet = Stack(StackConfig(tmp_path, vehicles=3, keys=["01" * 32, "02" * 32, "03" * 32]))
    assert [(m.name, m.address, m.home) for m in fleet.members] == [
        ("rov1", 2, (0.0, 0.0)),
        ("rov2", 3, (0.0, SPACING_M)),
        ("rov3", 4, (0.0, 2 * SPACING_M)),
    ]
    assert fleet.members[1].file("agent-state.json") == "agent-state-rov2.json"


class PollingModem:
    """A shore modem that acknowledges every transmission at once and records whom it addressed."""

    state = mm.LinkState.READY

    def __init__(self) -> None:
        self.addressed: list[tuple[str, int]] = []

    async def send(self, dest: int, frames: list[bytes], **_: object) -> mm.TransmitResult:
        sync = frames[0][1] == Command.SYNC  # a SYNC opens a slot without ending it: not a slot of its own
        self.addressed.append(("sync" if sync else "send", dest))
        return mm.TransmitResult(dest, len(frames), True, frozenset(range(len(frames))))

    async def poll(self, dest: int, **_: object) -> None:
        self.addressed.append(("poll", dest))

    async def ping(self, dest: int, **_: object) -> None:
        return None


def _shore(tmp_path: Path, vehicles: int) -> Shore:
    keys = [f"{i + 1:02x}" * 32 for i in range(vehicles)]
    return scripted_shore(tmp_path, keys, max_queued_commands=500, command_share=3)


def _run_slots(shore: Shore, modem: PollingModem, n: int) -> None:
    link = shore.link
    link.driver = modem  # type: ignore[assignment]

    async def slots() -> None:
        for _ in range(n):
            plan = await link._plan()
            await link._slot(plan[0][0])

    asyncio.run(slots())


def test_a_full_command_queue_does_not_stop_the_others_being_polled(tmp_path: Path) -> None:
    shore, modem = _shore(tmp_path, 3), PollingModem()
    for _ in range(100):
        shore.commands.submit(1, CommandIn(command="hold"), "tester")
    _run_slots(shore, modem, 60)
    count = {(kind, dest): modem.addressed.count((kind, dest)) for kind, dest in set(modem.addressed)}
    assert [a for a in modem.addressed if a[0] != "sync"][0] == ("send", 2)  # commands first (after a SYNC)
    assert 18 <= count[("send", 2)] + count[("poll", 2)] <= 22  # its share, a third, give or take its lead
    assert count[("send", 2)] >= 14 and count[("poll", 2)] >= 4  # command_share in a row, then a poll
    assert count[("poll", 3)] >= 19 and count[("poll", 4)] >= 19  # the others are polled all along
    slots = [a for a in modem.addressed if a[0] != "sync"]
    first = [next(i for i, (_, dest) in enumerate(slots) if dest == d) for d in (3, 4)]
    assert max(first) < 5  # from the start (their first SYNC, then polls), not after the queue
    assert shore.commands.pending(1) > 0  # commands were still waiting all along


def test_a_larger_share_gets_proportionally_more_slots(tmp_path: Path) -> None:
    shore, modem = _shore(tmp_path, 3), PollingModem()
    shore.link.share_changed(2, 3.0)  # rov2
    _run_slots(shore, modem, 50)
    polls = [modem.addressed.count(("poll", d)) for d in (2, 3, 4)]
    assert polls[1] >= 2.5 * polls[0] and abs(polls[0] - polls[2]) <= 1, polls


def test_time_sensitive_data_is_polled_sooner(tmp_path: Path) -> None:
    shore, modem = _shore(tmp_path, 3), PollingModem()
    _run_slots(shore, modem, 3)  # once round
    rov3 = next(v for v in shore.ingest.states() if v.address == 4)
    rov3.urgent = True
    plan = asyncio.run(shore.link._plan())
    assert [(v.address, reason) for v, reason in plan][0] == (4, SlotReason.URGENT)


def test_share_changes_through_the_api_and_is_kept(tmp_path: Path) -> None:
    settings = offline_settings(tmp_path, read_tokens=["observer"])
    with TestClient(create_app(settings)) as client:
        created = client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP).json()
        assert created["share"] == 1.0
        changed = client.put("/api/v1/vehicles/1/share", json={"share": 2.5}, headers=OP)
        assert changed.status_code == 200 and changed.json()["share"] == 2.5
        assert client.app.state.shore.ingest.states()[0].share == 2.5  # the schedule weighs it now
        assert (
            client.put("/api/v1/vehicles/1/share", json={"share": 0}, headers=OP).json()["field"] == "share"
        )
        observer = {"Authorization": "Bearer observer"}
        assert client.put("/api/v1/vehicles/1/share", json={"share": 2}, headers=observer).status_code == 403
        assert client.put("/api/v1/vehicles/9/share", json={"share": 2}, headers=OP).status_code == 404
        assert (
            client.get("/api/v1/link/schedule", headers=observer).json()["vehicles"] == []
        )  # no modem: no plan
    with TestClient(create_app(settings)) as client:  # a restart keeps it
        assert client.get("/api/v1/vehicles/1", headers=OP).json()["share"] == 2.5
        assert client.app.state.shore.ingest.states()[0].share == 2.5


def test_an_agent_steers_relative_to_its_home_and_reports_in_the_fleets_frame() -> None:
    from tacit.navigation import Pose
    from vehicle_agent.navigator import NavConfig, PositionEstimate

    config = NavConfig(home=[5, 30])  # type: ignore[arg-type]  # as TOML gives it
    position = PositionEstimate(config)
    assert config.home == (5.0, 30.0) and (position.north, position.east) == (0.0, 0.0)  # starts at home
    assert position.from_fleet(7.0, 31.0) == (2.0, 1.0)  # a position fix, in its own frame
    assert position.in_fleet_frame(Pose(2.0, 1.0, 3.0, 90.0)) == Pose(7.0, 31.0, 3.0, 90.0)  # as reported
    with pytest.raises(ValueError):
        NavConfig(home=[1.0])  # type: ignore[arg-type]
