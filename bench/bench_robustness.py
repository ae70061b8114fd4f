"""Robustness, measured: fuzz cases and crashes, attacks accepted, faults injected and what they cost.

Every row has a test in the suite at a small budget (named in the last column); this runs them bigger.
  fuzz      random and mutated input to each parser: anything but its typed error is a crash
  attacks   forged, bit-flipped, replayed and stale control packets through the vehicle's gate; forged
            SYNC heartbeats (the only packets besides commands that hold off the link-lost failsafe);
            forged, bit-flipped and replayed check-points and forged priority packets through the
            shore's ingest (accepted = applied, or telemetry marked verified)
  safety    the separation check's doors: two queued moves, a mission start, "return all home" to one home,
            a lost-link return set by set_param, each across another vehicle (accepted = queued)
  tokens    a revoked token's open event stream, an expiring operator minting a longer-lived token
  backups   a backup with a byte flipped or cut anywhere (restored, or files left behind)
            (each row counts only the cases that reached the check: otherwise NOT MEASURED)
  api       schemathesis over the server's OpenAPI (every operation, --api-examples each): 5xx = failure
  rest      non-finite numbers, oversized keys and names, partial updates (tests/integration/server/api/test_bad_input.py)
  faults    the running system (sim, serve, agent as processes): 50 % frame loss, the server SIGKILLed
            mid-mission, the agent SIGKILLed mid-mission: stored packets lost, commands executed twice,
            priority packets decoded after the restart

  system    --system: the attacks of issue 21 against the whole system on simulators instead
            (bench/robustness_system.py: a second modem, a channel recorder, stepped clocks)
  broker    --broker: one gateway's credentials against the split shore's broker, a center and
            another gateway (bench/robustness_broker.py: a nats-server with tacit broker-config's
            accounts)

Run: .venv/bin/python bench/bench_robustness.py [--cases 20000] [--api-examples 50] [--no-faults]
     .venv/bin/python bench/bench_robustness.py --system
     .venv/bin/python bench/bench_robustness.py --broker [--cases 1000]
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import math
import os
import random
import re
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tacit import auth, nmea, packets  # noqa: E402
from tacit.codec import CodecError, StreamDecoder  # noqa: E402
from tacit.packets import CheckpointPacket, Command, ControlPacket, MissionState  # noqa: E402
from tacit.streams import default_streams  # noqa: E402

rows: list[tuple[str, str, str, str, str]] = []


def row(area: str, target: str, cases: str, bad: str, test: str) -> None:
    rows.append((area, target, cases, bad, test))


T = TypeVar("T")


def fuzz(
    name: str,
    cases: int,
    make: Callable[[random.Random], T],
    call: Callable[[T], object],
    expected: type[Exception],
    test: str,
) -> None:
    rng, crashes = random.Random(1), 0
    for _ in tqdm(range(cases), desc=name, leave=False):
        try:
            call(make(rng))
        except expected:
            pass
        except Exception:
            crashes += 1
    row("fuzz", name, f"{cases:,}", str(crashes), test)


def mutate(rng: random.Random, data: bytes) -> bytes:
    out = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        if out and rng.random() < 0.7:
            out[rng.randrange(len(out))] = rng.randrange(256)
        else:
            out.insert(rng.randrange(len(out) + 1), rng.randrange(256))
    return bytes(out)


VALID_LINES = [
    s.encode()
    for s in (
        "$CACYC,0,1,2,0,1,1*58",
        "$CAMPR,2,1,0.0101*7C",
        "$CAREV,000052,AUV,0.93.0.09*07",
        nmea.RxData(2, 1, True, 1, bytes(32)).line(),
    )
]
VALID_FRAME = CheckpointPacket(
    seq=3, time=1_800_000_000, state=MissionState.PREPROGRAMMED, depth=2.0
).encode()


def fuzzing(cases: int) -> None:
    fuzz(
        "NMEA reader (random bytes)",
        cases,
        lambda r: r.randbytes(r.randint(0, 120)),
        nmea.parse,
        nmea.NmeaError,
        "test_nmea: random_bytes, mutated_sentences",
    )
    fuzz(
        "NMEA reader (mutated sentences)",
        cases,
        lambda r: mutate(r, r.choice(VALID_LINES)),
        nmea.parse,
        nmea.NmeaError,
        "test_nmea: mutated_sentences",
    )
    fuzz(
        "NMEA reader (overlong and non-finite numbers)",
        cases,
        numeric_fields,
        parse_bounded,
        nmea.NmeaError,
        "test_nmea: overlong_and_non_finite, fuzzed_numeric_fields",
    )
    fuzz(
        "packet decoder (random frames)",
        cases,
        lambda r: r.randbytes(r.choice((31, 32, 32, 33))),
        packets.decode,
        packets.PacketError,
        "test_packets: random_bytes",
    )
    fuzz(
        "packet decoder (bit-flipped)",
        cases,
        lambda r: mutate(r, VALID_FRAME)[:32],
        packets.decode,
        packets.PacketError,
        "test_packets: bit_flipped",
    )
    spec = default_streams()[next(iter(default_streams()))]
    fuzz(
        "sample decoder (random payloads)",
        cases // 10,
        lambda r: r.randbytes(30),
        lambda p: StreamDecoder(spec).decode(p, time.time()),
        CodecError,
        "test_codec: garbage_is_a_codec_error",
    )
    row(
        "fuzz",
        "modem driver (garbage on a live pty)",
        *driver_garbage(cases // 20),
        "test_modem: garbage_from_modem",
    )


def numeric_fields(rng: random.Random) -> bytes:
    """A known sentence with one field replaced by an overlong or non-finite number."""
    cls = rng.choice(nmea.SENTENCES)
    fields = ["1"] * (len(cls.PREFIX) + len(dataclasses.fields(cls)))
    fields[rng.randrange(len(fields))] = rng.choice(
        ["9" * rng.randint(20, 900), "nan", "inf", "-Infinity", "1e999", "0." + "1" * rng.randint(20, 60)]
    )
    body = cls.TALKERS[0] + cls.SID + "," + ",".join(fields)
    return f"${body}*{nmea.checksum(body)}".encode()


def parse_bounded(line: bytes) -> None:
    """Parse; a non-finite float or an integer too long for a column slipping through is a crash."""
    parsed = nmea.parse(line)
    for value in dataclasses.astuple(parsed) if dataclasses.is_dataclass(parsed) else ():
        if isinstance(value, float) and not math.isfinite(value):
            raise AssertionError("non-finite value parsed")
        if isinstance(value, int) and abs(value) >= 2**63:
            raise AssertionError("integer too large for a database column parsed")


def driver_garbage(lines: int) -> tuple[str, str]:
    """Feed the running driver garbage over a real pty; it must stay ready and still answer a ping."""
    import tempfile

    from simulators.scripted_modem import ScriptedModem
    from tacit.modem import DriverSettings, LinkState, ModemDriver

    def rule(m, s):
        from simulators.scripted_modem import default_rule

        replies = default_rule(m, s)
        if isinstance(s, nmea.Ping):
            replies.append(nmea.PingReply(s.dest, s.src, 0.5).line())
        return replies

    modem = ScriptedModem(Path(tempfile.mkdtemp()) / "modem", rule)
    rng = random.Random(2)

    async def run() -> bool:
        driver = ModemDriver(DriverSettings(url=str(modem.path), address=1, keepalive=600))
        await driver.start()
        for _ in range(lines):
            modem.send(rng.randbytes(rng.randint(1, 80)).replace(b"\n", b"") + b"\r\n")
            if rng.random() < 0.3:
                modem.send(mutate(rng, rng.choice(VALID_LINES)).replace(b"\n", b"") + b"\r\n")
        await asyncio.sleep(1.0)
        alive = driver.state is LinkState.READY and await driver.ping(2, timeout=5) is not None
        await driver.stop()
        return alive

    alive = asyncio.run(run())
    modem.close()
    return f"{lines:,} lines", "0" if alive else "1 (driver stopped answering)"


def attacks(
    cases: int,
    command: Command = Command.HOLD,
    prefix: str = "",
    stale: bool = True,
    test: str = "test_auth; test_agent_system: forged_and_replayed",
) -> None:
    """Forged, bit-flipped, replayed (and stale) control packets of ``command`` against the vehicle's gate."""
    key, address, now = bytes(range(32)), 2, time.time()
    gate = auth.ControlReceiver(key, address)
    genuine = [
        auth.sign(ControlPacket(command, seq=i + 1, time=int(now)), key, address) for i in range(cases)
    ]
    for frame in genuine:
        gate.accept(frame, now)
    rng = random.Random(3 + int(command))
    kinds = {
        "forged (a stranger's key)": lambda i: auth.sign(
            ControlPacket(command, seq=10**6 + i, time=int(now) + 1), rng.randbytes(32), address),
        "bit-flipped": lambda i: mutate(rng, genuine[i % len(genuine)])[:32],
        "replayed": lambda i: genuine[i % len(genuine)],
    }  # fmt: skip
    if stale:
        kinds["out of window (stale)"] = lambda i: auth.sign(
            ControlPacket(command, seq=2 * 10**6 + i, time=int(now) - 3600), key, address
        )
    for name, make in kinds.items():
        accepted = 0
        for i in range(cases):
            try:
                gate.accept(make(i), now)
                accepted += 1
            except packets.PacketError:
                pass
        row("attacks", prefix + name, f"{cases:,}", f"{accepted} accepted", test)


def flip(rng: random.Random, frame: bytes) -> bytes:
    """``frame`` with one to three distinct bits inverted (never the frame itself)."""
    out = bytearray(frame)
    for bit in rng.sample(range(len(frame) * 8), rng.randint(1, 3)):
        out[bit // 8] ^= 1 << (bit % 8)
    return bytes(out)


def shore_attacks(cases: int) -> None:
    """Vehicle -> shore forgeries through the real ingest on a SQLite file: forged, bit-flipped and
    replayed check-points (accepted = applied), forged priority packets (accepted = marked verified)."""
    import tempfile

    from sqlmodel import Session, select

    from server.core.config import Settings
    from server.core.db import make_engine, migrate
    from server.core.events import Bus as EventBus
    from server.link.ingest import Ingest
    from server.link.state import IncomingFrame
    from server.telemetry.models import Packet
    from server.vehicles.models import Vehicle

    url = f"sqlite:///{tempfile.mkdtemp(prefix='tacit-attacks-')}/tacit.db"
    migrate(url)
    db = make_engine(url)
    key, address = bytes(range(32)), 2
    with Session(db) as s:
        s.add(Vehicle(name="rov1", address=address, key_hex=key.hex()))
        s.commit()
    ingest = Ingest(db, EventBus(), default_streams(), Settings())
    ingest.load_vehicles()
    rng, t0 = random.Random(5), int(time.time())

    def checkpoint(i: int, signer: bytes, stamp: int) -> bytes:
        cp = CheckpointPacket(
            seq=i % 256, time=stamp, state=MissionState.PREPROGRAMMED, north=-3000.0, depth=300.0
        )
        return auth.sign_checkpoint(cp, signer, 1, address, [])

    genuine = checkpoint(0, key, t0)
    ingest.handle(IncomingFrame(address, 1, genuine))
    heard = [checkpoint(i, key, t0 + 100 + i) for i in range(cases)]  # genuine, then replayed byte for byte
    for frame in heard:
        ingest.handle(IncomingFrame(address, 1, frame))
    kinds = {
        "check-point forged (a stranger's key)": lambda i: checkpoint(i, rng.randbytes(32), t0 + i),
        "check-point bit-flipped (1-3 bits)": lambda i: flip(rng, checkpoint(i, key, t0 + 1 + i)),
        "check-point replayed (the same bytes again)": lambda i: heard[i],
        "priority packet forged (any 30 bytes)": lambda i: bytes([0xE0 | rng.randrange(16), i % 256]) + rng.randbytes(30),
    }  # fmt: skip
    for name, make in kinds.items():
        before = ingest.stats["verified"]
        for i in range(cases):
            ingest.handle(IncomingFrame(address, 1, make(i)))
        if name.startswith("priority"):  # a genuine check-point after them covers nothing of theirs
            ingest.handle(IncomingFrame(address, 1, checkpoint(cases, key, t0 + 10**6)))
            with Session(db) as s:
                accepted = len(
                    s.exec(select(Packet).where(Packet.type == "priority", Packet.auth == "verified")).all()
                )
        else:
            accepted = ingest.stats["verified"] - before
        row("attacks", name, f"{cases:,}", f"{accepted} accepted", "test_verify: forged_*")
    late_checkpoints(ingest, cases, lambda i: checkpoint(i, key, t0 - 1 - i))
    db.dispose()


def late_checkpoints(ingest: Any, cases: int, make: Callable[[int], bytes]) -> None:
    """Genuine check-points never heard before, stamped before the last one applied (one that came late
    through another gateway, or a recording of one the shore missed): verified as late, they may vouch
    for packets but must not set the vehicle's state back."""
    from server.link.state import IncomingFrame

    (vehicle,) = ingest.states()
    before, late = vehicle.link.checkpoint_time, ingest.stats["late"]
    for i in range(cases):
        ingest.handle(IncomingFrame(vehicle.address, 1, make(i)))
    moved = int(vehicle.link.checkpoint_time != before)
    row(
        "attacks",
        "check-point late (never heard, older than the last)",
        f"{cases:,}",
        f"{moved} set the state back ({ingest.stats['late'] - late} verified late)",
        "test_verify: forged_checkpoints_change_nothing; test_outages_and_restarts",
    )


def doors(cases: int) -> None:
    """The safety functions' doors, the tokens' limits and the backups' checksum, attacked through the
    API of a server on a SQLite file (check-points through its ingest, as the modem delivers them). A
    row counts only the cases whose attack reached the check (the setup it needs was accepted, the
    request was answered by the check, not refused before it): fewer than ``cases`` says NOT MEASURED."""
    import itertools
    import tempfile

    from fastapi.testclient import TestClient

    from server.app import create_app
    from server.core.config import Settings
    from server.link.state import IncomingFrame
    from tacit.params import LostAction, Param

    scratch = Path(tempfile.mkdtemp(prefix="tacit-doors-"))
    settings = Settings(
        database_url=f"sqlite:///{scratch}/tacit.db", modem_url="", map_enabled=False, write_tokens=["op"],
        ping_interval=3600,
    )  # fmt: skip
    op = {"Authorization": "Bearer op"}
    keys = [bytes([k + 1]) * 32 for k in range(3)]
    stamps = itertools.count(int(time.time()) - 100_000)
    with TestClient(create_app(settings)) as c:
        for k, key in enumerate(keys):
            c.post(
                "/api/v1/vehicles",
                json={"name": f"rov{k + 1}", "address": k + 2, "key": key.hex()},
                headers=op,
            )
        ingest = c.app.state.shore.ingest  # type: ignore[attr-defined]

        def place(*where: tuple[float, float]) -> None:
            for k, (north, east) in enumerate(where):
                cp = CheckpointPacket(seq=next(stamps) % 256, time=next(stamps), state=MissionState.HOLDING,
                                      north=north, east=east, depth=2.0)  # fmt: skip
                ingest.handle(IncomingFrame(k + 2, 1, auth.sign_checkpoint(cp, keys[k], 1, k + 2, [])))

        def send(vehicle: int, body: dict) -> int:
            return c.post(f"/api/v1/vehicles/{vehicle}/commands", json=body, headers=op).status_code

        def move(bearing: float) -> dict:
            return {"command": "move", "distance": 20.0, "angle": bearing, "absolute_angle": True}

        def two_moves(x: float, y: float) -> tuple[bool, bool]:
            place((x, y), (x + 100, y + 100), (x + 10, y + 10))  # rov3 inside east-then-north
            first, second = send(1, move(90.0)), send(1, move(0.0))
            return first == 202 and second in (202, 422), second == 202

        def mission_start(x: float, y: float) -> tuple[bool, bool]:
            place((x, y), (x + 100, y + 100), (x, y + 14))
            route = [{"north": x, "east": y, "depth": 2.0}, {"north": x, "east": y + 28, "depth": 2.0}]
            body = {"name": "across", "number": 1, "waypoints": route}
            mission = c.post("/api/v1/vehicles/1/missions", json=body, headers=op).json()
            started = c.post(f"/api/v1/missions/{mission['id']}/start", headers=op).status_code
            return started in (202, 422), started == 202

        def shared_home(x: float, y: float) -> tuple[bool, bool]:
            place((x, y), (x + 100, y + 100), (x - 100, y + 100))  # every home is the origin
            answer = c.post("/api/v1/fleet/commands", json={"command": "return_home"}, headers=op).status_code
            return answer in (202, 422), answer == 202

        def lost_return(x: float, y: float) -> tuple[bool, bool]:
            place((x + 100, y - 100), (x, y), (x / 2, y / 2))  # rov3 halfway home from rov2
            body = {
                "command": "set_param",
                "param_id": int(Param.LOST_ACTION),
                "param_value": float(LostAction.RETURN.code),
            }
            answer = send(2, body)
            return answer in (202, 422), answer == 202

        attacks = {
            "two queued moves around another vehicle": two_moves,
            "a mission start whose route crosses one": mission_start,
            "return all home to one shared home": shared_home,
            "lost-link return set across another (set_param)": lost_return,
        }
        rng = random.Random(11)
        for name, attack in attacks.items():
            reached = accepted = 0
            for _ in range(cases):
                hit, bad = attack(rng.uniform(-300, 300), rng.uniform(-300, 300))
                reached += hit
                accepted += bad
                c.post(
                    "/api/v1/fleet/commands", json={"command": "abort_mission"}, headers=op
                )  # a clean slate
            counted = (
                f"{accepted} accepted" if reached == cases else f"NOT MEASURED ({reached} of {cases} reached)"
            )
            row("safety", name, f"{cases:,}", counted, "test_separation")
        token_attacks(c, op, cases)
    backup_attacks(Path(settings.database_url.removeprefix("sqlite:///")), cases)


def token_attacks(c: Any, op: dict[str, str], cases: int) -> None:
    """A revoked token's event stream (events after the revocation), and an expiring operator minting a
    longer-lived token."""
    streams = min(cases, 20)
    leaked = reached = 0
    for i in range(streams):
        made = c.post("/api/v1/operators", json={"name": f"watcher{i}", "role": "read"}, headers=op).json()
        with c.stream(
            "GET", "/api/v1/events", headers={"Authorization": f"Bearer {made['token']}"}
        ) as stream:
            for line in stream.iter_lines():
                if line == ": connected":
                    reached += 1
                    c.delete(f"/api/v1/operators/{made['id']}", headers=op)
                    c.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=op)
                if line.startswith("event: command"):  # the stream outlived its token: counted, closed
                    leaked += 1
                    break
    outcome = (
        f"{leaked} events after revocation"
        if reached == streams
        else f"NOT MEASURED ({reached} of {streams})"
    )
    row("tokens", "a revoked token's open event stream", f"{streams:,}", outcome, "test_tokens")
    minted = reached = 0
    for i in range(cases):
        short = c.post(
            "/api/v1/operators", json={"name": f"short{i}", "role": "write", "expires_in_s": 60}, headers=op
        )
        mine = {"Authorization": f"Bearer {short.json()['token']}"}
        asked = {"name": f"long{i}", "role": "write", "expires_in_s": None if i % 2 else 3600.0}
        answer = c.post("/api/v1/operators", json=asked, headers=mine).status_code
        reached += answer in (201, 422)
        minted += answer == 201
    outcome = f"{minted} minted" if reached == cases else f"NOT MEASURED ({reached} of {cases})"
    row("tokens", "an expiring operator mints a longer-lived token", f"{cases:,}", outcome, "test_tokens")


def backup_attacks(database: Path, cases: int) -> None:
    """A backup of the running database with a byte flipped anywhere, or cut anywhere: restored (bad), or
    refused leaving files behind (bad); reached: the untouched backup restores."""
    import tempfile

    from server.ops import backup

    scratch = Path(tempfile.mkdtemp(prefix="tacit-backups-"))
    good = scratch / "good.backup"
    backup.backup(f"sqlite:///{database}", good)
    backup.restore(good, f"sqlite:///{scratch}/check.db")
    reached = (scratch / "check.db").exists()
    data, rng, restored, left = good.read_bytes(), random.Random(13), 0, 0
    for i in range(cases):
        bad = bytearray(data)
        if i % 2:
            bad = bad[: rng.randrange(len(bad))]
        else:
            bad[rng.randrange(len(bad))] ^= 1 << rng.randrange(8)
        path, target = scratch / "bad.backup", scratch / "restored" / f"{i}.db"
        path.write_bytes(bytes(bad))
        try:
            backup.restore(path, f"sqlite:///{target}")
            restored += 1
        except backup.BackupError:
            pass
        left += (scratch / "restored").exists()
    outcome = (
        f"{restored} restored, {left} left files"
        if reached
        else "NOT MEASURED (the good backup did not restore)"
    )
    row(
        "backups",
        "a backup flipped or truncated anywhere",
        f"{cases:,}",
        outcome,
        "test_operations: corrupt_truncated",
    )


def api(examples: int) -> None:
    passed, failed = pytest_counts("api/test_schemathesis.py", {"TACIT_API_EXAMPLES": str(examples)})
    row(
        "api",
        "schemathesis, every operation",
        f"{passed + failed} ops x {examples}",
        f"{failed} failed",
        "test_schemathesis",
    )
    passed, failed = pytest_counts("api/test_bad_input.py")
    row(
        "api",
        "NaN/Infinity/1e999 in every float, 100 kB keys, partial PUT",
        f"{passed + failed} tests (150 property examples)",
        f"{failed} failed",
        "test_bad_input",
    )


def pytest_counts(test_file: str, env: dict[str, str] | None = None) -> tuple[int, int]:
    """Run one file of the server's integration tests; how many passed and how many failed."""
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            f"tests/integration/server/{test_file}",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
    )
    passed = int(m.group(1)) if (m := re.search(r"(\d+) passed", result.stdout)) else 0
    failed = int(m.group(1)) if (m := re.search(r"(\d+) failed", result.stdout)) else 0
    return passed, failed


def faults() -> None:
    from launch.rig import Rig

    rig = Rig(300.0, scale=10.0, extra_loss=0.5, attempts=10)
    try:
        results = [rig.command({"command": "hold"}, timeout=150) for _ in range(8)]
        time.sleep(2)
        executed = rig.executed_per_seq()
    finally:
        rig.close()
    failed = sum(1 for status, _ in results if status == "failed")
    row(
        "faults",
        "50 % frame loss, 8 commands",
        "8",
        f"{failed} undelivered, {sum(n - 1 for n in executed.values())} executed twice",
        "bench_link delivery; test_channel: extra_loss",
    )

    for victim in ("server", "agent"):
        kill_mid_mission(victim)
    suite_row(
        "faults",
        "MAVLink link dropped and restored",
        "tests/integration/vehicle_agent/test_mavlink_reconnect.py::test_mavlink_link_drops_and_the_agent_reconnects",
    )
    suite_row(
        "faults",
        "modem rebooted mid-cycle",
        "tests/integration/tacit/test_modem.py::test_modem_rebooting_mid_cycle_fails_the_cycle_then_recovers",
    )
    suite_row(
        "faults",
        "serial port vanished and returned",
        "tests/integration/tacit/test_modem.py::test_vanished_port_comes_back",
    )


def suite_row(area: str, target: str, test: str) -> None:
    """A fault whose injection lives in a test: run it and report its outcome."""
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", test],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    row(area, target, "1", "0" if result.returncode == 0 else "1 (test failed)", test.split("::")[-1])


def kill_mid_mission(victim: str) -> None:
    """SIGKILL the server or the agent mid-mission with a command queued; count what it cost."""
    from launch.rig import Rig
    from launch.stack import wait_for

    rig = Rig(200.0, scale=5.0, mission=True)
    try:
        http = rig.http
        rig.start_square()
        wait_for(lambda: http.get("/packets", params={"limit": 1}).json()["total"] >= 5, 60, what="packets")
        queued = http.post("/vehicles/1/commands", json={"command": "goto_depth", "depth": 3.0}).json()
        before = {p["id"] for p in http.get("/packets", params={"limit": 1000}).json()["items"]}
        killed_at = time.time()
        if victim == "server":
            rig.kill_server()
            rig.start_server()
        else:
            rig.kill_agent()
            rig.start_agent()
        wait_for(
            lambda: http.get(f"/commands/{queued['id']}").json()["status"] in ("executing", "executed"),
            120,
            what="queued command executed",
        )
        after = {p["id"] for p in http.get("/packets", params={"limit": 1000}).json()["items"]}
        twice = sum(n - 1 for n in rig.executed_per_seq().values())

        def after_restart() -> list[dict]:
            items = http.get("/packets", params={"limit": 1000, "type": "priority"}).json()["items"]
            return [p for p in items if p["at"] > killed_at]

        wait_for(lambda: any("error" not in p["body"] for p in after_restart()), 120, what="a packet decoded")
        late = after_restart()
        decoded = sum(1 for p in late if "error" not in p["body"])
        row(
            "faults",
            f"{victim} SIGKILLed mid-mission",
            "1",
            f"{len(before - after)} packets lost, {twice} executed "
            f"twice, {decoded}/{len(late)} priority packets decoded after restart",
            "test_faults" if victim == "server" else "test_agent_system: survives_an_agent_restart",
        )
    finally:
        rig.close()


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--cases", type=int, default=20_000, help="fuzz cases per parser")
    parser.add_argument("--api-examples", type=int, default=50, help="schemathesis examples per operation")
    parser.add_argument(
        "--no-faults", action="store_true", help="skip the fault runs (they start the system)"
    )
    parser.add_argument(
        "--system",
        action="store_true",
        help="only the attacks of issue 21 on the whole system (sim, serve, agent as processes, simulated "
        "time 10x; about 10 minutes); exits 1 if one could not show it reached the system",
    )
    parser.add_argument(
        "--broker",
        action="store_true",
        help="only the attacks on the split shore's broker from one gateway's credentials (about a "
        "minute); exits 1 if one could not show it reached the broker",
    )
    parser.add_argument(
        "--claims",
        action="store_true",
        help="only the attacks on the center through one gateway's word (what it reports, what it relays, "
        "when; about a minute); exits 1 if one could not show it reached the center",
    )
    options = parser.parse_args()
    if options.claims:
        sys.exit(claims(max(10, options.cases // 1000)))
    if options.system:
        sys.exit(system())
    if options.broker:
        sys.exit(broker(max(10, options.cases // 400)))
    fuzzing(options.cases)
    attacks(max(100, options.cases // 20))
    attacks(max(100, options.cases // 20), Command.SYNC, "SYNC ", False, "test_auth: sync_corrects_the_clock")
    shore_attacks(max(100, options.cases // 100))
    doors(max(20, options.cases // 400))
    api(options.api_examples)
    if not options.no_faults:
        faults()
    table([("area", "target", "cases", "bad outcomes", "test in the suite"), *rows])


def table(lines: list[tuple[str, ...]]) -> None:
    widths = [max(len(line[i]) for line in lines) for i in range(len(lines[0]))]
    for line in lines:
        print("  ".join(cell.ljust(w) for cell, w in zip(line, widths, strict=True)).rstrip())


def broker(cases: int) -> int:
    """The attacks on the broker: their table; 1 if one measured nothing."""
    import robustness_broker

    rows = robustness_broker.run(cases)
    header = ("attack", "cases", "outcome", "shows it reached the broker", "test in the suite")
    table([header, *(dataclasses.astuple(r) for r in rows)])
    return 1 if any("NOT MEASURED" in r.checked for r in rows) else 0


def claims(cases: int) -> int:
    """The attacks through a gateway's word: their table; 1 if one measured nothing."""
    import robustness_claims

    rows = robustness_claims.run(cases)
    header = ("attack", "cases", "outcome", "shows it reached the center", "test in the suite")
    table([header, *(dataclasses.astuple(r) for r in rows)])
    return 1 if any(r.checked.startswith("NOT MEASURED") for r in rows) else 0


def system() -> int:
    """The attacks on the whole system: their table; 1 if one measured nothing."""
    import robustness_system

    rows = robustness_system.run()
    header = ("attack", "cases", "outcome", "shows it reached the system", "test in the suite")
    table([header, *(dataclasses.astuple(r) for r in rows)])
    return 1 if any(r.checked.startswith("NOT MEASURED") for r in rows) else 0


if __name__ == "__main__":
    main()
