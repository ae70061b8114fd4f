"""The agent's persisted state: mission progress, replay window, packet counters, position estimate,
clock correction, key epoch and the packets waiting to be sent.

Written atomically (temporary file, fsync, rename; owner-only) after every change that matters, so
killing the agent at any moment and starting it again resumes where it was.

A state file that cannot be read (truncated by a power cut, corrupted, written by something else) is
set aside as ``<name>.corrupt-<time>`` with one clear log line, and the agent starts from a safe
fresh state instead of a crash loop. A fresh state knows no control sequence numbers and no SYNC
counter: it is *unsynced* (``sync_counter`` None, as is a file from protocol version 2) and accepts no
command and no SYNC until a SYNC echoes one of its check-points (``tacit.auth.SyncWindow``), which sets
its clock offset, its SYNC counter and its replay window's floor in one exchange. Any frame recorded
before that SYNC is refused.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger("tacit.agent.state")


@dataclass(frozen=True)
class Queued:
    """A packet waiting to be sent (or not yet acknowledged)."""

    urgent: bool
    data: bytes

    def to_json(self) -> dict[str, Any]:
        return {"urgent": self.urgent, "hex": self.data.hex()}

    @classmethod
    def from_json(cls, item: Any) -> Queued:
        urgent, data = (
            (item["urgent"], item["hex"]) if isinstance(item, dict) else item
        )  # older files: [urgent, hex]
        return cls(bool(urgent), bytes.fromhex(data))


@dataclass(frozen=True)
class Uncovered:
    """A delivered priority packet no check-point has covered yet: its seq and the hash its MAC covers."""

    seq: int
    hash: bytes

    def to_json(self) -> dict[str, Any]:
        return {"seq": self.seq, "hash": self.hash.hex()}

    @classmethod
    def from_json(cls, item: Any) -> Uncovered:
        seq, digest = (item["seq"], item["hash"]) if isinstance(item, dict) else item
        return cls(int(seq), bytes.fromhex(digest))


@dataclass(frozen=True)
class Settled:
    """A command's final status on board (a ``CommandStatus`` name), for the check-points to report."""

    seq: int
    status: str

    def to_json(self) -> dict[str, Any]:
        return {"seq": self.seq, "status": self.status}

    @classmethod
    def from_json(cls, item: Any) -> Settled:
        seq, status = (item["seq"], item["status"]) if isinstance(item, dict) else item
        return cls(int(seq), str(status))


#: The list fields and how each item is read back.
RECORDS: dict[str, Callable[[Any], Queued | Uncovered | Settled]] = {
    "outbox": Queued.from_json,
    "uncovered": Uncovered.from_json,
    "settled": Settled.from_json,
}


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
    sync_counter: int | None = None  # the last accepted SYNC's counter; None: unsynced (lost state)
    key_epoch: int = 0  # the epoch of the key the vehicle signs with (the newest the shore confirmed)
    outbox: list[Queued] = field(default_factory=list)  # queued, not yet delivered
    uncovered: list[Uncovered] = field(default_factory=list)  # delivered, not yet in a check-point
    settled: list[Settled] = field(default_factory=list)  # final statuses of recent commands
    fresh: bool = False  # not persisted: True when this state was not loaded from a file

    @classmethod
    def load(cls, path: Path) -> AgentState:
        """The saved state, or a fresh (unsynced) one if there is none or it is unreadable (set aside,
        logged)."""
        if not path.exists():
            return cls(fresh=True)
        try:
            data = json.loads(path.read_text())
            if not isinstance(data, dict):
                raise ValueError(f"a JSON object was expected, not {type(data).__name__}")
            known = {f.name: f for f in dataclasses.fields(cls) if f.name != "fresh"}
            state = cls(**{k: v for k, v in data.items() if k in known and k not in RECORDS})
            state._check()
            for name, record in RECORDS.items():
                items = data.get(name, [])
                if not isinstance(items, list):
                    raise ValueError(f"{name} is not a list")
                setattr(state, name, [record(item) for item in items])
            return state
        except (OSError, ValueError, TypeError, KeyError, UnicodeDecodeError) as exc:
            aside = path.with_name(f"{path.name}.corrupt-{time.strftime('%Y%m%d-%H%M%S')}")
            try:
                os.replace(path, aside)
            except OSError:
                aside = path
            log.error(
                "agent state %s is unreadable (%s): set aside as %s; starting safe (waiting, unsynced: "
                "no command until the shore answers a check-point)",
                path,
                exc,
                aside.name,
            )
            return cls(fresh=True)

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
        if self.sync_counter is not None and (
            not isinstance(self.sync_counter, int) or self.sync_counter < 0
        ):
            raise ValueError("sync_counter is not a counter")

    def save(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "fresh"}
        for name in RECORDS:
            data[name] = [item.to_json() for item in data[name]]
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as handle:
            json.dump(data, handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
