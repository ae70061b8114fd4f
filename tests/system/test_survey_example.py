"""examples/survey.py, the README's scripted mission: run as a user runs it against the simulated system
(server, agent and simulator as processes). Its handling of failed commands: tests/unit/examples."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from launch.rig import TOKEN, Rig

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "survey.py"


def run_example(rig: Rig, *args: str) -> tuple[int, list[dict], str]:
    result = subprocess.run(
        [
            sys.executable,
            str(EXAMPLE),
            "--url",
            f"http://127.0.0.1:{rig.port}",
            "--token",
            TOKEN,
            "--vehicle",
            "1",
            "--json",
            "--poll",
            "0.2",
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=400,
    )
    return result.returncode, [json.loads(line) for line in result.stdout.splitlines()], result.stderr


def test_survey_runs_through_the_api_on_the_simulated_system() -> None:
    rig = Rig(150.0, 8.0, settle=0, mission=True, agent_config={"limits": {"max_depth": 3.0}})
    try:
        status, steps, err = run_example(
            rig, "--lines", "2", "--length", "6", "--spacing", "3", "--depth", "1"
        )
        assert status == 0, err
        assert [s["body"]["command"] for s in steps] == ["goto_depth", "move", "move", "move"]
        assert all(s["status"] == "executed" and s["report"] for s in steps)
        last = steps[-1]["report"]  # 6 m north, 3 m east, 6 m south: back near the start line, 3 m east
        assert abs(last["east"] - 3.0) < 2.0 and abs(last["north"]) < 2.0 and abs(last["depth"] - 1.0) < 0.4

        status, steps, err = run_example(rig, "--depth", "150")  # beyond the shore's limit: nothing is sent
        assert status == 3 and "refused by the shore" in err and "field depth" in err
        assert steps[-1]["status"] == "refused" and steps[-1]["command_ids"] == []

        status, steps, err = run_example(
            rig, "--depth", "4"
        )  # the shore allows it, the vehicle (3 m) does not
        assert status == 3 and "refused by the vehicle: out_of_limits" in err
        assert steps == [{**steps[0], "status": "refused", "reason": "out_of_limits"}]
        assert rig.http.get(f"/commands/{steps[0]['command_ids'][0]}").json()["status"] == "refused"
    finally:
        rig.close()
