"""The operator's screens in real headless Chromium (Debian's) against the running demo:
the dashboard loads without console errors, a command sent from the 3D map's panel moves the simulated
vehicle and reaches "acknowledged" on the page, priority packets show in the live log and timeline.
Screenshots are saved in test-artifacts/."""

from __future__ import annotations

import math
import re
import time
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import sync_playwright

from tests.conftest import tacit_process

ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts"
CHROMIUM = "/usr/bin/chromium"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--use-gl=swiftshader", "--enable-unsafe-swiftshader"]  # fmt: skip


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201
    data = tmp_path_factory.mktemp("demo")
    with tacit_process("demo", "--headless", "--time-scale", "4", "--data-dir", str(data), "--port", "18311",
                       "--map-port", "18391") as (proc, info):  # fmt: skip
        yield info


def checkpoint(info: dict) -> dict | None:
    link = httpx.get(info["api_url"] + "/link", headers={"Authorization": f"Bearer {info['token']}"}).json()
    return link["vehicles"]["rov1"]["checkpoint"]


def test_dashboard_and_map_in_a_real_browser(demo: dict) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    deadline = time.monotonic() + 60
    while checkpoint(demo) is None and time.monotonic() < deadline:
        time.sleep(0.5)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        errors: list[str] = []
        dashboard = browser.new_page(viewport={"width": 1400, "height": 1600})
        dashboard.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        dashboard.on("pageerror", lambda e: errors.append(str(e)))
        dashboard.goto(demo["dashboard_url"])
        dashboard.fill("#token", demo["token"])
        dashboard.click("#login button")
        dashboard.wait_for_function("document.querySelector('#role').textContent === 'operator'")

        map_page = browser.new_page(viewport={"width": 1400, "height": 900})
        map_page.goto(demo["map_url"])
        map_page.get_by_text("Modem").first.wait_for(timeout=30_000)
        before = checkpoint(demo)
        map_page.get_by_role("button", name="Send").click()
        # reaching "acknowledged" means that state or a later one (the panel may skip past it between repaints)
        map_page.get_by_text(
            re.compile(r"Command seq \d+: (acknowledged|executing|executed)")
        ).first.wait_for(timeout=90_000)
        map_page.screenshot(path=str(ARTIFACTS / "map.png"))

        deadline = time.monotonic() + 60
        moved = 0.0
        while moved < 3.0 and time.monotonic() < deadline:
            after = checkpoint(demo)
            moved = math.hypot(after["north"] - before["north"], after["east"] - before["east"])
            time.sleep(1.0)
        assert moved >= 3.0, "the vehicle did not move after the map's command"

        dashboard.wait_for_function("[...document.querySelectorAll('#packets td')].some(td => td.textContent === 'priority')",
                                    timeout=60_000)  # fmt: skip
        dashboard.wait_for_function("state.timeline.some(e => e.kind.startsWith('p'))")
        dashboard.wait_for_function("[...document.querySelectorAll('#commands td')].some(td => td.textContent === 'acknowledged' || td.textContent === 'executed')")  # fmt: skip
        dashboard.screenshot(path=str(ARTIFACTS / "dashboard.png"), full_page=True)
        browser.close()
    assert errors == []


def test_observer_sees_everything_and_cannot_write(demo: dict) -> None:
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        page = browser.new_page()
        page.goto(demo["dashboard_url"])
        page.fill("#token", "not-a-token")
        page.click("#login button")
        page.wait_for_function("document.querySelector('#role').textContent === 'not signed in'")
        assert page.locator("#send").is_disabled()
        browser.close()
