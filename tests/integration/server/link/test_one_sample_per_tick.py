"""Issue 22 item 1, one sample per stream per time: a real dive through the agent as it runs (its MAVLink
listener, its compressor) and the shore's ingest, its messages reaching the agent late and in bursts (a
busy Pi, a TCP buffer): every sample the vehicle measured is stored once, within eps, dated within half
a tick of when the autopilot measured it, and a tick holds one sample (but at ``small.tlog``'s start: its
stream-rate change sent a burst of messages milliseconds apart, several to a tick)."""

from __future__ import annotations

import random
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from sqlmodel import Session, col, select

from analysis import tlog
from server.core.config import Settings
from server.core.events import Bus
from server.link.ingest import Ingest
from server.link.state import IncomingFrame
from server.telemetry.models import Telemetry
from server.vehicles.models import Vehicle
from tacit import auth
from tacit.packets import Stream
from tacit.sampletime import boot_seconds
from tacit.streams import default_streams
from tests.support.shore import store_with
from vehicle_agent.agent import Agent, AgentConfig

DIVE = Path(__file__).resolve().parents[3] / "data" / "ardusub" / "small.tlog"
KEY = bytes(range(32))
ADDRESS = 2
SAMPLES = {"RAW_IMU": "imu", "SCALED_PRESSURE2": "env"}


def late_and_bunched(messages: list, seed: int = 5) -> None:
    """Each message's arrival (``_timestamp``) made later: 0-40 ms of jitter, and every 10-30 s the reader
    stalls for 0.6-1.5 s and gets what waited all at once."""
    rng = random.Random(seed)
    stall, length = messages[0]._timestamp + 10.0, rng.uniform(0.6, 1.5)
    last = 0.0
    for msg in messages:
        arrival = msg._timestamp + rng.uniform(0.0, 0.04)
        if arrival >= stall + length:
            stall, length = stall + length + rng.uniform(10.0, 30.0), rng.uniform(0.6, 1.5)
        if stall <= arrival < stall + length:
            arrival = stall + length + rng.uniform(0.0, 0.005)
        msg._timestamp = last = max(last, arrival)


def measured(messages: list) -> dict[str, list[tuple[float, list[float | None]]]]:
    """What the autopilot measured, per stream: (when: its stamp on the clock of the dive's log, by the
    least delay over the whole dive; the values)."""
    out: dict[str, list[tuple[float, list[float | None]]]] = {}
    for kind, name in SAMPLES.items():
        mine = [m for m in messages if m.get_type() == kind]
        offset = min(m._timestamp - boot_seconds(m) for m in mine)
        at = [boot_seconds(m) + offset for m in mine]
        if kind == "RAW_IMU":
            channels = default_streams()[Stream.KINEMATIC].channels
            out[name] = [(t, [float(getattr(m, c)) for c in channels]) for t, m in zip(at, mine, strict=True)]
        else:  # the agent's depth from the pressure, as it computes it: compared by temperature only
            out[name] = [(t, [m.temperature / 100.0, None, None]) for t, m in zip(at, mine, strict=True)]
    return out


@pytest.fixture
def ingest(tmp_path: Path):
    db = store_with(tmp_path, Vehicle(name="rov1", address=ADDRESS, key_hex=KEY.hex()))
    shore = Ingest(db, Bus(), default_streams(), Settings())
    shore.load_vehicles()
    yield shore
    db.dispose()


def test_a_real_dive_delivered_late_and_in_bursts_keeps_one_sample_per_time(tmp_path: Path, ingest) -> None:
    messages = [m for m in tlog.messages(DIVE) if m.get_type() in SAMPLES]
    truth = measured(messages)
    late_and_bunched(messages)
    config = AgentConfig(key=KEY.hex(), state_file=str(tmp_path / "agent-state.json"), modem_url="/dev/null")
    agent = Agent(config, config.plans(tmp_path))
    seq = 0

    def deliver(now: float) -> None:
        nonlocal seq
        for _, encoded in agent.compressor.ready(now, seq):
            frame = auth.tag_priority(encoded.packet, KEY, ADDRESS)
            seq += 1
            ingest.handle(IncomingFrame(ADDRESS, 1, frame, at=now))
            agent.compressor.resolve(encoded.packet.seq, True)

    loop = messages[0]._timestamp
    for msg in messages:
        if msg._timestamp >= loop + 0.1:  # the agent's loop takes what arrived since it last ran
            loop = msg._timestamp
            agent._drain_samples(agent.pose())
            deliver(loop)
        agent.mav._apply(msg)  # as its MAVLink thread hands each message on
    agent._drain_samples(agent.pose())
    for later in range(1, 200):
        deliver(messages[-1]._timestamp + later)

    with Session(ingest.db) as s:
        rows = s.exec(select(Telemetry).order_by(col(Telemetry.time), col(Telemetry.id))).all()
    for spec in default_streams().values():
        stored = [r for r in rows if r.stream == spec.name]
        samples = sorted(truth[spec.name], key=lambda x: x[0])
        assert all(r.certain for r in stored)
        assert len(stored) == len(samples) > 400  # every sample once
        for row, (at, values) in zip(stored, samples, strict=True):
            # the dive's first messages came 0.2-0.5 s late (a stream-rate change): until a prompt one
            # comes the agent dates them by the least delayed it has seen
            if at > samples[0][0] + 5.0:
                assert abs(row.time - at) <= spec.period / 2 + 0.01, (spec.name, row.tick)
            for v, m, e in zip(row.values, values, spec.eps, strict=True):
                assert m is None or abs(v - m) <= e + 1e-9, (spec.name, row.tick, row.values, values)
        by_tick = defaultdict(list)
        for row, (at, _) in zip(stored, samples, strict=True):
            by_tick[row.tick].append(at)
        shared = {tick: ats for tick, ats in by_tick.items() if len(ats) > 1}
        # several samples in one tick only in the dive's first seconds (its stream-rate change sent a
        # burst of messages measured milliseconds apart, which came late): after it, one per tick
        assert all(max(ats) < samples[0][0] + 5.0 for ats in shared.values()), shared
    assert np.isfinite([r.time for r in rows]).all()
