"""Stream a real ArduSub ``.tlog`` over the simulator's MAVLink endpoints, at its own pace (scaled).

The agent cannot tell this from a live vehicle: the bytes are the log's own MAVLink frames. Commands
sent to a replayed vehicle are counted and ignored (a recording cannot obey).
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

from analysis import tlog
from simulators.mavlink_vehicle import Links

log = logging.getLogger("simulators.replay")


def read_tlog(path: str | Path) -> list[tuple[float, bytes]]:
    """(timestamp, raw MAVLink frame) for every message of a tlog, in order."""
    out = [(msg._timestamp, bytes(msg.get_msgbuf())) for msg in tlog.messages(path)]
    if not out:
        raise ValueError(f"{path}: no MAVLink messages")
    return out


class TlogReplay:
    def __init__(
        self, path: str | Path, links: Links, scale: float = 1.0, loop_forever: bool = False
    ) -> None:
        self.path = Path(path)
        self.links = links
        self.scale = scale
        self.loop_forever = loop_forever
        self.frames = read_tlog(self.path)
        self.sent = 0
        self.ignored_commands = 0
        self.finished = asyncio.Event()
        links.on_message = self._ignore

    def _ignore(self, msg: object, reply: object) -> None:
        self.ignored_commands += 1

    @property
    def duration(self) -> float:
        return self.frames[-1][0] - self.frames[0][0]

    async def run(self) -> None:
        while True:
            loop = asyncio.get_running_loop()
            start_wall, start_log = loop.time(), self.frames[0][0]
            for stamp, frame in self.frames:
                due = start_wall + (stamp - start_log) / self.scale
                delay = due - loop.time()
                if delay > 0:
                    await asyncio.sleep(delay)
                self.links.broadcast(frame)
                self.sent += 1
            if not self.loop_forever:
                break
        self.finished.set()
        log.info("replay of %s finished: %d messages", self.path.name, self.sent)
