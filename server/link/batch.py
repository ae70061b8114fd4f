"""Rows gathered while handling a batch of frames, inserted together just before its commit."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from server.core.db import Tx
from server.link import repository as link
from server.telemetry import repository as telemetry


@dataclass
class Batch:
    samples: list[dict[str, Any]] = field(default_factory=list)  # telemetry rows
    events: list[dict[str, Any]] = field(default_factory=list)  # link event rows

    def flush(self, s: Tx) -> None:
        telemetry.add_samples(s, self.samples)
        link.add_events(s, self.events)
        self.samples.clear()
        self.events.clear()
