"""The agent's persisted state: mission progress, replay window, packet counters, position estimate,
clock correction, key epoch and the packets waiting to be sent.

Written atomically (temporary file, fsync, rename; owner-only) after every change that matters, so
killing the agent at any moment and starting it again resumes where it was.

A state file that cannot be read (truncated by a power cut, corrupted, written by something else) is
set aside as ``<name>.corrupt-<time>`` with one clear log line, and the agent starts from a safe
fresh state instead of a crash loop. A fresh state knows no control sequence numbers, so its replay
window starts with a time floor: only control frames stamped after the agent started are accepted.
The shore signs every attempt afresh with the current time, so genuine commands still pass, while any
frame recorded before the restart is refused.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

log = logging.getLogger("tacit.agent.state")

FLOOR_SLACK_S = 5.0  # a control frame stamped this much before the fresh start still counts


@dataclass
class AgentState:
    mission: dict = field(default_factory=dict)
    replay: dict = field(default_factory=lambda: {"highest": 0, "seen": 0, "floor": 0})
    packet_seq: int = 0  # one counter for check-points and priority packets (u8 on the wire)
    priority_count: int = 0
    north: float = 0.0
    east: float = 0.0
    speed: float = 0.0  # dead-reckoned speed, thrust and vehicle time: a restart integrates the gap
    thrust: int = 0
    yaw: float = 0.0  # rad: the heading the vehicle kept while the agent was down
    time: float | None = None
    clock_offset: float = 0.0  # s to add to the local clock (from the shore's authenticated time)
    heartbeat: list = field(default_factory=lambda: [0, 0])  # (time, seq) of the last shore heartbeat
    key_epoch: int = 0  # the epoch of the key the vehicle signs with (the newest the shore confirmed)
    outbox: list = field(default_factory=list)  # [urgent, hex] packets queued, not yet delivered
    uncovered: list = field(default_factory=list)  # [seq, hash hex] delivered, not yet in a check-point
    settled: list = field(default_factory=list)  # [seq, status] final statuses of recent commands
    fresh: bool = False  # not persisted: True when this state was not loaded from a file

    @classmethod
    def new(cls, now: float | None = None) -> AgentState:
        """A fresh state whose replay window only takes control frames stamped from now on."""
        now = time.time() if now is None else now
        state = cls(fresh=True)
        state.replay = {"highest": 0, "seen": 0, "floor": int(now - FLOOR_SLACK_S)}
        return state

    @classmethod
    def load(cls, path: Path, now: float | None = None) -> AgentState:
        """The saved state, or a fresh one if there is none or it is unreadable (set aside, logged)."""
        if not path.exists():
            return cls.new(now)
        try:
            data = json.loads(path.read_text())
            if not isinstance(data, dict):
                raise ValueError(f"a JSON object was expected, not {type(data).__name__}")
            known = {f.name: f for f in dataclasses.fields(cls) if f.name != "fresh"}
            state = cls(**{k: v for k, v in data.items() if k in known})
            state._check()
            return state
        except (OSError, ValueError, TypeError, KeyError, UnicodeDecodeError) as exc:
            aside = path.with_name(f"{path.name}.corrupt-{time.strftime('%Y%m%d-%H%M%S')}")
            try:
                os.replace(path, aside)
            except OSError:
                aside = path
            log.error("agent state %s is unreadable (%s): set aside as %s; starting safe (waiting, replay "
                      "window floored at now)", path, exc, aside.name)  # fmt: skip
            return cls.new(now)

    def _check(self) -> None:
        """Types and ranges a hand-edited or damaged file could get wrong, as ValueError."""
        for name in ("packet_seq", "priority_count", "thrust", "key_epoch"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < -(2**31):
                raise ValueError(f"{name} is not an integer")
        for name in ("north", "east", "speed", "yaw", "clock_offset"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"{name} is not a finite number")
        if self.time is not None and (
            not isinstance(self.time, (int, float)) or not math.isfinite(self.time)
        ):
            raise ValueError("time is not a finite number")
        if not isinstance(self.mission, dict) or not isinstance(self.replay, dict):
            raise ValueError("mission and replay are objects")
        for key in ("highest", "seen"):
            if not isinstance(self.replay.get(key), int):
                raise ValueError(f"replay.{key} is not an integer")
        for name in ("heartbeat", "outbox", "uncovered", "settled"):
            if not isinstance(getattr(self, name), list):
                raise ValueError(f"{name} is not a list")

    def save(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        data = asdict(self)
        data.pop("fresh")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as handle:
            json.dump(data, handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
