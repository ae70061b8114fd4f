"""``tacit backhaul-audit``: issue 24's own check, counted. Per gateway, the frames its modem heard (its
outbox file), those it published, and at the center those stored, merged with another gateway's copy of
the same transmission (stored once: spatial diversity) and decoded, or resent (a retransmission: the
same packets as an earlier frame, dropped as duplicates); every frame heard and published but not stored
is named. ``tacit demo --gateways N`` prints it at exit.

An outbox keeps the newest ``Outbox.keep`` published messages (and every unpublished one): the count is
of the frames it still holds.
"""

from __future__ import annotations

import argparse
import contextlib
import sqlite3
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from server.backhaul import repository, subjects
from server.core.db import Tx, make_engine, reading
from server.telemetry import repository as telemetry

SHOWN = 5  # frames named per gateway


@dataclass
class Count:
    """One gateway's frames, from its modem to the center's store."""

    gateway: str
    heard: int = 0
    published: int = 0
    stored: int = 0
    merged: int = 0  # stored as another gateway's copy of the same frame, or the kept copy of one
    decoded: int = 0  # stored, and every packet of its frame decoded
    resent: int = 0  # stored, not decoded: a retransmission, its packets stored from an earlier frame
    missing: list[str] = field(default_factory=list)  # published, not stored

    def line(self) -> str:
        waiting = self.heard - self.published
        named = ", ".join(self.missing[:SHOWN]) + (" ..." if len(self.missing) > SHOWN else "")
        return (
            f"{self.gateway}: {self.heard} frames heard, {self.published} published"
            + (f" ({waiting} waiting in its outbox)" if waiting else "")
            + f"; center: {self.stored} stored ({self.merged} merged with another gateway's copy), "
            f"{self.decoded} decoded"
            + (f", {self.resent} resent (their packets stored before)" if self.resent else "")
            + (f"; HEARD BUT NOT STORED: {len(self.missing)} ({named})" if self.missing else "")
        )


def outbox_frames(path: Path) -> dict[str, list[tuple[str, bool]]]:
    """The frame messages an outbox file holds, by gateway: (message id, published). Their subjects are
    ``tacit.v1.frames.<gateway>.<partition>`` (or ``tacit.v1.frames.<gateway>``, the previous wire's, in
    an outbox not opened since): the gateway is the token after the prefix."""
    if not path.is_file():
        raise FileNotFoundError(f"no outbox file {path}")
    with contextlib.closing(sqlite3.connect(path)) as db:  # not read-only: a WAL file's reader may write
        rows = db.execute(
            "SELECT subject, id, published FROM outbox WHERE subject LIKE ? ORDER BY seq",
            (subjects.frames(">").removesuffix(">") + "%",),
        ).fetchall()
    out: dict[str, list[tuple[str, bool]]] = {}
    depth = subjects.frames(">").count(".")  # the gateway's token
    for subject, message_id, published in rows:
        out.setdefault(subject.split(".")[depth], []).append((message_id, bool(published)))
    return out


def audit(outboxes: Sequence[Path], database_url: str) -> list[Count]:
    """Each gateway's count, from its outbox file and the center's database."""
    frames: dict[str, list[tuple[str, bool]]] = {}
    for path in outboxes:
        for gateway, held in outbox_frames(path).items():
            frames.setdefault(gateway, []).extend(held)
    engine = make_engine(database_url)
    try:
        with reading(engine) as s:
            return [_count(s, gateway, held) for gateway, held in sorted(frames.items())]
    finally:
        engine.dispose()


def _count(s: Tx, gateway: str, held: list[tuple[str, bool]]) -> Count:
    count = Count(gateway, heard=len(held), published=sum(p for _, p in held))
    published = [message_id for message_id, p in held if p]
    stored = repository.frame_ids(s, published)
    frame_ids = sorted({f for f in stored.values() if f is not None})
    copies, decoded = repository.copy_counts(s, frame_ids), telemetry.decoded_frames(s, frame_ids)
    count.missing = [m for m in published if m not in stored]
    count.stored = len(stored)
    count.merged = sum(copies.get(f, 0) > 1 for f in stored.values() if f is not None)
    count.decoded = sum(f in decoded for f in stored.values() if f is not None)
    resent = telemetry.resent_frames(s, [f for f in frame_ids if f not in decoded])
    count.resent = sum(f in resent for f in stored.values() if f is not None)
    return count


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--outbox", type=Path, action="append", required=True, help="a gateway's outbox file (repeat)"
    )
    parser.add_argument("--database-url", required=True, help="the center's database")


def run(args: argparse.Namespace) -> int:
    try:
        counts = audit(args.outbox, args.database_url)
    except FileNotFoundError as exc:
        print(f"tacit backhaul-audit: {exc}", file=sys.stderr)
        return 2
    for count in counts:
        print(count.line())
    return 1 if any(c.missing for c in counts) else 0
