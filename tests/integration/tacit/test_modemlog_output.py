"""`tacit modem-log` says what it saw: packets read from a log are unverified unless the vehicle's key
checks them, bytes that are no Tacit packet are shown as such, the modem's errors are counted, and a
reader that stops early (``| head``) gets no traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tacit import auth, nmea
from tacit.modemlog import FROM_MODEM, TO_MODEM, ModemLog
from tacit.packets import (
    CheckpointPacket,
    Command,
    ControlPacket,
    MissionState,
    Priority,
    PriorityPacket,
    Stream,
    cover_bitmap,
)

KEY = bytes(range(32))
VEHICLE = 2


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tacit.cli", "modem-log", *args], capture_output=True, text=True, timeout=60
    )


def control(seq: int, key: bytes) -> str:
    return nmea.TxData(
        1, VEHICLE, True, auth.sign(ControlPacket(Command.HOLD, seq=seq, time=90), key, VEHICLE)
    ).line()


def received(frame: bytes) -> str:
    return nmea.RxData(VEHICLE, 1, False, 1, frame).line()


def write_log(path: Path) -> Path:
    """A session: two control packets (one signed with another key), a priority packet and the check-point
    that covers it, a check-point with a wrong MAC, bytes that are no packet, and the modem's errors."""
    priority = auth.tag_priority(
        PriorityPacket(5, Priority.IMPORTANT, Stream.KINEMATIC, b"\x11" * 29), KEY, VEHICLE
    )
    checkpoint = CheckpointPacket(seq=6, time=100, state=MissionState.HOLDING, covered=cover_bitmap(6, [5]))
    signed = auth.sign_checkpoint(checkpoint, KEY, 0, VEHICLE, [auth.packet_hash(priority)])
    log = ModemLog(path)
    for line in (control(1, KEY), control(2, bytes(32))):
        log.write(TO_MODEM, line)
    for line in (
        received(priority),
        received(signed),
        received(signed[:-1] + bytes([signed[-1] ^ 1])),
        received(b"\x01" * 32),  # packet version 0
        nmea.Error("120000", "NMEA", 1, "Bad NMEA sentence").line(),
        nmea.Message("BAD_CRC", "1").line(),
        nmea.Message("BAD_CRC", "2").line(),
        nmea.Message("PACKET_TIMEOUT", "0").line(),
    ):
        log.write(FROM_MODEM, line)
    log.close()
    return path


def packets_of(stdout: str) -> list[dict[str, object]]:
    return [p for line in stdout.splitlines() for p in json.loads(line).get("packets", [])]


def test_without_the_key_every_packet_is_unverified_and_other_bytes_are_no_packet(tmp_path: Path) -> None:
    path = write_log(tmp_path / "m.log")
    found = packets_of(run_cli(str(path), "--json").stdout)
    assert [p.get("type") for p in found] == [
        "control",
        "control",
        "priority",
        "checkpoint",
        "checkpoint",
        None,
    ]
    assert all(p["auth"] == "unverified" for p in found[:5])
    assert "auth" not in found[5] and "version" in str(found[5]["error"]) and found[5]["bytes"] == "01" * 32
    human = run_cli(str(path))
    assert human.returncode == 0, human.stderr
    assert "UNVERIFIED packet (no key given" in human.stdout
    assert (
        f"not a Tacit packet (unknown packet version 1 (byte 1; this end speaks 3, 4)): {'01' * 32}"
        in human.stdout
    )
    assert human.stdout.splitlines()[-1] == (
        "10 sentences, 5 packets (5 unverified), 1 not Tacit packets, 0 malformed lines, "
        "4 modem errors (2 BAD_CRC, 1 CAERR, 1 PACKET_TIMEOUT)"
    )


def test_the_vehicles_key_verifies_control_packets_and_check_points(tmp_path: Path) -> None:
    path = write_log(tmp_path / "m.log")
    result = run_cli(str(path), "--json", "--key", KEY.hex(), "--address", str(VEHICLE))
    assert result.returncode == 0, result.stderr
    found = packets_of(result.stdout)
    assert [p.get("auth") for p in found] == ["verified", "forged", "unverified", "verified", "forged", None]
    assert "vouches for the priority packets with seqs [5]" in str(found[3]["auth_detail"])
    rows = [json.loads(line) for line in result.stdout.splitlines()]
    assert [r.get("modem_error") for r in rows[6:]] == ["CAERR", "BAD_CRC", "BAD_CRC", "PACKET_TIMEOUT"]
    human = run_cli(str(path), "--key", KEY.hex(), "--address", str(VEHICLE)).stdout
    assert "5 packets (2 verified, 2 forged, 1 unverified)" in human and "FORGED packet" in human
    lone = run_cli(str(path), "--key", KEY.hex())
    assert lone.returncode == 2 and "--address" in lone.stderr


def test_a_reader_that_stops_early_gets_no_traceback(tmp_path: Path) -> None:
    path = tmp_path / "long.log"
    lines = [nmea.Message("BAD_CRC", "1").line()] + [nmea.Message("PACKET_TIMEOUT", "0").line()] * 20000
    path.write_text("\n".join(lines) + "\n")
    proc = subprocess.Popen(
        [sys.executable, "-m", "tacit.cli", "modem-log", str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None and proc.stderr is not None
    assert b"BAD_CRC" in proc.stdout.readline()
    proc.stdout.close()  # as head does after its lines
    assert proc.wait(timeout=60) in (0, 141)
    assert proc.stderr.read() == b""
