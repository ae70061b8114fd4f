"""Cancelling a queued command from the dashboard, in real headless Chromium: ``tacit serve`` (its own
process) with no shore modem, so that what is queued stays queued while the test looks. The command
history's cancel button takes a queued command back (it reads cancelled, struck through, with who said it
in its step's title), the vehicle's queue against its cap is shown, and an observer's button is
disabled."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from playwright.sync_api import sync_playwright

from launch.processes import stop
from tests.support.nats import free_port
from tests.system.test_browser import ARTIFACTS, CHROMIUM, FLAGS

TOKEN = "cancel-operator"
OBSERVER = "cancel-observer"
LONG = 60_000  # ms


@pytest.fixture(scope="module")
def shore(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    folder = tmp_path_factory.mktemp("cancel")
    port = free_port()
    env = {
        **os.environ, "TACIT_WRITE_TOKENS": TOKEN, "TACIT_READ_TOKENS": OBSERVER, "TACIT_METRICS_PORT": "0",
        "TACIT_MODEM_URL": "", "PYTHONUNBUFFERED": "1",
    }  # fmt: skip
    with (folder / "serve.log").open("w") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "tacit.cli", "serve", "--port", str(port), "--no-map",
             "--database-url", f"sqlite:///{folder}/tacit.db"],
            stdout=log, stderr=subprocess.STDOUT, env=env, text=True,
        )  # fmt: skip
        api = f"http://127.0.0.1:{port}"
        try:
            http = httpx.Client(base_url=api, headers={"Authorization": f"Bearer {TOKEN}"})
            deadline = time.monotonic() + 60
            while True:
                assert proc.poll() is None, (folder / "serve.log").read_text()[-2000:]
                assert time.monotonic() < deadline, (folder / "serve.log").read_text()[-2000:]
                try:
                    if http.get("/api/v1/health").status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                time.sleep(0.2)
            yield {"api": api, "http": http}
        finally:
            stop(proc)


def test_the_dashboard_cancels_a_queued_command_and_shows_the_queue_against_its_cap(
    shore: dict[str, Any],
) -> None:
    http = shore["http"]
    assert http.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}).status_code == 201
    ids = [http.post("/api/v1/vehicles/1/commands", json={"command": "hold"}).json()["id"] for _ in range(3)]
    ARTIFACTS.mkdir(exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        errors: list[str] = []
        page = browser.new_page(viewport={"width": 1400, "height": 1400}, bypass_csp=True)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(f"{shore['api']}/#token={TOKEN}")
        page.wait_for_function("document.querySelector('#role').textContent === 'operator'", timeout=LONG)
        queue = page.locator("#queue-cap")
        queue.filter(has_text="rov1: 3 / 20 commands waiting for the link").wait_for(timeout=LONG)
        row = page.locator(f"#commands tr[data-id='{ids[1]}']")
        row.locator("button[data-cancel]").click()
        row.locator("td.status-cancelled").wait_for(timeout=LONG)
        assert "cancelled, never sent" in (page.locator("#command-result").text_content() or "")
        assert row.locator("button[data-cancel]").count() == 0  # nothing left to cancel
        title = row.locator(".step[data-status='cancelled']").get_attribute("title") or ""
        assert "from an operator config-operator-1; by config-operator-1" in title  # the token's name
        queue.filter(has_text="rov1: 2 / 20 commands waiting").wait_for(timeout=LONG)
        assert http.get(f"/api/v1/commands/{ids[1]}").json()["status"] == "cancelled"
        assert [http.get(f"/api/v1/commands/{i}").json()["status"] for i in (ids[0], ids[2])] == [
            "queued"
        ] * 2
        page.screenshot(path=str(ARTIFACTS / "command-cancel.png"))

        observer = browser.new_page(viewport={"width": 1400, "height": 1400}, bypass_csp=True)
        observer.goto(f"{shore['api']}/#token={OBSERVER}")
        observer.wait_for_function("document.querySelector('#role').textContent.startsWith('observer')")
        button = observer.locator(f"#commands tr[data-id='{ids[0]}'] button[data-cancel]")
        button.wait_for(timeout=LONG)
        assert button.is_disabled()
        browser.close()
    assert errors == []
