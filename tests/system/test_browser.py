"""The operator's screens in real headless Chromium (Debian's) against the running demo: the demo's
link signs in at once (and the token leaves the address bar), a wrong token says so, observers cannot
write (dashboard or map), the map's panel sends only once signed in as an operator and its command
moves the simulated vehicle, the dashboard refuses a blank field before sending and takes a 270 deg
bearing, its result line follows the command's status, and after a reload the control row and command
histories come back from the API. Screenshots are saved in test-artifacts/ (the README's come from here)."""

from __future__ import annotations

import io
import json
import math
import re
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image
from playwright.sync_api import sync_playwright

from tests.conftest import tacit_process

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"
CHROMIUM = "/usr/bin/chromium"
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--use-gl=swiftshader",
    "--enable-unsafe-swiftshader",
]


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory):
    data = tmp_path_factory.mktemp("demo")
    with tacit_process(
        "demo",
        "--headless",
        "--time-scale",
        "4",
        "--data-dir",
        str(data),
        "--port",
        "18311",
        "--map-port",
        "18391",
    ) as (proc, info):
        yield info


def checkpoint(info: dict) -> dict | None:
    link = httpx.get(info["api_url"] + "/link", headers={"Authorization": f"Bearer {info['token']}"}).json()
    return link["vehicles"]["rov1"]["checkpoint"]


MAP_TOKEN = "div.mantine-Flex-root:has(label:text-is('Token')) input"


def test_dashboard_and_map_in_a_real_browser(demo: dict) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    deadline = time.monotonic() + 60
    while checkpoint(demo) is None and time.monotonic() < deadline:
        time.sleep(0.5)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        errors: list[str] = []
        # the page's CSP forbids eval: wait_for_function's predicates (strings of JavaScript) need it to poll
        dashboard = browser.new_page(viewport={"width": 1400, "height": 1600}, bypass_csp=True)
        dashboard.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        dashboard.on("pageerror", lambda e: errors.append(str(e)))
        dashboard.goto(demo["sign_in_url"])  # the demo's link: the token in the fragment signs in at once
        dashboard.wait_for_function("document.querySelector('#role').textContent === 'operator'")
        assert "token" not in dashboard.url and dashboard.url.endswith("/")  # cleared from the address bar
        assert dashboard.locator("#sign-out").is_visible() and not dashboard.locator("#sign-in").is_visible()
        speed = dashboard.locator("#f-speed")  # blank: the vehicle's cruise speed (0 would read as "stop")
        assert speed.input_value() == "" and speed.get_attribute("placeholder") == "default (cruise)"
        assert dashboard.locator("label:has(#angle-mode)").text_content().strip().startswith("Angle is")
        assert dashboard.locator("label:has(#f-angle)").text_content().strip().startswith("Turn from heading")

        map_page = browser.new_page(viewport={"width": 1400, "height": 900})
        map_page.goto(demo["map_url"])
        map_page.get_by_text("Watching only").first.wait_for(timeout=90_000)
        assert map_page.get_by_role("button", name="Send").is_disabled()  # not signed in: watch only
        map_page.locator(MAP_TOKEN).first.fill(demo["token"])
        map_page.keyboard.press("Tab")
        map_page.get_by_role("button", name="Sign in").click()
        map_page.get_by_text("commands enabled").first.wait_for(timeout=10_000)
        assert map_page.locator(MAP_TOKEN).first.input_value() == ""  # the token does not stay on screen
        before = checkpoint(demo)
        map_page.get_by_role("button", name="Send").click()
        # reaching "acknowledged" means that state or a later one (the panel may skip past it between repaints)
        map_page.get_by_text(
            re.compile(r"Command #\d+ seq \d+: (acknowledged|executing|executed)")
        ).first.wait_for(timeout=90_000)
        map_page.get_by_text(re.compile(r"#\d+ rov1 move 10 m, turn \+0°.*\d\d:\d\d:\d\dZ")).first.wait_for()
        time.sleep(2)  # the map opens top-down: this is what an operator sees first
        # headless Chromium renders WebGL in software, and viser says so in a notice over the scene
        for close in map_page.locator(".mantine-Notification-closeButton").all():
            close.click()
        map_page.screenshot(path=str(ARTIFACTS / "map.png"))

        deadline = time.monotonic() + 60
        moved = 0.0
        while moved < 3.0 and time.monotonic() < deadline:
            after = checkpoint(demo)
            moved = math.hypot(after["north"] - before["north"], after["east"] - before["east"])
            time.sleep(1.0)
        assert moved >= 3.0, "the vehicle did not move after the map's command"

        # the dashboard: a blank field is refused in the page; a bearing of 270 goes through
        sent_before = len(httpx.get(demo["api_url"] + "/vehicles/1/commands", headers=auth(demo)).json())
        dashboard.fill("#f-distance", "")
        dashboard.click("#send")
        dashboard.wait_for_function(
            "document.querySelector('#command-result').textContent.includes('Distance is required')"
        )
        assert (
            len(httpx.get(demo["api_url"] + "/vehicles/1/commands", headers=auth(demo)).json()) == sent_before
        )
        dashboard.fill("#f-distance", "6")
        dashboard.select_option("#angle-mode", "bearing")
        dashboard.fill("#f-angle", "270")
        dashboard.click("#send")
        dashboard.wait_for_function(
            "/bearing 270°.*: (queued|sent|acknowledged|executing|executed)/.test(document.querySelector('#command-result').textContent)"
        )
        dashboard.wait_for_function(
            "/: (acknowledged|executing|executed)/.test(document.querySelector('#command-result').textContent)",
            timeout=90_000,
        )  # fmt: skip  (the line follows the command's status)
        dashboard.wait_for_function(
            "[...document.querySelectorAll('#packets td')].some(td => td.textContent === 'priority')",
            timeout=60_000,
        )
        dashboard.wait_for_function("state.timeline.some(e => e.kind.startsWith('p'))")
        # priority packets' trust, shown pending, turns verified live when a check-point covers them (not
        # every one: a packet whose ACK the vehicle missed is never covered, and turns unverifiable)
        pending = dashboard.wait_for_function(
            "(ids => ids.length ? ids : null)(state.packets.filter(p => p.type === 'priority' && p.auth === 'pending').map(p => p.id))",
            timeout=60_000,
        ).json_value()
        dashboard.wait_for_function(
            f"{json.dumps(pending)}.some(id => document.querySelector(`#packets tr[data-id=\"${{id}}\"] td.trust`)?.textContent === 'verified')",
            timeout=60_000,
        )
        dashboard.wait_for_function(
            "state.series.some(p => p.packet !== undefined && p.trust === 'verified')"
        )
        assert "forged" in dashboard.text_content("#trust-legend")
        dashboard.wait_for_function(
            "document.querySelector('#vehicle-state').textContent.includes('Predicted now')"
        )
        assert "UTC" in dashboard.text_content("#vehicle-state")
        assert dashboard.text_content("#state-hint").strip()  # what the state label means, on screen
        assert "airtime: polls" in dashboard.text_content("#link-stats")
        assert "version" in dashboard.text_content("#link-stats tr:has(th:text-is('key'))")  # or a rotation
        dashboard.screenshot(path=str(ARTIFACTS / "dashboard.png"), full_page=True)

        dashboard.reload()  # after a reload the control row and the commands' history come from the API
        dashboard.wait_for_function("state.timeline.some(e => e.kind === 'ctl')")
        dashboard.wait_for_function(
            "document.querySelector('#commands td.history')?.textContent.includes('queued')"
        )
        browser.close()
    assert errors == []


def drawn(png: bytes) -> float:
    """The share of an image's pixels that differ from its commonest colour (0: blank)."""
    pixels = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).reshape(-1, 3)
    _colours, counts = np.unique(pixels, axis=0, return_counts=True)
    return 1.0 - counts.max() / len(pixels)


def test_the_dashboard_frames_the_map_and_the_frame_draws(demo: dict) -> None:
    """Its own Content-Security-Policy in force (no bypass): the frame loads the map, and the map's canvas
    inside it draws the scene (the water, the axes, the vehicle), not a blank or a blocked page."""
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        blocked: list[str] = []
        page = browser.new_page(viewport={"width": 1400, "height": 1600})
        page.on("console", lambda m: blocked.append(m.text) if "Content Security Policy" in m.text else None)
        page.goto(demo["sign_in_url"])
        canvas = page.frame_locator("#map").locator("canvas").first
        canvas.wait_for(timeout=60_000)
        frame = page.locator("#map")
        frame.scroll_into_view_if_needed()
        deadline, share = time.monotonic() + 30, 0.0
        while share < 0.02 and time.monotonic() < deadline:  # the scene arrives over the map's websocket
            time.sleep(0.5)
            box = canvas.bounding_box()  # in the page: the canvas is what the frame shows of the map
            assert box is not None
            share = drawn(page.screenshot(clip=box))
        assert share >= 0.02, f"the map's frame draws nothing ({share:.3%} of its pixels)"
        browser.close()
    assert blocked == []


def auth(demo: dict) -> dict:
    return {"Authorization": f"Bearer {demo['token']}"}


def test_sign_in_says_what_to_do_and_observers_cannot_write(demo: dict) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        page = browser.new_page(viewport={"width": 1400, "height": 900}, bypass_csp=True)
        page.goto(demo["dashboard_url"])
        assert page.locator("#welcome").is_visible() and not page.locator("#main").is_visible()
        assert "tacit demo" in page.text_content("#welcome")
        page.screenshot(path=str(ARTIFACTS / "sign-in.png"))
        page.fill("#token", "not-a-token")
        page.click("#login button")
        page.wait_for_function("!document.querySelector('#login-error').hidden")
        assert "not accepted" in page.text_content("#login-error")
        assert page.text_content("#role") == "not signed in"
        assert page.locator("#sign-in").is_visible() and not page.locator("#sign-out").is_visible()

        observer = browser.new_page(bypass_csp=True)
        observer.goto(demo["observer_url"])
        observer.wait_for_function("document.querySelector('#role').textContent === 'observer (read only)'")
        assert observer.locator("#send").is_disabled() and observer.locator("#observer-note").is_visible()

        map_page = browser.new_page(viewport={"width": 1400, "height": 900})
        map_page.goto(demo["map_url"])
        map_page.get_by_text("Watching only").first.wait_for(timeout=90_000)
        map_page.locator(MAP_TOKEN).first.fill(demo["read_token"])
        map_page.keyboard.press("Tab")
        map_page.get_by_role("button", name="Sign in").click()
        map_page.get_by_text("watching only (an observer").first.wait_for(timeout=10_000)
        assert map_page.get_by_role("button", name="Send").is_disabled()
        browser.close()


def test_api_docs_render_offline(demo: dict) -> None:
    """/docs draws every operation from local files (Swagger UI 5 reads FastAPI's OpenAPI 3.1)."""
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        page.goto(demo["dashboard_url"] + "docs")
        page.get_by_text("/api/v1/vehicles/{vehicle_id}/commands").first.wait_for(timeout=30_000)
        assert "Unable to render" not in page.content()
        browser.close()
