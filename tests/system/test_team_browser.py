"""Team missions from the dashboard, in real headless Chromium against ``tacit demo --vehicles 3``: a
team whose lanes are too close is refused with the reason under the form; the manual's example
(docs/missions.md), entered as written, is created and started on the demo fleet; a second team over the
same vehicles is refused where its Start was pressed, stays ``refused`` with the reason, and is deleted;
the first is aborted and deleted. Screenshot in test-artifacts/."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from playwright.sync_api import Page, expect, sync_playwright

from launch.stack import wait_for
from tests.conftest import tacit_process
from tests.integration.server.missions.test_teams import manual_example
from tests.system.test_browser import ARTIFACTS, CHROMIUM, FLAGS

LONG = 120_000  # ms: three vehicles share a rate-0 channel on 2 busy cores


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    data = tmp_path_factory.mktemp("team-demo")
    with tacit_process(
        "demo",
        "--headless",
        "--vehicles",
        "3",
        "--time-scale",
        "4",
        "--data-dir",
        str(data),
        "--port",
        "18351",
        "--map-port",
        "18431",
    ) as (_proc, info):
        yield info


def teams(api: httpx.Client) -> dict[int, dict]:
    return {t["id"]: t for t in api.get("/teams").json()}


def fill(page: Page, example: dict) -> None:
    """The form filled with the manual's example, as written."""
    page.fill("#team-name", example["name"])
    for side in ("south", "north", "west", "east"):
        page.fill(f"#team-{side}", str(example["area"][side]))
    page.fill("#team-spacing", str(example["spacing"]))
    page.fill("#team-depth", str(example["depth"]))
    for member in example["vehicles"]:
        page.locator(f"[data-vehicle='{member['vehicle']}']").check()
        page.locator(f"[data-lost='{member['vehicle']}']").select_option(member.get("lost_action", ""))


def press(page: Page, team_id: int, action: str) -> None:
    page.locator(f"[data-team='{team_id}'] [data-action='{action}']").click()


def test_team_missions_from_the_dashboard(fleet: dict) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    api = httpx.Client(base_url=fleet["api_url"], headers={"Authorization": f"Bearer {fleet['token']}"})
    example = manual_example()
    assert [m["vehicle"] for m in example["vehicles"]] == ["rov1", "rov2", "rov3"]
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        page = browser.new_page(viewport={"width": 1400, "height": 2400})
        page.goto(fleet["sign_in_url"])
        page.locator("[data-vehicle='rov3']").wait_for(timeout=LONG)
        wait_for(lambda: len(api.get("/safety").json()["paths"]) == 3, timeout=LONG / 1000, what="all heard")

        fill(page, example)
        page.fill("#team-spacing", "3")
        page.click("#team-create")
        expect(page.locator("#team-create-result")).to_contain_text(
            "not created: lanes 3 m apart would bring neighbouring vehicles closer than the 5 m separation"
        )
        assert teams(api) == {}

        fill(page, example)
        page.click("#team-create")
        expect(page.locator("#team-create-result")).to_contain_text("created")
        (first,) = teams(api)
        assert teams(api)[first]["members"][1]["lost_action"] == "return"
        press(page, first, "start")
        expect(page.locator(f"[data-team='{first}']")).to_contain_text("started", timeout=30_000)
        assert teams(api)[first]["status"] == "started"

        page.click("#team-create")  # the same vehicles again
        expect(page.locator("#team-create-result")).to_contain_text(f"team mission {first + 1}")
        second = first + 1
        press(page, second, "start")
        refusal = f"start refused: rov1, rov2, rov3 run team mission {first} (river survey): abort it first"
        expect(page.locator(f"[data-team='{second}'] .team-outcome")).to_contain_text(refusal, timeout=30_000)
        shown = teams(api)[second]
        assert shown["status"] == "refused" and "abort it first" in shown["detail"]
        page.screenshot(path=str(ARTIFACTS / "team-missions.png"), full_page=True)
        press(page, second, "delete")
        expect(page.locator(f"[data-team='{second}']")).to_have_count(0, timeout=30_000)

        press(page, first, "abort")
        expect(page.locator(f"[data-team='{first}']")).to_contain_text("aborted", timeout=30_000)
        press(page, first, "delete")
        expect(page.locator(f"[data-team='{first}']")).to_have_count(0, timeout=30_000)
        assert teams(api) == {}
        browser.close()
