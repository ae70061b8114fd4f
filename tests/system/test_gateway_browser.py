"""The gateways on the dashboard, in real headless Chromium: ``tacit center`` (its own process, on a
nats-server of the test's own and a throwaway PostgreSQL database) and two gateways told where their
modems are, on the routing tests' stand-in modems, relaying two vehicles' check-points (rov1 heard by both,
better by gw1; rov2 by gw2 only). The gateway panel lists both, up, with their places, modems and
outboxes; the fleet table says each vehicle's gateway; the packet log each frame's gateways with their
SNR, the kept copy in bold; a gateway stopped turns silent, live. With a third vehicle and a team
mission, the 3D map opens fitted to the fleet and both gateways (300 m west, 600 m east), clear of its
panel, and draws them. Screenshots: test-artifacts/gateways.png, fleet-gateways-dashboard.png and
fleet-gateways-map.png (docs/screenshots/ holds copies)."""

from __future__ import annotations

import asyncio
import io
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
import numpy as np
import pytest
from PIL import Image
from playwright.sync_api import sync_playwright

from launch.processes import stop
from launch.split import throwaway_database as postgres_database
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.subjects import Place
from server.screens.fleet import GATEWAYS
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
    port, map_port = free_port(), free_port()
    env = {
        **os.environ, "TACIT_WRITE_TOKENS": TOKEN, "TACIT_ORIGIN": "40.4862,-74.4518", "TACIT_METRICS_PORT": "0",
        "TACIT_GATEWAY_TIMEOUT": "4", "TACIT_ROUTING_DWELL": "0", "PYTHONUNBUFFERED": "1",
    }  # fmt: skip
    try:
        with postgres_database(postgres_server) as url, (folder / "center.log").open("w") as log:
            proc = subprocess.Popen(
                [sys.executable, "-m", "tacit.cli", "center", "--nats", broker.url, "--insecure", "--database-url", url,
                 "--port", str(port), "--map-port", str(map_port)],
                stdout=log, stderr=subprocess.STDOUT, env=env, text=True,
            )  # fmt: skip
            api = f"http://127.0.0.1:{port}"
            try:
                http = httpx.Client(base_url=api, headers={"Authorization": f"Bearer {TOKEN}"})
                until_answers(http, proc, folder / "center.log")
                gateways = Gateways(folder, broker.url)
                try:
                    yield {"api": api, "http": http, "gateways": gateways, "broker": broker,
                           "map": f"http://127.0.0.1:{map_port}", "keys": register(http)}  # fmt: skip
                finally:
                    gateways.close()
            finally:
                stop(proc)
    finally:
        broker.stop()


FLEET = (("rov1", 2, 0.0), ("rov2", 3, 30.0), ("rov3", 4, 60.0))  # name, modem address, m east of the origin


def register(http: httpx.Client) -> dict[int, bytes]:
    """The three vehicles, each at its home, reporting every 5 minutes; their keys by modem address."""
    keys = {}
    for name, address, east in FLEET:
        body = {"name": name, "address": address, "home": [0.0, east], "report_interval": 300.0}
        answer = http.post("/api/v1/vehicles", json=body)
        assert answer.status_code == 201, answer.text
        keys[address] = bytes.fromhex(answer.json()["key"])
    return keys


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


def test_both_screens_show_three_vehicles_and_two_gateways(center: dict[str, Any]) -> None:
    http, gateways, keys = center["http"], center["gateways"], center["keys"]
    # one check-point each: its registered report interval (300 s) stands for its report gap, so none is
    # overdue while the screens are looked at
    gateways.heard(2, keys[2], 1, 0.0, {"gw1": 14.0, "gw2": 5.0})
    gateways.heard(3, keys[3], 1, 30.0, {"gw2": 15.0})
    gateways.heard(4, keys[4], 1, 60.0, {"gw2": 11.0, "gw1": 3.0})
    team = {"name": "survey", "vehicles": [{"vehicle": "rov2"}, {"vehicle": "rov3"}], "spacing": 10.0,
            "depth": 2.0, "area": {"south": 10.0, "north": 50.0, "west": 20.0, "east": 70.0}}  # fmt: skip
    assert http.post("/api/v1/teams", json=team).status_code == 201
    until(lambda: all(v["reported"] for v in http.get("/api/v1/fleet").json()["vehicles"]))
    ARTIFACTS.mkdir(exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        errors: list[str] = []
        dashboard = browser.new_page(viewport={"width": 1400, "height": 1800}, bypass_csp=True)
        dashboard.on("pageerror", lambda e: errors.append(str(e)))
        dashboard.goto(f"{center['api']}/#token={TOKEN}")
        dashboard.wait_for_function(
            "[...document.querySelectorAll('#fleet tbody tr')].filter(r => r.textContent.includes('ago')).length === 3",
            timeout=LONG,
        )  # fmt: skip
        dashboard.wait_for_function(
            "document.querySelectorAll('#gateways tbody tr').length === 2", timeout=LONG
        )
        swatches = dashboard.evaluate(  # in one call: the table is drawn again every few seconds
            "[...document.querySelectorAll('#gateways tbody tr td:first-child .swatch')].map(e => getComputedStyle(e).backgroundColor)"
        )
        assert len(swatches) == 2 and len(set(swatches)) == 2  # each gateway its own colour

        # the map in the dashboard's frame: fitted to the fleet and both gateways, clear of its panel
        frame = dashboard.frame_locator("#map")
        frame.locator(".mantine-Paper-root").first.wait_for(timeout=LONG)  # the map's panel
        dashboard.locator("#map").scroll_into_view_if_needed()
        canvas, panel = (
            frame.locator("canvas").first.bounding_box(),
            frame.locator(".mantine-Paper-root").first,
        )
        deadline, found = time.monotonic() + LONG / 1000, []
        while len(found) < 2 and time.monotonic() < deadline:  # the scene comes over the websocket, fitted
            time.sleep(1.0)
            left = panel.bounding_box()
            assert canvas is not None and left is not None
            shot = np.asarray(Image.open(io.BytesIO(dashboard.screenshot(clip=canvas))).convert("RGB"))
            found = gateway_boxes(shot.astype(int)[:, : int(left["x"] - canvas["x"])])  # left of the panel
        for close in frame.locator(".mantine-Notification-closeButton").all():
            close.click()  # software rendering's notice
        frame.locator(".mantine-Notification-root").first.wait_for(state="detached", timeout=LONG)
        dashboard.screenshot(path=str(ARTIFACTS / "fleet-gateways-map.png"), clip=canvas)
        dashboard.screenshot(path=str(ARTIFACTS / "fleet-gateways-dashboard.png"), full_page=True)
        assert len(found) == 2, f"both gateways on the map's first view, clear of its panel: {found}"
        browser.close()
    assert errors == []


def gateway_boxes(image: np.ndarray) -> list[tuple[float, float]]:
    """The centres (x, y in pixels) of the gateways' boxes on a screenshot: blobs of 30 pixels or more of
    the two gateways' colours (``server.screens.fleet.GATEWAYS``) as lit: their hue (the share of each of
    red, green and blue), strongly coloured."""
    centres = []
    strong = image.max(axis=2) - image.min(axis=2) > 60
    hue = image / np.maximum(image.sum(axis=2, keepdims=True), 1)
    for colour in GATEWAYS[:2]:
        rgb = np.array([int(colour[i : i + 2], 16) for i in (1, 3, 5)])
        ys, xs = np.nonzero(strong & (np.abs(hue - rgb / rgb.sum()).max(axis=2) < 0.06))
        if len(xs) >= 30:
            centres.append((float(np.median(xs)), float(np.median(ys))))
    return centres


def test_the_gateways_and_each_vehicles_gateway_on_the_dashboard(center: dict[str, Any]) -> None:
    gateways, keys = center["gateways"], center["keys"]
    for seq in (2, 3):
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
        # the chosen vehicle's link (rov1's, the first): how each gateway hears it, its own gateway first
        page.wait_for_function(
            "document.querySelector('#link-stats').textContent.includes('via gw1')", timeout=LONG
        )
        link = page.eval_on_selector_all("#link-stats th", "ths => ths.map(th => th.textContent)")
        assert link[link.index("last heard") + 3 : link.index("last heard") + 5] == ["via gw1", "via gw2"], (
            link
        )
        # a vehicle registered now and never heard: starting (its first report is not due), not overdue
        body = {"name": "rov4", "address": 5, "home": [0.0, 90.0]}
        assert center["http"].post("/api/v1/vehicles", json=body).status_code == 201
        page.wait_for_function(
            "document.querySelector(\"#fleet tr[data-name='rov4'] td.state\")?.textContent.includes('waiting for its first report')",
            timeout=LONG,
        )  # fmt: skip
        assert "overdue" not in (page.get_attribute("#fleet tr[data-name='rov4']", "class") or "")

        # an outage: gw1's modem goes on hearing; back, it tells how long it lasted and what waited
        center["broker"].stop()
        until(lambda: gateways.gateways["gw1"].down_since is not None)
        for seq in (4, 5, 6):
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
