"""`tacit modem-log`: every line decoded, malformed lines reported with their number, never fatal."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tacit import auth, nmea
from tacit.link import to_frames
from tacit.modemlog import FROM_MODEM, TO_MODEM, ModemLog
from tacit.packets import CheckpointPacket, Command, ControlPacket, MissionState


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tacit.cli", "modem-log", *args], capture_output=True, text=True, timeout=60
    )


def test_decodes_a_driver_log_with_packets_and_bad_lines(tmp_path: Path) -> None:
    control = auth.sign(ControlPacket(Command.MOVE, seq=3, time=10, distance=5), bytes(32), 2)
    checkpoint = CheckpointPacket(seq=1, time=11, state=MissionState.PREPROGRAMMED, depth=2.5).encode()
    log = ModemLog(tmp_path / "m.log")
    log.write(TO_MODEM, nmea.Cycle(1, 2, 0, True, 1).line())
    log.write(TO_MODEM, nmea.TxData(1, 2, True, control).line())
    log.write(FROM_MODEM, "$CAMPA,1,2*00")
    log.write(FROM_MODEM, nmea.RxData(2, 1, False, 1, checkpoint).line())
    log.write(FROM_MODEM, nmea.RxData(2, 1, False, 1, b"\x00" * 32).line())
    log.close()
    with (tmp_path / "m.log").open("a") as handle:
        handle.write("\n\x01\x02 noise without a dollar\n$CAREV,000052,AUV,0.93.0.09*07\n")
    result = run_cli(str(tmp_path / "m.log"), "--json")
    assert result.returncode == 0, result.stderr
    rows = [json.loads(line) for line in result.stdout.splitlines()]
    assert [r["line"] for r in rows] == [1, 2, 3, 4, 5, 7, 8]
    assert rows[0]["sentence"] == "CCCYC" and rows[0]["direction"] == "to_modem" and "time" in rows[0]
    assert rows[1]["packets"][0]["type"] == "control" and rows[1]["packets"][0]["distance"] == 5.0
    assert "checksum" in rows[2]["error"]
    assert rows[3]["packets"][0]["type"] == "checkpoint" and rows[3]["packets"][0]["depth"] == 2.5
    assert "padding" in rows[4]["packets"][0]["error"]
    assert "error" in rows[5] and rows[5]["line"] == 7
    assert rows[6]["sentence"] == "CAREV" and "time" not in rows[6]


def test_a_rate_5_frame_is_split_into_its_packets_as_the_link_splits_it(tmp_path: Path) -> None:
    reports = [CheckpointPacket(seq=i, time=20 + i, state=MissionState.HOLDING).encode() for i in range(3)]
    (frame,) = to_frames(reports, 5)
    log = ModemLog(tmp_path / "m.log")
    log.write(FROM_MODEM, nmea.RxData(2, 1, False, 1, frame).line())
    log.write(FROM_MODEM, nmea.RxData(2, 1, False, 1, reports[0] + b"\x01\x02").line())
    log.close()
    result = run_cli(str(tmp_path / "m.log"), "--json")
    first, second = (json.loads(line) for line in result.stdout.splitlines())
    assert [p["seq"] for p in first["packets"]] == [0, 1, 2]
    assert second["packets"][0]["seq"] == 0 and "not a whole number" in second["packets"][1]["error"]


def test_human_output_and_summary(tmp_path: Path) -> None:
    (tmp_path / "bare.log").write_text("$CAMPR,2,1,0.0101*7C\n$CAMPR,2,1*00\n")
    result = run_cli(str(tmp_path / "bare.log"))
    assert result.returncode == 0
    assert "CAMPR" in result.stdout and "travel_time=0.0101" in result.stdout
    assert result.stdout.strip().endswith(
        "1 sentences, 0 packets, 0 not Tacit packets, 1 malformed lines, 0 modem errors"
    )


def test_unreadable_file_is_a_clear_error(tmp_path: Path) -> None:
    result = run_cli(str(tmp_path / "missing.log"))
    assert result.returncode == 1 and "cannot read" in result.stderr
