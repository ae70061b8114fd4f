"""The agent's persisted state: mission progress, replay window, packet counters, position estimate.

Written atomically (temporary file, fsync, rename) after every change that matters, so killing the
agent at any moment and starting it again resumes where it was.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path


@dataclass
class AgentState:
    mission: dict = field(default_factory=dict)
    replay: dict = field(default_factory=lambda: {"highest": 0, "seen": 0})
    packet_seq: int = 0  # one counter for check-points and priority packets (u8 on the wire)
    priority_count: int = 0
    north: float = 0.0
    east: float = 0.0
    speed: float = 0.0  # dead-reckoned speed, thrust and vehicle time: a restart integrates the gap
    thrust: int = 0
    yaw: float = 0.0  # rad: the heading the vehicle kept while the agent was down
    time: float | None = None

    @classmethod
    def load(cls, path: Path) -> AgentState:
        if not path.exists():
            return cls()
        try:
            return cls(**json.loads(path.read_text()))
        except (ValueError, TypeError) as exc:
            raise ValueError(
                f"{path}: unreadable agent state ({exc}); move it aside to start afresh"
            ) from None

    def save(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        with tmp.open("w") as handle:
            json.dump(asdict(self), handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
