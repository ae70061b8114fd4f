"""The gateways on the dashboard, in real headless Chromium: ``tacit center`` (its own process, on a
nats-server of the test's own and a throwaway PostgreSQL database) and two gateways told where their
modems are, on the routing tests' stand-in modems, relaying two vehicles' check-points (rov1 heard by both,
better by gw1; rov2 by gw2 only). The gateway panel lists both, up, with their places, modems and
outboxes; the fleet table says each vehicle's gateway; the packet log each frame's gateways with their
SNR, the kept copy in bold; a gateway stopped turns silent, live. Screenshot: test-artifacts/gateways.png
(docs/screenshots/gateways.png is one)."""

from __future__ import annotations

import asyncio
import os
import re
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import sync_playwright

from launch.processes import stop
from launch.split import throwaway_database as postgres_database
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.subjects import Place
from tacit import auth
from tacit.packets import CheckpointPacket, MissionState
from tests.integration.server.routing.test_choice import StandInModem, Vehicle
from tests.support.nats import NATS_SERVER, NatsServer, free_port
from tests.system.test_browser import ARTIFACTS, CHROMIUM, FLAGS

pytestmark = pytest.mark.skipif(not Path(NATS_SERVER).exists(), reason="nats-server is not installed")

TOKEN = "gateway-screens-operator"
LONG = 60_000  # ms
PLACES = {"gw1": (Place(0.0, -300.0, 1.0), 1), "gw2": (Place(0.0, 600.0, 1.0), 101)}


class Gateways:
    """Two gateways on stand-in modems, in an event loop of their own; ``heard`` puts a vehicle's signed
    check-point in the outboxes of the gateways that hear it, as their modems would."""

    def __init__(self, folder: Path, url: str) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.outboxes = {name: Outbox(folder / f"{name}.db", name) for name in PLACES}
        self.gateways = {
            name: Gateway(self.outboxes[name], url, StandInModem(name, Vehicle()), heartbeat=1.0,  # type: ignore[arg-type]
                          place=place, address=address)
            for name, (place, address) in PLACES.items()
        }  # fmt: skip
        for name in PLACES:
            self.call(self.gateways[name].start())

    def call(self, work: Any) -> None:
        asyncio.run_coroutine_threadsafe(work, self.loop).result(timeout=30)

    def heard(self, address: int, key: bytes, seq: int, east: float, snr: dict[str, float]) -> None:
        cp = CheckpointPacket(
            seq=seq, time=int(time.time()), state=MissionState.PREPROGRAMMED, east=east, depth=2.0
        )
        frame = auth.sign_checkpoint(cp, key, 1, address, [])
        for name, value in snr.items():
            self.outboxes[name].add_frame(address, 0, frame, rate=0, snr_in=value, at=time.time())

    def close(self) -> None:
        for gateway in self.gateways.values():
            if gateway.nc is not None:
                self.call(gateway.stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout=10)


@pytest.fixture(scope="module")
def center(tmp_path_factory: pytest.TempPathFactory, postgres_server: str) -> Iterator[dict[str, Any]]:
    folder = tmp_path_factory.mktemp("gateway-screens")
    broker = NatsServer(folder)
    broker.start()
    port = free_port()
    env = {
        **os.environ, "TACIT_WRITE_TOKENS": TOKEN, "TACIT_ORIGIN": "40.4862,-74.4518", "TACIT_METRICS_PORT": "0",
        "TACIT_GATEWAY_TIMEOUT": "4", "TACIT_ROUTING_DWELL": "0", "PYTHONUNBUFFERED": "1",
    }  # fmt: skip
    try:
        with postgres_database(postgres_server) as url, (folder / "center.log").open("w") as log:
            proc = subprocess.Popen(
                [sys.executable, "-m", "tacit.cli", "center", "--nats", broker.url, "--insecure", "--database-url", url,
                 "--port", str(port), "--no-map"],
                stdout=log, stderr=subprocess.STDOUT, env=env, text=True,
            )  # fmt: skip
            api = f"http://127.0.0.1:{port}"
            try:
                http = httpx.Client(base_url=api, headers={"Authorization": f"Bearer {TOKEN}"})
                until_answers(http, proc, folder / "center.log")
                gateways = Gateways(folder, broker.url)
                try:
                    yield {"api": api, "http": http, "gateways": gateways, "broker": broker}
                finally:
                    gateways.close()
            finally:
                stop(proc)
    finally:
        broker.stop()


def until(condition: Any, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def until_answers(http: httpx.Client, proc: subprocess.Popen[str], log: Path) -> None:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"tacit center exited: {log.read_text()[-2000:]}"
        try:
            if http.get("/api/v1/health").status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise AssertionError(f"tacit center did not answer: {log.read_text()[-2000:]}")


def test_the_gateways_and_each_vehicles_gateway_on_the_dashboard(center: dict[str, Any]) -> None:
    http, gateways = center["http"], center["gateways"]
    keys = {}
    for name, address, east in (("rov1", 2, 0.0), ("rov2", 3, 30.0)):
        answer = http.post("/api/v1/vehicles", json={"name": name, "address": address, "home": [0.0, east]})
        assert answer.status_code == 201, answer.text
        keys[address] = bytes.fromhex(answer.json()["key"])
    for seq in (1, 2):
        gateways.heard(2, keys[2], seq, 0.0, {"gw1": 14.0, "gw2": 5.0})
        gateways.heard(3, keys[3], seq, 30.0, {"gw2": 15.0})

    ARTIFACTS.mkdir(exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        errors: list[str] = []
        page = browser.new_page(viewport={"width": 1400, "height": 1400}, bypass_csp=True)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(f"{center['api']}/#token={TOKEN}")
        page.wait_for_function(
            "[...document.querySelectorAll('#gateways tbody tr')].filter(r => r.textContent.includes('up for')).length === 2",
            timeout=LONG,
        )  # fmt: skip
        assert page.is_visible("#gateways-card")
        gw1 = page.text_content("#gateways tr[data-name='gw1']") or ""
        assert "N 0, E -300 m" in gw1 and "address 1" in gw1 and "ready" in gw1 and "W" in gw1  # lat/lon too
        page.wait_for_function(
            "document.querySelector(\"#fleet tr[data-name='rov1'] .gw-col\")?.textContent.includes('gw1') && "
            "document.querySelector(\"#fleet tr[data-name='rov2'] .gw-col\")?.textContent.includes('gw2')",
            timeout=LONG,
        )
        assert page.is_visible("#fleet tr[data-name='rov1'] .gw-col")  # the column shows with gateways
        page.wait_for_function(
            "document.querySelector(\"#gateways tr[data-name='gw1'] .gw-vehicles\").textContent.includes('rov1')",
            timeout=LONG,
        )
        # a frame both heard: both copies with their SNR, the kept one (gw1's, the best) in bold
        page.wait_for_function(
            "[...document.querySelectorAll('#packets td.heard')].some(td => td.querySelector('.copy.kept')?.textContent === 'gw1 14.0' && td.textContent.includes('gw2 5.0'))",
            timeout=LONG,
        )  # fmt: skip

        # an outage: gw1's modem goes on hearing; back, it tells how long it lasted and what waited
        center["broker"].stop()
        until(lambda: gateways.gateways["gw1"].down_since is not None)
        for seq in (3, 4, 5):
            gateways.heard(2, keys[2], seq, 0.0, {"gw1": 13.0})
        center["broker"].start()
        page.wait_for_function(
            "document.querySelector(\"#gateways tr[data-name='gw1']\").textContent.includes('waiting when it came back')",
            timeout=LONG,
        )  # fmt: skip
        backlog = re.search(
            r"(\d+) waiting when it came back", page.text_content("#gateways tr[data-name='gw1']") or ""
        )
        assert backlog and int(backlog.group(1)) >= 3  # the three frames (and any command outcomes)

        gateways.call(gateways.gateways["gw2"].stop())  # its heartbeats stop: silent, live on the page
        page.wait_for_function(
            "document.querySelector(\"#gateways tr[data-name='gw2']\").textContent.includes('silent for')",
            timeout=LONG,
        )
        assert "silent" in (page.get_attribute("#gateways tr[data-name='gw2']", "class") or "")
        page.locator("#gateways-card").screenshot(path=str(ARTIFACTS / "gateways.png"))
        page.screenshot(path=str(ARTIFACTS / "gateways-dashboard.png"), full_page=True)
        browser.close()
    assert errors == []
