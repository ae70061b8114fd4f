"""WHOI's own host library (PyPI `acomms`) drives the emulated Micro-Modems over their ptys."""

from __future__ import annotations

import json
import queue
import time
from pathlib import Path

import pytest
from acomms import Micromodem

from tests.conftest import tacit_process

DISTANCE = 150.0

# acomms's reader thread keeps reading after disconnect() closes its port and dies with a TypeError
# inside pyserial: a bug of the library under test's teardown, not of the simulator.
pytestmark = pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")


def write_config(tmp_path: Path) -> Path:
    config = {
        "seed": 3,
        "time_scale": 4.0,  # the channel's delays and airtimes in simulated time, four times faster
        "channel": {"noise_level_db": 90.0},
        "modems": [
            {"address": 1, "name": "shore", "position": [0.0, 0.0, 1.0]},
            {"address": 2, "name": "far", "position": [DISTANCE, 0.0, 1.0]},
        ],
    }
    path = tmp_path / "sim.json"
    path.write_text(json.dumps(config))
    return path


def connect(pty: str, name: str, log_dir: Path) -> Micromodem:
    modem = Micromodem(name=name, log_path=str(log_dir) + "/", log_level="WARNING")
    modem.connect_serial(pty, 19200)
    deadline = time.monotonic() + 5
    while modem.id < 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    return modem


def test_acomms_reads_id_sends_with_ack_and_pings(tmp_path: Path) -> None:
    with tacit_process("sim", "--config", str(write_config(tmp_path))) as (_, info):
        ptys = {m["address"]: m["pty"] for m in info["modems"]}
        a = connect(ptys[1], "a", tmp_path)
        b = connect(ptys[2], "b", tmp_path)
        try:
            assert (a.id, b.id) == (1, 2)
            frames: queue.Queue = queue.Queue()
            acks: queue.Queue = queue.Queue()
            b.incoming_dataframe_queues.append(frames)
            a.ack_listeners.append(lambda ack, msg: acks.put(ack))
            a.send_packet_data(2, bytearray(range(32)), rate_num=0, ack=True)
            frame = frames.get(timeout=20)
            assert bytes(frame.data) == bytes(range(32)) and (frame.src, frame.dest) == (1, 2)
            ack = acks.get(timeout=20)
            assert (ack.src, ack.dest) == (2, 1)
            a.send_ping(2)
            travel = a.wait_for_ping_reply(2, timeout=20)
            assert travel == pytest.approx(DISTANCE / 1500.0, rel=0.01)
        finally:
            a.disconnect()
            b.disconnect()
