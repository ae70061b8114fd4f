"""Each vehicle speaks its own protocol version: registered with it (the newest by default), decoded in
it, and a mixed fleet works side by side; samples in another version than the registered one are
refused with the reason, logged once and counted."""

from __future__ import annotations

import io
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from fastapi.testclient import TestClient

from server.app import create_app
from server.core.config import Settings
from server.link.state import IncomingFrame
from tacit import auth, nmea
from tacit.codec import PacketEncoder
from tacit.codec.format import MAX_WINDOW
from tacit.packets import (
    NEWEST,
    SYNC_RESTART_CHAINS,
    CheckpointPacket,
    Command,
    ControlPacket,
    MissionState,
    Stream,
    with_seq,
)
from tacit.streams import default_streams
from vehicle_agent.agent import Agent, AgentConfig
from vehicle_agent.state import Uncovered

KEYS = {2: bytes(range(32)), 3: bytes(range(1, 33))}
OP = {"Authorization": "Bearer op"}


def frames(address: int, protocol: int, start: float) -> list[bytes]:
    """A vehicle's first priority packets in ``protocol``, tagged with its key."""
    streams = list(default_streams().values())
    encoder, out = PacketEncoder(streams, max_latency=1.0, protocol=protocol), []
    for k in range(40):
        t = start + 0.25 * k
        encoder.push(0, t, list(np.arange(9.0) + k % 3))  # the IMU, then the water
        encoder.push(1, t, [10.0 + 0.01 * k, 5.0, 8.0])
        while encoder.ready(t):
            packet = encoder.take()
            out.append(auth.tag_priority(with_seq(packet.packet, len(out)), KEYS[address], address))
            encoder.resolve(True)
    return out


def test_a_mixed_fleet_decodes_each_vehicle_in_its_own_version(tmp_path: Path, caplog) -> None:
    settings = Settings(
        database_url=f"sqlite:///{tmp_path}/tacit.db", modem_url="", map_enabled=False, write_tokens=["op"]
    )
    with TestClient(create_app(settings)) as client:
        new = {"name": "rov1", "address": 2, "key": KEYS[2].hex()}
        old = {"name": "rov2", "address": 3, "key": KEYS[3].hex(), "protocol": 3}
        assert client.post("/api/v1/vehicles", json=new, headers=OP).json()["protocol"] == NEWEST
        assert client.post("/api/v1/vehicles", json=old, headers=OP).json()["protocol"] == 3
        wrong = {"name": "rov3", "address": 4, "protocol": 5}
        refused = client.post("/api/v1/vehicles", json=wrong, headers=OP)
        assert refused.status_code == 422 and "protocol" in refused.text
        ingest = client.app.state.shore.ingest  # type: ignore[attr-defined]
        ingest.load_vehicles()
        now = time.time()
        for address, protocol in ((2, NEWEST), (3, 3)):
            for frame in frames(address, protocol, now):
                ingest.handle(IncomingFrame(address, 1, frame, at=now + 20))
        for frame in frames(2, 3, now + 30)[:3]:  # rov1's agent configured for version 3 by mistake
            ingest.handle(IncomingFrame(2, 1, frame, at=now + 40))
        says = CheckpointPacket(seq=200, time=int(now), state=MissionState.HOLDING, quiet=20, version=NEWEST)
        ingest.handle(IncomingFrame(2, 1, auth.sign_checkpoint(says, KEYS[2], 1, 2, []), at=now + 41))
        link = client.get("/api/v1/link", headers=OP).json()
        parquet = client.get(
            "/api/v1/telemetry.parquet", params={"vehicle_id": 1, "stream": "imu"}, headers=OP
        )
        older = client.get("/api/v1/telemetry.parquet", params={"vehicle_id": 2, "stream": "imu"}, headers=OP)
        csv = client.get("/api/v1/telemetry.csv", params={"vehicle_id": 1, "stream": "imu"}, headers=OP)
        samples = {
            vid: client.get("/api/v1/telemetry", params={"vehicle_id": vid}, headers=OP).json()["items"]
            for vid in (1, 2)
        }
    assert link["vehicles"]["rov2"]["old_protocol"] == 0
    assert link["vehicles"]["rov1"]["checkpoint"]["predictable_until"] == int(now) - 20  # the silence said
    said = pq.read_metadata(io.BytesIO(parquet.content)).metadata  # and the exports say it
    assert float(said[b"predictable_until"]) == int(now) - 20
    assert float(csv.headers["Tacit-Predictable-Until"]) == int(now) - 20
    assert b"predictable_until" not in pq.read_metadata(io.BytesIO(older.content)).metadata  # none said
    assert link["vehicles"]["rov1"]["old_protocol"] == 3
    assert caplog.text.count("rov1 is registered as speaking version 4") == 1
    for vid, rows in samples.items():  # each decoded in its own version: the 40 ticks of both streams
        assert all(r["certain"] for r in rows), vid
        water = sorted((r["time"], r["values"][0]) for r in rows if r["stream"] == "env")
        assert len(water) >= 30 and abs(water[0][1] - 10.0) <= 0.05, vid
        assert all(abs(b - a - 0.01) <= 0.1 for (_, a), (_, b) in zip(water, water[1:], strict=False)), vid


def test_a_version_4_agent_says_the_silence_in_its_checkpoints_and_sends_no_packet_for_it(
    tmp_path: Path,
) -> None:
    config = AgentConfig(
        key=KEYS[2].hex(), state_file=str(tmp_path / "agent-state.json"), modem_url="/dev/null"
    )
    agent = Agent(config, config.plans(tmp_path))
    assert agent.checkpoint().version == NEWEST and agent.checkpoint().quiet == 0  # nothing waits
    agent.compressor.silence_said(config.checkpoint_interval)  # 60 s, as often as max_silence
    assert agent.compressor.encoder.policy.max_silence is None
    agent.compressor.silence_said(config.max_silence + 1)  # check-points set further apart: packets again
    assert agent.compressor.encoder.policy.max_silence == config.max_silence
    old = Agent(replace(config, protocol=3, state_file=str(tmp_path / "old.json")), config.plans(tmp_path))
    old.compressor.silence_said(config.checkpoint_interval)  # version 3 cannot say it
    assert old.compressor.encoder.policy.max_silence == config.max_silence
    assert old.checkpoint().version == 3


def test_the_agent_numbers_no_packet_a_checkpoint_could_not_cover(tmp_path: Path) -> None:
    """A check-point covers 16 seqs back: the agent makes no priority packet that would put a delivered
    packet not yet covered, or one in flight, out of its reach (one seq kept for the check-point); one a
    check-point on its way covers no longer holds the window back."""
    config = AgentConfig(
        key=KEYS[2].hex(), state_file=str(tmp_path / "agent-state.json"), modem_url="/dev/null"
    )
    agent = Agent(config, config.plans(tmp_path))
    assert agent._room() == MAX_WINDOW  # nothing outstanding: a whole window
    agent.state.packet_seq = 10
    agent.state.uncovered = [Uncovered(0, bytes(32))]  # delivered at seq 0, not yet covered
    assert agent._room() == MAX_WINDOW - 10
    agent.state.packet_seq = 20
    assert agent._room() == 0
    agent.state.packet_seq = 12
    agent._send_checkpoint()  # it covers seq 0: the window opens while it is on its way
    assert agent._room() == MAX_WINDOW
    agent.link.queue[-1].on_result(False)  # lost for good: seq 0 needs the next check-point again
    assert agent._room() == MAX_WINDOW - 13


def test_a_restart_request_withdraws_the_packets_in_flight_and_codes_their_samples_again(
    tmp_path: Path,
) -> None:
    config = AgentConfig(
        key=KEYS[2].hex(), state_file=str(tmp_path / "agent-state.json"), modem_url="/dev/null"
    )
    agent = Agent(config, config.plans(tmp_path))
    agent.link._answer_poll(nmea.DataRequest("000000", 2, 1, True, 256, 1))  # a rate-5 poll's frame
    rng, now = np.random.default_rng(2), agent.now()
    for k in range(40):  # an IMU the shore cannot predict: full packets
        agent.compressor.add(Stream.KINEMATIC, now - 20 + 0.25 * k, list(rng.normal(0, 500, 9)))
    agent._send_packets()
    queued = [item.data for item in agent.link.queue]
    assert len(queued) == 8 and len(agent.compressor.encoder.pending) < 40  # a window of 8 in flight
    sync = ControlPacket(Command.SYNC, seq=1, time=int(now), param_id=SYNC_RESTART_CHAINS)
    agent._on_sync(sync)
    assert not any(data in queued for data in (item.data for item in agent.link.queue))
    assert {x.serial for x in agent.compressor.encoder.pending} == set(
        range(40)
    )  # coded from the start again
