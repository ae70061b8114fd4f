"""A scripted survey through Tacit's REST API: a lawnmower pattern, one command at a time.

    python examples/survey.py --url http://127.0.0.1:8000 --token "$TOKEN" --vehicle 1 \
        --lines 4 --length 20 --spacing 5 --depth 2

The vehicle first goes to the survey depth, then runs ``--lines`` lines of ``--length`` m, alternately
north and south, stepping ``--spacing`` m east between lines. Each step is a control packet; the next
one is sent only when the vehicle says the step is done. A command's final status is one of:

- ``executed``: the vehicle reached the target (its check-point says where and when: ``report``);
- ``refused``: by the shore (HTTP 422 naming the field, nothing sent) or by the vehicle (``reason``, e.g.
  ``out_of_limits``, ``geofence``). The survey stops: the rest of the pattern would start from the wrong
  place. Exit status 3.
- ``failed``: the modem never acknowledged it. It may still have reached the vehicle (the ACK can be the
  frame that was lost), so the script asks for a check-point first, and only if the vehicle never ran
  it sends it again (a move sent twice would move twice). After ``--retries`` the survey stops.
  Exit status 4 (also when a command is not final within ``--timeout`` seconds).

Needs only ``httpx`` (installed with ``tacit[demo]``). The functions take any ``httpx.Client`` whose base
URL is the server, so a test can drive them too. ``--json`` prints one JSON object per command.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import httpx

FINAL = {"executed", "refused", "failed", "superseded"}
REFUSED, FAILED = 3, 4  # exit statuses


@dataclass
class Step:
    """One command of the survey and what became of it."""

    body: dict
    status: str = ""
    reason: str = ""
    command_ids: list[int] = field(default_factory=list)
    report: dict | None = None  # the vehicle's time and pose when it reported the final status


def lawnmower(lines: int, length: float, spacing: float, depth: float) -> list[dict]:
    """The commands of the pattern: absolute bearings, so a line does not depend on the heading."""
    steps = [{"command": "goto_depth", "depth": depth}]
    for line in range(lines):
        steps.append(
            {
                "command": "move",
                "distance": length,
                "angle": 0.0 if line % 2 == 0 else 180.0,
                "absolute_angle": True,
            }
        )
        if line < lines - 1:
            steps.append({"command": "move", "distance": spacing, "angle": 90.0, "absolute_angle": True})
    return steps


class SurveyError(RuntimeError):
    def __init__(self, message: str, exit_status: int) -> None:
        super().__init__(message)
        self.exit_status = exit_status


def send(http: httpx.Client, vehicle: int, body: dict) -> dict:
    """POST a command; a refusal by the shore (422: out of range or limits) raises, naming the field."""
    response = http.post(f"/api/v1/vehicles/{vehicle}/commands", json=body)
    if response.status_code == 422:
        problem = response.json()
        raise SurveyError(f"refused by the shore: {problem['detail']} (field {problem['field']})", REFUSED)
    response.raise_for_status()
    return response.json()


def wait_final(http: httpx.Client, command_id: int, timeout: float, poll: float = 0.5) -> dict:
    """Poll the command until its status is final; its full record, with ``history``."""
    deadline = time.monotonic() + timeout
    while True:
        command = http.get(f"/api/v1/commands/{command_id}").json()
        if command["status"] in FINAL:
            return command
        if time.monotonic() > deadline:
            raise SurveyError(f"command {command_id} still {command['status']} after {timeout:.0f} s", FAILED)
        time.sleep(poll)


def run_step(http: httpx.Client, vehicle: int, step: Step, timeout: float, retries: int, poll: float) -> Step:
    for _ in range(retries + 1):
        command = send(http, vehicle, step.body)
        step.command_ids.append(command["id"])
        final = wait_final(http, command["id"], timeout, poll)
        if final["status"] == "failed":  # did it reach the vehicle after all? Ask before sending it again.
            wait_final(http, send(http, vehicle, {"command": "request_checkpoint"})["id"], timeout, poll)
            final = http.get(f"/api/v1/commands/{command['id']}").json()
            if final["status"] not in ("failed", *FINAL):  # it did, and is running: wait for its end
                final = wait_final(http, command["id"], timeout, poll)
        step.status, step.reason = final["status"], final["reason"]
        step.report = next((e["report"] for e in reversed(final["history"]) if e.get("report")), None)
        if step.status != "failed":
            break
    return step


def survey(
    http: httpx.Client,
    vehicle: int,
    steps: list[dict],
    timeout: float = 600.0,
    retries: int = 1,
    poll: float = 0.5,
    progress: Callable[[Step], object] = print,
) -> list[Step]:
    """Run the commands one after the other; stop at the first that is not executed (``SurveyError``)."""
    done: list[Step] = []
    for body in steps:
        step = Step(body)
        done.append(step)
        try:
            run_step(http, vehicle, step, timeout, retries, poll)
        except SurveyError as exc:
            step.status, step.reason = ("refused" if exc.exit_status == REFUSED else "failed"), str(exc)
            progress(step)
            raise SurveyError(str(exc), exc.exit_status) from None
        progress(step)
        if step.status == "refused":
            raise SurveyError(f"refused by the vehicle: {step.reason}", REFUSED)
        if step.status != "executed":
            raise SurveyError(f"{step.status}: {step.reason or 'no acknowledgement'}", FAILED)
    return done


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--url", default="http://127.0.0.1:8000", help="the shore server")
    parser.add_argument("--token", required=True, help="an operator's token")
    parser.add_argument("--vehicle", type=int, default=1, help="the vehicle's id")
    parser.add_argument("--lines", type=int, default=4)
    parser.add_argument("--length", type=float, default=20.0, help="m per line")
    parser.add_argument("--spacing", type=float, default=5.0, help="m between lines")
    parser.add_argument("--depth", type=float, default=2.0, help="survey depth (m)")
    parser.add_argument("--timeout", type=float, default=600.0, help="s for each command to be final")
    parser.add_argument("--retries", type=int, default=1, help="resends of a command the modem never ACKed")
    parser.add_argument("--poll", type=float, default=1.0, help="s between status reads")
    parser.add_argument("--json", action="store_true", help="one JSON object per command")
    args = parser.parse_args(argv)

    def progress(step: Step) -> None:
        if args.json:
            print(json.dumps(asdict(step)), flush=True)
            return
        where = step.report or {}
        at = (
            f" at N {where['north']:.1f} E {where['east']:.1f} m, depth {where['depth']:.1f} m"
            if where
            else ""
        )
        print(f"{json.dumps(step.body)}: {step.status}{at} {step.reason}".rstrip(), flush=True)

    headers = {"Authorization": f"Bearer {args.token}"}
    with httpx.Client(base_url=args.url, headers=headers, timeout=30) as http:
        try:
            survey(
                http,
                args.vehicle,
                lawnmower(args.lines, args.length, args.spacing, args.depth),
                args.timeout,
                args.retries,
                args.poll,
                progress,
            )
        except SurveyError as exc:
            print(f"survey stopped: {exc}", file=sys.stderr)
            return exc.exit_status
        except httpx.HTTPError as exc:
            print(f"survey stopped: {exc}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
