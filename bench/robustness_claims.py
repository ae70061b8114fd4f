"""A gateway's word against what the center can check (``bench_robustness.py --claims``).

Each row gets a fresh scene: a real nats-server with the accounts ``tacit broker-config`` writes
(gateways ``ship`` and ``buoy``), the center (``tacit center``'s app: API, consumers, dispatcher) on a
SQLite file, and both gateways on their own credentials, with no modem (a command is stored and never
sent). The attacker holds one gateway's credentials: whatever that gateway's outbox holds goes up as its
frames and events. The vehicle is the test's key: its check-points are signed as the agent signs them.
Each row says what shows the attack reached the center before it counts what changed; a row that
cannot show it is ``NOT MEASURED`` and the command exits 1. Slots: ``SLOT`` s, two gateways.
"""

from __future__ import annotations

import os
import re
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
from fastapi.testclient import TestClient
from robustness_system import Row

from launch.broker import Secured, free_port
from server.app import create_app
from server.backhaul.center import serve
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.relay import RelayIngest
from server.core.config import Settings
from server.core.db import migrate
from tacit import auth
from tacit.packets import CheckpointPacket, MissionState

TOKEN = "claims-operator"
OP = {"Authorization": f"Bearer {TOKEN}"}
ADDRESS = 2
SLOT = 0.8  # s: each gateway's TDMA slot (two gateways: a gateway's slot comes every 1.6 s)
TEST = "test_claims"


class Scene:
    """The broker, the center's app and both gateways; ``heard`` and ``event`` are what a gateway's
    outbox publishes (its modem's frames, its reports)."""

    def __init__(self, folder: Path, client: TestClient, server: Secured, metrics: int) -> None:
        self.client, self.metrics, self.seq, self.key = client, metrics, 0, b""
        self.outboxes = {name: Outbox(folder / f"{name}.db", name) for name in ("ship", "buoy")}
        self.gateways = [
            Gateway(outbox, server.url, heartbeat=0.2, auth=server.credentials(f"gateway-{name}"))
            for name, outbox in self.outboxes.items()
        ]

    def register(self) -> None:
        answer = self.client.post("/api/v1/vehicles", json={"name": "rov1", "address": ADDRESS}, headers=OP)
        self.key = bytes.fromhex(answer.json()["key"])

    def checkpoint(self, at: float, last_command: int = 0) -> bytes:
        self.seq += 1
        cp = CheckpointPacket(
            seq=self.seq, time=int(at), state=MissionState.PREPROGRAMMED, last_command=last_command
        )
        return auth.sign_checkpoint(cp, self.key, 1, ADDRESS, [])

    def heard(self, snr: dict[str, float], at: float | None = None, last_command: int = 0) -> None:
        at = time.time() if at is None else at
        data = self.checkpoint(at, last_command)
        for name, value in snr.items():
            self.outboxes[name].add_frame(ADDRESS, 0, data, rate=0, snr_in=value, at=at)

    def get(self, path: str) -> Any:
        return self.client.get(f"/api/v1{path}", headers=OP).json()

    def gateway(self, name: str) -> dict[str, Any]:
        return next(g for g in self.get("/gateways") if g["name"] == name)

    def route(self) -> dict[str, Any]:
        return dict(self.get("/routing")[0])

    def last_heard(self) -> float | None:
        return self.get("/link")["vehicles"]["rov1"]["last_heard"]

    def refused(self, reason: str) -> int:
        text = httpx.get(f"http://127.0.0.1:{self.metrics}/metrics").text
        found = re.search(rf'tacit_backhaul_refused_total{{reason="{reason}"}} (\d+)', text)
        return int(found.group(1)) if found else 0

    def dispatches(self, command: int) -> list[Any]:
        return self.client.app.state.shore.routing.dispatches(command)  # type: ignore[attr-defined]

    def command(self) -> int:
        return int(
            self.client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=OP).json()["id"]
        )

    def status(self, command: int) -> str:
        return str(self.get(f"/commands/{command}")["status"])

    def on_ship(self) -> int:
        """The vehicle heard by both, better by the ship; a command dispatched through it and stored."""
        self.register()
        self.heard({"ship": 20.0, "buoy": 12.0})
        until(lambda: self.route()["gateway"] == "ship")
        command = self.command()
        until(lambda: [d.state for d in self.dispatches(command)] == ["stored"])
        return command


@contextmanager
def scene(**changes: Any) -> Iterator[Scene]:
    with tempfile.TemporaryDirectory() as folder:
        server = Secured(Path(folder) / "broker", ["ship", "buoy"])
        server.start()
        url, metrics = f"sqlite:///{folder}/center.db", free_port()
        migrate(url)
        settings = Settings(
            database_url=url, map_enabled=False, write_tokens=[TOKEN], routing_window=60.0, routing_dwell=0.0,
            gateway_timeout=5.0, dispatch_receipt=1.5, tdma_slot=SLOT, tdma_guard=0.05, command_attempts=2,
            metrics_port=metrics, **changes,
        )  # fmt: skip
        app = create_app(
            settings, RelayIngest, [lambda shore: serve(shore, server.url, auth=server.credentials("center"))]
        )
        try:
            with TestClient(app) as client:
                here = Scene(Path(folder), client, server, metrics)
                assert client.portal is not None
                for gateway in here.gateways:
                    client.portal.call(gateway.start)
                try:
                    yield here
                finally:
                    for gateway in here.gateways:
                        client.portal.call(gateway.stop)
        finally:
            server.stop()


def until(condition: Callable[[], object], timeout: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def foreign_reports(cases: int) -> Row:
    """The buoy reports the ship's command sent, acked, acked and final, ``cases`` times."""
    with scene(gateway_faulty_slots=1000) as s:
        command = s.on_ship()
        dispatch = s.dispatches(command)[0].id
        for i in range(cases):
            outcome = {"outcome": "sent", "attempt": 1} if i % 2 == 0 else {"outcome": "acked", "final": True}
            s.outboxes["buoy"].add_event("attempt", {"command": dispatch, **outcome})
        counted = until(lambda: s.gateway("buoy")["foreign_reports"] == cases)
        moved = int(s.status(command) != "queued") + int(s.dispatches(command)[0].state != "stored")
    reached = f"{cases} counted on the buoy" if counted else "NOT MEASURED: the reports were not counted"
    return Row("another gateway's command reported acked", f"{cases}", f"{moved} moved", reached, TEST)


def random_frames(cases: int) -> Row:
    """Random bytes as the vehicle's frames through the buoy, at a claimed 30 dB."""
    with scene() as s:
        s.register()
        s.heard({"ship": 12.0})
        until(lambda: s.route()["gateway"] == "ship" and s.last_heard() is not None)
        heard = s.last_heard()
        for _ in range(cases):
            s.outboxes["buoy"].add_frame(ADDRESS, 0, os.urandom(32), rate=0, snr_in=30.0, at=time.time() + 60)
        stored = until(lambda: s.gateway("buoy")["frames"] == cases)
        s.client.app.state.shore.routing.update()  # type: ignore[attr-defined]
        route = s.route()
        scored = sum(h["frames"] for h in route["heard"] if h["gateway"] == "buoy")
        outcome = f"vehicle on {route['gateway']}, buoy scored by {scored} frames, last heard " + (
            "unmoved" if s.last_heard() == heard else "MOVED"
        )
    reached = f"{cases} stored" if stored else "NOT MEASURED: the frames were not stored"
    return Row("random bytes as a vehicle's frames at 30 dB", f"{cases}", outcome, reached, TEST)


def future_frames(cases: int) -> Row:
    """Genuine check-points stamped 30 days ahead, through the ship."""
    with scene() as s:
        s.register()
        s.heard({"ship": 12.0})
        until(lambda: s.last_heard() is not None)
        heard, before = s.last_heard(), s.gateway("ship")["frames"]
        later = time.time() + 30 * 86400
        for _ in range(cases):
            s.outboxes["ship"].add_frame(ADDRESS, 0, s.checkpoint(later), rate=0, snr_in=12.0, at=later)
        refused = until(lambda: s.refused("future") == cases)
        stored = s.gateway("ship")["frames"] - before
        outcome = f"{stored} stored, last heard " + ("unmoved" if s.last_heard() == heard else "MOVED")
    reached = f"{cases} refused (future)" if refused else "NOT MEASURED: no refusal counted"
    return Row("frames stamped 30 days ahead", f"{cases}", outcome, reached, TEST)


def _found_faulty(s: Scene, command: int, start: float, how: Callable[[float], str]) -> str:
    """Whether the ship is found faulty (``how`` it was, given the slots it took since ``start``) and the
    command sent again through the buoy."""
    found = until(lambda: s.gateway("ship")["faulty"] != "")
    slots = (time.monotonic() - start) / (2 * SLOT)
    again = until(lambda: any(d.gateway == "buoy" for d in s.dispatches(command)))
    if not found:
        return "NOT FOUND FAULTY"
    return f"faulty {how(slots)} command " + ("sent again through the buoy" if again else "NOT SENT AGAIN")


def refuted_ack() -> Row:
    """The ship says the vehicle's modem ACKed the command; the vehicle's check-points through the buoy
    say it never arrived."""
    with scene() as s:
        command = s.on_ship()
        dispatch = s.dispatches(command)[0].id
        s.outboxes["ship"].add_event("attempt", {"command": dispatch, "outcome": "sent", "attempt": 1})
        s.outboxes["ship"].add_event("attempt", {"command": dispatch, "outcome": "acked", "final": True})
        claimed = until(lambda: s.status(command) == "acknowledged")
        start = time.monotonic()
        s.heard({"buoy": 12.0}, at=time.time() + 6, last_command=0)  # made after the claimed ACK
        outcome = _found_faulty(
            s,
            command,
            start,
            lambda slots: f"within {slots:.1f} of its slots; vehicle on {s.route()['gateway']},",
        )
    reached = "the command acknowledged on its word" if claimed else "NOT MEASURED: the claim did not count"
    return Row("a gateway's ACK the vehicle refutes", "1", outcome, reached, TEST)


def held_command() -> Row:
    """The ship stores the command and says nothing more."""
    with scene(gateway_faulty_slots=3) as s:
        command = s.on_ship()
        start = time.monotonic()
        outcome = _found_faulty(s, command, start, lambda slots: f"after {slots:.1f} of its slots (N = 3);")
    return Row("a gateway holding a command without a word", "1", outcome, "its receipt: stored", TEST)


def run(cases: int = 20) -> list[Row]:
    return [foreign_reports(cases), random_frames(cases), future_frames(cases), refuted_ack(), held_command()]
