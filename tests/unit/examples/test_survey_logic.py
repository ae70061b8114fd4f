"""examples/survey.py against a fake shore: a failed command is sent again only if the vehicle never ran it; one
that keeps failing stops the survey."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import httpx
import pytest

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "survey.py"


def load_example():
    spec = importlib.util.spec_from_file_location("survey_example", EXAMPLE)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules["survey_example"] = module
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


survey_example = load_example()


class FakeShore:
    """The API as a script sees it, with a link that loses the first move's ACK."""

    def __init__(self, ran_after_all: bool) -> None:
        self.ran_after_all = ran_after_all
        self.commands: list[dict] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        if request.method == "POST":
            body = json.loads(request.content)
            command = {"id": len(self.commands) + 1, "body": body, "reason": "", "history": [], "polls": 0}
            first_move = body["command"] == "move" and not any(
                c["body"]["command"] == "move" for c in self.commands
            )
            command["status"] = "failed" if first_move else "executed"
            self.commands.append(command)
            return httpx.Response(202, json={"id": command["id"], "status": "queued"})
        command = self.commands[int(request.url.path.rsplit("/", 1)[1]) - 1]
        if command["body"]["command"] == "request_checkpoint" and self.ran_after_all:
            self.commands[1]["status"] = "executing"  # the check-point shows the "failed" move running
        elif command["status"] == "executing":
            command["status"] = "executed"
        report = {"time": 1, "state": "holding", "north": 1.0, "east": 2.0, "depth": 0.5, "heading": 0.0}
        return httpx.Response(
            200, json={**command, "history": [{"status": command["status"], "report": report}]}
        )


@pytest.mark.parametrize("ran_after_all", [True, False])
def test_a_failed_command_is_sent_again_only_if_the_vehicle_never_ran_it(ran_after_all: bool) -> None:
    shore = FakeShore(ran_after_all)
    with httpx.Client(transport=httpx.MockTransport(shore), base_url="http://shore") as http:
        steps = survey_example.survey(
            http, 1, survey_example.lawnmower(1, 5, 5, 1), poll=0, progress=lambda s: None
        )
    assert [s.status for s in steps] == ["executed", "executed"]
    sent = [c["body"]["command"] for c in shore.commands]
    if ran_after_all:  # it ran: waited for, not repeated (a move sent twice moves twice)
        assert sent == ["goto_depth", "move", "request_checkpoint"] and steps[1].command_ids == [2]
    else:
        assert sent == ["goto_depth", "move", "request_checkpoint", "move"] and steps[1].command_ids == [2, 4]


def test_a_command_that_keeps_failing_stops_the_survey() -> None:
    def always_failing(request: httpx.Request) -> httpx.Response:
        if request.method == "POST":
            return httpx.Response(202, json={"id": 1, "status": "queued"})
        return httpx.Response(
            200, json={"id": 1, "status": "failed", "reason": "no acknowledgement", "history": []}
        )

    with httpx.Client(transport=httpx.MockTransport(always_failing), base_url="http://shore") as http:
        with pytest.raises(survey_example.SurveyError) as stopped:
            survey_example.survey(http, 1, [{"command": "hold"}], retries=2, poll=0, progress=lambda s: None)
    assert stopped.value.exit_status == survey_example.FAILED
