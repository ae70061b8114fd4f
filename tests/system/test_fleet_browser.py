"""The fleet on both screens, in real headless Chromium against ``tacit demo --vehicles 2``: every vehicle
listed in its own colour with its state, last report, prediction, battery and link, the fleet's origin in
latitude and longitude, a timeline row and airtime per vehicle; a command sent to the vehicle picked in
the form reaches that vehicle; "hold all" (dashboard) and "return all home" (map) are one action and one
command per vehicle, each followed; no reported step shows before its command was sent; a vehicle whose
agent is killed is greyed on both screens while the other carries on. Screenshots in test-artifacts/."""

from __future__ import annotations

import os
import re
import signal
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import Page, sync_playwright

from tests.conftest import tacit_process
from tests.system.test_browser import ARTIFACTS, CHROMIUM, FLAGS, MAP_TOKEN

LONG = 150_000  # ms: two vehicles share a rate-0 channel on 2 busy cores

#: For every command on the page: its reported steps (on board) never before its first transmission.
CAUSE_FIRST = """() => [...document.querySelectorAll('#commands tbody tr')].map(row => {
  const steps = [...row.querySelectorAll('.step')];
  const sent = steps.filter(s => s.dataset.status === 'sent').map(s => Number(s.dataset.at));
  const reported = steps.filter(s => s.querySelector('.on-board')).map(s => Number(s.dataset.at));
  return {id: row.dataset.id, sent: sent.length ? Math.min(...sent) : null, reported};
})"""


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory):
    data = tmp_path_factory.mktemp("fleet-demo")
    with tacit_process(
        "demo",
        "--headless",
        "--vehicles",
        "2",
        "--time-scale",
        "4",
        "--data-dir",
        str(data),
        "--port",
        "18331",
        "--map-port",
        "18411",
    ) as (_proc, info):
        yield {**info, "data": data}


def agent_pid(data: Path, name: str) -> int:
    """The demo's agent for vehicle ``name`` (a child this test's demo started), by its configuration file."""
    config = str(data / f"agent-{name}.toml")
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                argv = (entry / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if config.encode() in argv:
                return int(entry.name)
    raise LookupError(f"no agent running on {config}")


def sign_in_map(page: Page, info: dict) -> None:
    page.goto(info["map_url"])
    page.get_by_text("Watching only").first.wait_for(timeout=90_000)
    page.locator(MAP_TOKEN).first.fill(info["token"])
    page.keyboard.press("Tab")
    page.get_by_role("button", name="Sign in").click()
    page.get_by_text("commands enabled").first.wait_for(timeout=30_000)


def test_the_fleet_on_both_screens(fleet: dict) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        errors: list[str] = []
        dashboard = browser.new_page(viewport={"width": 1400, "height": 1800}, bypass_csp=True)
        dashboard.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        dashboard.on("pageerror", lambda e: errors.append(str(e)))
        dashboard.goto(fleet["sign_in_url"])
        dashboard.wait_for_function(
            "[...document.querySelectorAll('#fleet tbody tr')].filter(r => r.textContent.includes('ago')).length === 2",
            timeout=LONG,
        )  # fmt: skip  (both vehicles listed, each with a report)
        rows = dashboard.locator("#fleet tbody tr")
        assert [rows.nth(i).get_attribute("data-name") for i in range(2)] == ["rov1", "rov2"]
        colours = dashboard.evaluate(  # in one call: the table is drawn again every few seconds
            "[...document.querySelectorAll('#fleet tbody tr .swatch')].map(e => getComputedStyle(e).backgroundColor)"
        )
        assert len(set(colours)) == 2  # each vehicle its own colour
        for i in range(2):
            text = rows.nth(i).text_content()
            assert re.search(r"± \d+\.\d m", text) and " V" in text and "SNR" in text
            assert re.search(r"vehicle clock at (most|least) \d+\.\d s (behind|ahead of) the shore's", text)
        assert "40.48620° N, 74.45180° W" in dashboard.text_content("#origin")  # the one origin
        dashboard.wait_for_function(
            "state.vehicles.every(v => state.timeline.some(e => e.vehicle === v.name))", timeout=LONG
        )
        assert dashboard.evaluate("document.querySelector('#timeline').height") >= 40 + 2 * 44  # a row each
        # the command form: the vehicle picked is the one the command goes to
        dashboard.select_option("#vehicle", label="rov2 (modem 3)")
        dashboard.wait_for_function(
            "document.querySelector('#vehicle-name').textContent === 'rov2'", timeout=LONG
        )
        dashboard.wait_for_function(  # the card is the chosen vehicle's link, not a row per vehicle
            "document.querySelector('#link-stats').textContent.includes('its airtime')", timeout=LONG
        )
        link = dashboard.eval_on_selector_all("#link-stats th", "ths => ths.map(th => th.textContent)")
        assert link.count("last heard") == 1 and link.count("its airtime") == 1 and link.count("key") == 1, (
            link
        )
        dashboard.select_option("#cmd", "goto_depth")
        dashboard.fill("#f-depth", "1.5")
        dashboard.click("#send")
        dashboard.wait_for_function(
            "/go to depth 1.5 m to rov2 .*: (executing|executed)/.test(document.querySelector('#command-result').textContent)",
            timeout=LONG,
        )  # fmt: skip
        sent_to = dashboard.evaluate("state.commands.get(state.lastSent).vehicle_id")
        assert sent_to == dashboard.evaluate("state.vehicles.find(v => v.name === 'rov2').id")

        # one action for the fleet: one command per vehicle, each with its own status
        dashboard.click("#fleet-actions [data-command='hold']")
        assert dashboard.text_content("#fleet-confirm") == "Confirm: hold all (2 vehicles)"
        dashboard.click("#fleet-confirm")
        dashboard.wait_for_function(
            "[...document.querySelectorAll('#fleet-result .fleet-command')].filter(e => /: (executing|executed)$/.test(e.textContent)).length === 2",
            timeout=LONG,
        )  # fmt: skip
        held = dashboard.eval_on_selector_all(
            "#fleet-result .fleet-command", "els => els.map(e => e.dataset.id)"
        )
        assert len(set(held)) == 2

        # times that make sense: no step the vehicle reported shows before its command left the shore
        dashboard.wait_for_function(
            f"({CAUSE_FIRST})().filter(c => c.reported.length).length >= 3", timeout=LONG
        )
        for command in dashboard.evaluate(f"({CAUSE_FIRST})()"):
            assert all(t >= command["sent"] for t in command["reported"]), command
        dashboard.screenshot(path=str(ARTIFACTS / "fleet-dashboard.png"), full_page=True)

        map_page = browser.new_page(viewport={"width": 1400, "height": 1000})
        sign_in_map(map_page, fleet)
        map_page.get_by_text(re.compile(r"predicted N .* ± ")).nth(1).wait_for(timeout=LONG)  # both listed
        map_page.get_by_role("button", name="Return all home").click()
        map_page.get_by_role("button", name="Confirm: return all home").click()
        map_page.get_by_text("Return all home: 2 commands queued").first.wait_for(timeout=LONG)
        for close in map_page.locator(".mantine-Notification-closeButton").all():
            close.click()
        map_page.screenshot(path=str(ARTIFACTS / "fleet-map.png"))

        # a silent vehicle is greyed on both screens; the other is not
        os.kill(agent_pid(fleet["data"], "rov2"), signal.SIGKILL)
        dashboard.wait_for_function(  # the other carries on: it is not greyed meanwhile
            "document.querySelector('#fleet tr[data-name=rov2]').classList.contains('overdue')"
            " && !document.querySelector('#fleet tr[data-name=rov1]').classList.contains('overdue')",
            timeout=LONG,
        )
        map_page.get_by_text(re.compile(r"rov2.*\(overdue\)")).first.wait_for(timeout=LONG)
        token = {"Authorization": f"Bearer {fleet['token']}"}
        listed = httpx.get(fleet["api_url"] + "/fleet", headers=token).json()["vehicles"]
        assert listed[1]["name"] == "rov2" and listed[1]["overdue"]
        dashboard.screenshot(path=str(ARTIFACTS / "fleet-dashboard-overdue.png"), full_page=True)
        browser.close()
    assert errors == []
