"""The attacks of issue 21 against the whole system on simulators (``bench_robustness.py --system``).

Each attack gets a fresh stack (``launch.rig.Rig``: ``tacit sim``, ``tacit serve`` and ``tacit agent`` as
processes, simulated time ``SCALE`` times faster than the wall clock) with what it needs: a second modem
in the water that claims whatever address the attack needs (``attacker``), a recorder that reports
every data frame on the channel (``recorder``), wall clocks that can be stepped (``stepped_clocks``).
Every row checks that it measured what it claims (the attack frames were heard, the window saw traffic);
a row that could not is marked ``NOT MEASURED`` and the command exits 1.

Rates are per simulated minute; times are simulated seconds (wall seconds x ``SCALE``).
"""

from __future__ import annotations

import asyncio
import logging
import random
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import serial

from launch.rig import TOKEN, Rig
from launch.stack import SHORE_ADDRESS, VEHICLE_ADDRESS, wait_for
from tacit import nmea
from tacit.modem import DriverSettings, ModemDriver
from tacit.packets import (
    PACKET_SIZE,
    CheckpointPacket,
    Command,
    ControlPacket,
    PacketError,
    Priority,
    PriorityPacket,
    Stream,
    decode,
)

SCALE = 10.0  # simulated seconds per wall second
WINDOW_S = 180.0  # simulated seconds each before / during window lasts
TWINS_S = 300.0  # simulated seconds of twins: several check-points' worth
ROTATION_S = 400.0  # a waiting rotation watched longer than the agent's link_lost_timeout (300 s)
STRANGER = 9  # a modem address nobody registered
REACHED = ("executing", "executed", "refused")  # the vehicle answered the command


@dataclass
class Row:
    attack: str
    cases: str
    outcome: str
    checked: str  # what shows the attack happened, or NOT MEASURED and why
    test: str


class NotMeasured(RuntimeError):
    """The run could not show that the attack reached the system."""


class Recorder:
    """The recorder modem's reports: every data frame heard on the channel (src, dest, bytes)."""

    def __init__(self, path: Path) -> None:
        self.port = serial.Serial(str(path), timeout=0.2)
        self.frames: list[tuple[int, int, bytes]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            line = self.port.readline()
            try:
                sentence = nmea.parse(line.strip()) if line.strip() else None
            except nmea.NmeaError:
                continue
            if isinstance(sentence, nmea.RxData):
                self.frames.append((sentence.src, sentence.dest, sentence.data))

    def heard(self, src: int, dest: int, kind: type) -> list[tuple[bytes, Any]]:
        """The frames ``src`` sent ``dest`` that decode as ``kind``, with their packets, oldest first."""
        out = []
        for s, d, data in list(self.frames):
            if (s, d) != (src, dest) or len(data) != PACKET_SIZE:
                continue
            try:
                packet = decode(data)
            except PacketError:
                continue
            if isinstance(packet, kind):
                out.append((data, packet))
        return out

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.port.close()


def transmit(rig: Rig, claim: int, dest: int, frames: list[bytes], gap_s: float = 1.0) -> int:
    """Send ``frames`` from the attacker's modem set to address ``claim``, one rate-0 cycle each without
    ACK, ``gap_s`` simulated seconds apart; how many went on the air. The modem keeps the address after
    (with no frames: it only takes the address, and acknowledges what is sent to it from then on)."""

    async def run() -> int:
        settings = DriverSettings(url=str(rig.stack.pty("attacker")), address=claim, keepalive=600)
        driver = ModemDriver(settings)
        await driver.start()
        sent = 0
        for frame in frames:
            sent += (await driver.send(dest, [frame], rate=0, ack=False)).transmitted
            await asyncio.sleep(gap_s / rig.scale)
        await driver.stop()
        return sent

    return asyncio.run(run())


def link(rig: Rig) -> dict[str, Any]:
    return rig.http.get("/link").json()


def polls_and_packets(rig: Rig) -> tuple[int, int]:
    status = link(rig)
    return status["counters"]["polls"], status["vehicles"]["rov1"]["packets"]


def per_minute(rig: Rig, wall_s: float) -> tuple[float, float]:
    """Polls and vehicle packets per simulated minute over the next ``wall_s`` wall seconds."""
    polls, packets = polls_and_packets(rig)
    time.sleep(wall_s)
    polls2, packets2 = polls_and_packets(rig)
    minutes = wall_s * rig.scale / 60
    return (polls2 - polls) / minutes, (packets2 - packets) / minutes


def start_mission(rig: Rig) -> None:
    rig.start_square()
    wait_for(lambda: link(rig)["vehicles"]["rov1"]["checkpoint"], 120, what="a first check-point")


def agent_log(rig: Rig, since: int = 0) -> str:
    return rig.stack.log("agent.log")[since:]


def command(rig: Rig, body: dict[str, Any]) -> int:
    response = rig.http.post("/vehicles/1/commands", json=body)
    response.raise_for_status()
    return int(response.json()["id"])


def status(rig: Rig, command_id: int) -> str:
    return str(rig.http.get(f"/commands/{command_id}").json()["status"])


def sim_s(rig: Rig, wall_s: float) -> float:
    return wall_s * rig.scale


def lost_state() -> Row:
    """A recorded SYNC and command replayed to a vehicle whose state file was lost."""
    rig = Rig(300.0, SCALE, mission=True, attacker=True, recorder=True, settle=0)
    recorder = Recorder(rig.stack.pty("recorder"))
    try:
        start_mission(rig)
        genuine = command(rig, {"command": "goto_depth", "depth": 1.5})
        wait_for(lambda: status(rig, genuine) in REACHED, 120, what="the genuine command")
        controls = recorder.heard(SHORE_ADDRESS, VEHICLE_ADDRESS, ControlPacket)
        syncs = [f for f, p in controls if p.command is Command.SYNC]
        commands = [f for f, p in controls if p.command is Command.GOTO_DEPTH]
        if not syncs or not commands:
            raise NotMeasured("the recorder heard no SYNC or no command")
        recorded = decode(commands[-1]).seq
        rig.kill_agent()
        Path(rig.stack.dir / "agent-state.json").unlink()
        offset = len(agent_log(rig))
        restarted, syncs_before = time.monotonic(), link(rig)["counters"]["syncs"]
        rig.start_agent()
        wait_for(lambda: " up: modem " in agent_log(rig, offset), 30, what="the agent restarted")
        replayed = [syncs[-1], commands[-1]] * 3
        sent = transmit(rig, SHORE_ADDRESS, VEHICLE_ADDRESS, replayed)
        wait_for(lambda: "accepted (shore time" in agent_log(rig, offset), 120, what="the shore's answer")
        resynced = sim_s(rig, time.monotonic() - restarted)
        exchanges = wait_for(  # the shore counts a SYNC once its cycle is over, after the vehicle took it
            lambda: link(rig)["counters"]["syncs"] - syncs_before, 30, what="the SYNC counted"
        )
        log = agent_log(rig, offset)
        executed = log.count(f"control seq {recorded} accepted")
        refused = log.count("control frame rejected")
        if refused == 0:
            raise NotMeasured(f"{sent} replayed frames sent, none reached the agent")
        return Row(
            "lost state file + recorded SYNC and command",
            f"{sent} frames replayed",
            f"commands executed by the attack: {executed}; resynchronised {resynced:.0f} s after the "
            f"restart, {exchanges} SYNC(s) sent",
            f"{refused} replayed frames refused by the agent",
            "test_freshness: attack_1_a_lost_state",
        )
    finally:
        recorder.close()
        rig.close()


def forged_restart_with_acking_modem() -> Row:
    """A forged priority packet from the vehicle's address, then the second modem stays, acknowledging
    every frame sent to the vehicle at the same moment as the vehicle's own modem."""
    rig = Rig(300.0, SCALE, mission=True, attacker=True, settle=0)
    try:
        start_mission(rig)
        before = per_minute(rig, WINDOW_S / rig.scale)
        forged_before = link(rig)["ingest"]["forged"]
        offset = len(agent_log(rig))
        rng = random.Random(4)

        def forged() -> bytes:
            seq = rng.randrange(256)
            return PriorityPacket(seq, Priority.IMPORTANT, Stream.KINEMATIC, rng.randbytes(29)).encode()

        sent = send_until_counted(rig, VEHICLE_ADDRESS, forged, lambda: link(rig)["ingest"]["forged"])
        during = per_minute(rig, WINDOW_S / rig.scale)
        heard = link(rig)["ingest"]["forged"] - forged_before
        restarts = agent_log(rig, offset).count("shore asked to restart the sample chains")
        if heard == 0:
            raise NotMeasured(f"{sent} forged packets sent, none heard by the shore")
        return Row(
            "forged priority packet + idle second modem ACKing as the vehicle",
            f"{sent} forged until one was heard, then {WINDOW_S:.0f} s",
            f"polls/min {before[0]:.1f} before, {during[0]:.1f} during; vehicle packets/min "
            f"{before[1]:.1f} before, {during[1]:.1f} during; chain restarts on the vehicle: {restarts}",
            f"{heard} forged packets heard by the shore (refused: tag)",
            "test_fair_queue: forged_packets_with_an_unknown_base",
        )
    finally:
        rig.close()


def forged_twins() -> Row:
    """Forged packets at the vehicle's next sequence numbers, read off the channel, for a window."""
    rig = Rig(300.0, SCALE, mission=True, attacker=True, recorder=True, settle=0)
    recorder = Recorder(rig.stack.pty("recorder"))
    try:
        start_mission(rig)
        stats = link(rig)["ingest"]
        started, sent, rng, last = time.monotonic(), 0, random.Random(5), 0
        while time.monotonic() - started < TWINS_S / rig.scale:
            genuine = recorder.heard(VEHICLE_ADDRESS, SHORE_ADDRESS, PriorityPacket)
            last = genuine[-1][1].seq if genuine else last  # twins at the next two seqs, sent again and again
            twins = [
                PriorityPacket(
                    (last + k) % 256, Priority.ROUTINE, Stream.KINEMATIC, rng.randbytes(29)
                ).encode()
                for k in (1, 2)
            ]
            sent += transmit(rig, VEHICLE_ADDRESS, SHORE_ADDRESS, twins)
        wait_for(lambda: link(rig)["ingest"]["verified"] > stats["verified"] + 1, 240, what="check-points")
        after = link(rig)["ingest"]
        delta = {k: after[k] - stats[k] for k in ("forged", "verified", "unverifiable", "replayed")}
        if delta["forged"] == 0:
            raise NotMeasured(f"{sent} twins sent, none heard by the shore")
        refused = delta["unverifiable"] + delta["replayed"]
        return Row(
            "forged twins at the vehicle's next seqs",
            f"{sent} twins in {TWINS_S:.0f} s",
            f"genuine check-points refused: {refused} (verified: {delta['verified']})",
            f"{delta['forged']} twins heard by the shore (refused: tag)",
            "test_verify: forged_priority_packet_with_a_genuine_seq",
        )
    finally:
        recorder.close()
        rig.close()


def clock_steps() -> list[Row]:
    """The agent's and the shore's wall clocks stepped by +-1 h and +-1 day: how long until a command
    reaches the vehicle and a check-point with the right time is accepted again. An agent's clock is
    measured from its step (its SYNCs fix it); the shore's from when it is set right after 2 minutes."""
    rig = Rig(300.0, SCALE, stepped_clocks=True, settle=0)
    rows = []
    try:
        wait_for(lambda: link(rig)["vehicles"]["rov1"]["checkpoint"], 120, what="a first check-point")
        for side in ("agent", "shore"):
            for step in (3600.0, -3600.0, 86400.0, -86400.0):
                rows.append(clock_step(rig, side, step))
    finally:
        rig.close()
    return rows


def clock_step(rig: Rig, side: str, step: float) -> Row:
    rig.stack.step_clock(side, step)
    if side == "shore":
        time.sleep(120 / rig.scale)  # wrong for two SYNC intervals
        rig.stack.step_clock(side, 0.0)
    recovered = recovery(rig)
    if side == "agent":  # set right again: itself a step back, healed before the next case
        rig.stack.step_clock(side, 0.0)
        recovery(rig)
    name = f"{'+' if step > 0 else '-'}1 {'h' if abs(step) == 3600 else 'day'}"
    outcome = (
        f"recovered in {recovered[0]:.0f} s, {recovered[1]} SYNC(s)"
        if recovered
        else "not recovered in 600 s"
    )
    return Row(
        f"clock step {name} on the {side}",
        "1",
        outcome,
        "a command answered and a check-point stamped right accepted after",
        "test_freshness: attack_4_*",
    )


def recovery(rig: Rig, limit_s: float = 600.0) -> tuple[float, int] | None:
    """Simulated seconds and SYNCs until a command posted now reaches the vehicle (a failed one is posted
    again) and a check-point stamped within 30 s of the true time is accepted; None if not within
    ``limit_s``."""
    started, syncs, true_start = time.monotonic(), link(rig)["counters"]["syncs"], time.time()
    pending = command(rig, {"command": "goto_depth", "depth": 1.0})
    done = {"command": False, "checkpoint": False}

    def healed() -> bool:
        nonlocal pending
        state = status(rig, pending)
        done["command"] = done["command"] or state in REACHED
        if state == "failed":
            pending = command(rig, {"command": "goto_depth", "depth": 1.0})
        checkpoint = link(rig)["vehicles"]["rov1"]["checkpoint"] or {}
        stamp = checkpoint.get("time", 0)
        done["checkpoint"] = done["checkpoint"] or (stamp > true_start and abs(stamp - time.time()) < 30)
        return all(done.values())

    try:
        wait_for(healed, limit_s / rig.scale, every=0.2, what="recovery")
    except TimeoutError:
        return None
    return sim_s(rig, time.monotonic() - started), link(rig)["counters"]["syncs"] - syncs


def key_rotation() -> list[Row]:
    """A rotation to a key the vehicle does not have, then cancelled; then one to the key it holds as
    ``next_key``."""
    rig = Rig(300.0, SCALE, mission=True, settle=0)
    try:
        start_mission(rig)
        offset = len(agent_log(rig))
        rig.http.post("/vehicles/1/key", json={}).raise_for_status()
        during = command(rig, {"command": "goto_depth", "depth": 1.0})
        time.sleep(ROTATION_S / rig.scale)
        log = agent_log(rig, offset)
        refused, lost = log.count("BadMac"), log.count("queued: LINK_LOST")
        reached = status(rig, during) in REACHED
        syncs = log.count("accepted (shore time")
        cancelled = rig.http.delete("/vehicles/1/key/pending").status_code
        after = command(rig, {"command": "goto_depth", "depth": 1.5})
        wait_for(lambda: status(rig, after) in REACHED, 120, what="a command after the cancel")
        if syncs == 0:
            raise NotMeasured("no SYNC reached the vehicle during the rotation")
        rows = [
            Row(
                "key rotation to a vehicle without the new key, then cancelled",
                f"{ROTATION_S:.0f} s",
                f"SYNCs refused by the vehicle: {refused}; link lost: {lost}; command during it answered: "
                f"{int(reached)}/1; cancel: HTTP {cancelled}, command after it answered: 1/1",
                f"{syncs} SYNCs accepted by the vehicle during the rotation",
                "test_key_rotation: a_waiting_rotation_can_be_cancelled",
            )
        ]
        rows.append(rotation_to_next_key(rig))
        return rows
    finally:
        rig.close()


def rotation_to_next_key(rig: Rig) -> Row:
    new = "4d" * 32
    rig.restart_agent(next_key=new)
    started, syncs = time.monotonic(), link(rig)["counters"]["syncs"]
    rig.http.post("/vehicles/1/key", json={"key": new}).raise_for_status()
    wait_for(
        lambda: rig.http.get("/vehicles/1").json()["key_rotation"] is None, 600 / rig.scale, what="confirmed"
    )
    took = sim_s(rig, time.monotonic() - started)
    return Row(
        "key rotation to a vehicle holding it as next_key",
        "1",
        f"confirmed in {took:.0f} s, {link(rig)['counters']['syncs'] - syncs} SYNC(s)",
        "the shore's rotation ended by a check-point signed with the new key",
        "test_key_rotation: the_new_key_is_used_once_a_checkpoint_says",
    )


def queued_commands(clients: int = 50) -> Row:
    """``clients`` API clients queueing commands as fast as the server answers, for a window."""
    rig = Rig(300.0, SCALE, mission=True, settle=0)
    try:
        start_mission(rig)
        before = per_minute(rig, WINDOW_S / rig.scale)
        deadline = time.monotonic() + WINDOW_S / rig.scale
        result: dict[int, int] = {}
        lock = threading.Lock()

        def client(_: int) -> None:
            with httpx.Client(
                base_url=str(rig.http.base_url), headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
            ) as http:
                while time.monotonic() < deadline:
                    code = http.post("/vehicles/1/commands", json={"command": "hold"}).status_code
                    with lock:
                        result[code] = result.get(code, 0) + 1

        polls, packets = polls_and_packets(rig)
        started = time.monotonic()
        with ThreadPoolExecutor(clients) as pool:
            list(pool.map(client, range(clients)))
        polls2, packets2 = polls_and_packets(rig)
        minutes = sim_s(rig, time.monotonic() - started) / 60
        if result.get(429, 0) == 0:
            raise NotMeasured(f"the queue never filled: {result}")
        return Row(
            f"{clients} clients queueing commands",
            f"{sum(result.values()):,} POSTs in {WINDOW_S:.0f} s",
            f"queued {result.get(202, 0)}, refused 429: {result.get(429, 0)}; polls/min {before[0]:.1f} "
            f"before, {(polls2 - polls) / minutes:.1f} during; vehicle packets/min {before[1]:.1f} before, "
            f"{(packets2 - packets) / minutes:.1f} during",
            "429s show the cap was reached",
            "test_fair_queue: polls_keep_their_share, full_queue_answers_429",
        )
    finally:
        rig.close()


def replayed_checkpoint() -> Row:
    """A genuine check-point recorded off the channel and replayed at once, then after the next one."""
    rig = Rig(300.0, SCALE, mission=True, attacker=True, recorder=True, settle=0)
    recorder = Recorder(rig.stack.pty("recorder"))
    try:
        start_mission(rig)
        heard = wait_for(
            lambda: recorder.heard(VEHICLE_ADDRESS, SHORE_ADDRESS, CheckpointPacket),
            120,
            what="a check-point",
        )
        frame, packet = heard[-1]
        stats = link(rig)["ingest"]
        sent = send_until_counted(rig, VEHICLE_ADDRESS, lambda: frame, lambda: refused_copies(rig))
        wait_for(
            lambda: link(rig)["vehicles"]["rov1"]["checkpoint"]["time"] > packet.time, 240, what="a newer one"
        )
        sent += send_until_counted(rig, VEHICLE_ADDRESS, lambda: frame, lambda: refused_copies(rig))
        after = link(rig)["ingest"]
        copies = (after["duplicates"] - stats["duplicates"]) + (after["replayed"] - stats["replayed"])
        items = rig.http.get("/packets", params={"limit": 1000, "type": "checkpoint"}).json()["items"]
        applied = sum(1 for p in items if p["body"]["time"] == packet.time and p["auth"] == "verified")
        back = int(link(rig)["vehicles"]["rov1"]["checkpoint"]["time"] <= packet.time)
        if copies == 0:
            raise NotMeasured(f"{sent} copies sent, none heard by the shore")
        return Row(
            "check-point replayed (at once, and after the next)",
            f"{sent} copies",
            f"accepted: {applied - 1}; shown pose went back: {back}",
            f"{copies} copies heard by the shore (duplicate or replay)",
            "test_replays_and_strangers: checkpoint_replayed_after_the_duplicate_window",
        )
    finally:
        recorder.close()
        rig.close()


def send_until_counted(
    rig: Rig, claim: int, make: Callable[[], bytes], counted: Callable[[], int], tries: int = 10
) -> int:
    """Frames from ``make``, sent from the attacker's modem as ``claim`` one at a time until the shore's
    ``counted`` rises (the channel is busy: a frame can collide); how many were sent."""
    before, sent = counted(), 0
    while sent < tries and counted() == before:
        sent += transmit(rig, claim, SHORE_ADDRESS, [make()])
    return sent


def refused_copies(rig: Rig) -> int:
    stats = link(rig)["ingest"]
    return int(stats["duplicates"] + stats["replayed"])


def strangers_junk(frames: int = 30, kept: int = 10) -> Row:
    """Junk frames from a modem address nobody registered, against a shore keeping ``kept`` of them."""
    rig = Rig(300.0, SCALE, mission=True, attacker=True, settle=0, server={"stranger_frames_kept": kept})
    try:
        start_mission(rig)
        rng = random.Random(6)
        sent = transmit(rig, STRANGER, SHORE_ADDRESS, [rng.randbytes(PACKET_SIZE) for _ in range(frames)])
        strangers = link(rig)["strangers"]
        heard = strangers["kept"] + strangers["dropped"]
        if heard == 0:
            raise NotMeasured(f"{sent} junk frames sent, none heard by the shore")
        return Row(
            "strangers' junk frames",
            f"{sent} frames",
            f"kept {strangers['kept']} (limit {kept}), dropped {strangers['dropped']}",
            f"{heard} heard by the shore",
            "test_replays_and_strangers: frames_from_unknown_addresses",
        )
    finally:
        rig.close()


def measured(attack: Callable[[], Row | list[Row]], name: str) -> list[Row]:
    """An attack's rows, or one saying why it measured nothing."""
    try:
        rows = attack()
    except (NotMeasured, TimeoutError) as exc:
        return [Row(name, "-", "-", f"NOT MEASURED: {exc}", "-")]
    return rows if isinstance(rows, list) else [rows]


ATTACKS: list[tuple[Callable[[], Row | list[Row]], str]] = [
    (lost_state, "lost state file + recorded SYNC and command"),
    (forged_restart_with_acking_modem, "forged priority packet + idle second modem ACKing"),
    (forged_twins, "forged twins at the vehicle's next seqs"),
    (clock_steps, "clock steps"),
    (key_rotation, "key rotation"),
    (queued_commands, "50 clients queueing commands"),
    (replayed_checkpoint, "check-point replayed"),
    (strangers_junk, "strangers' junk frames"),
]


def run() -> list[Row]:
    logging.getLogger("tacit").setLevel(logging.ERROR)  # the attacker's modem driver's own complaints
    rows: list[Row] = []
    for attack, name in ATTACKS:
        rows += measured(attack, name)
    return rows
