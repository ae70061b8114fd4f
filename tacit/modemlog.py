"""Modem logs: every NMEA sentence to and from a Micro-Modem, time-stamped, one per line.

Written by the driver as ``<ISO-8601 UTC time> <dir> <sentence>`` where ``dir`` is ``>`` for host ->
modem and ``<`` for modem -> host, so a field engineer can replay or grep a session. The reader also
takes bare sentences (no time, no direction), as captured by a terminal program, and lines in
goby's ``[time] dir sentence`` style loosely: anything before the ``$`` is treated as a prefix.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from tacit import nmea, packets
from tacit.link import from_frame
from tacit.packets import PACKET_SIZE

TO_MODEM = ">"
FROM_MODEM = "<"


class ModemLog:
    """Appends sentences to a log file, flushed line by line (a crash loses nothing written)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: TextIO = self.path.open("a", encoding="ascii", errors="backslashreplace")
        self._lock = threading.Lock()

    def write(self, direction: str, line: str) -> None:
        stamp = dt.datetime.now(dt.UTC).isoformat(timespec="microseconds").replace("+00:00", "Z")
        text = line.rstrip("\r\n")
        with self._lock:
            self._file.write(f"{stamp} {direction} {text}\n")
            self._file.flush()

    def close(self) -> None:
        with self._lock:
            self._file.close()


@dataclass(frozen=True)
class LogEntry:
    number: int
    time: str | None
    direction: str | None
    text: str


def read_entries(lines: Iterator[str]) -> Iterator[LogEntry]:
    """Split each log line into time, direction and sentence text (blank lines are skipped)."""
    for number, raw in enumerate(lines, start=1):
        line = raw.rstrip("\r\n")
        if not line.strip():
            continue
        prefix, dollar, rest = line.partition("$")
        if not dollar:
            yield LogEntry(number, None, None, line)
            continue
        words = prefix.replace("[", " ").replace("]", " ").split()
        direction = next((w for w in words if w in (TO_MODEM, FROM_MODEM)), None)
        stamp = next((w for w in words if w not in (TO_MODEM, FROM_MODEM)), None)
        yield LogEntry(number, stamp, direction, "$" + rest)


def describe(entry: LogEntry) -> dict[str, object]:
    """Decode one log entry: the sentence, and the Tacit packet in its data if it carries one."""
    out: dict[str, object] = {"line": entry.number}
    if entry.time:
        out["time"] = entry.time
    if entry.direction:
        out["direction"] = "to_modem" if entry.direction == TO_MODEM else "from_modem"
    try:
        sentence = nmea.parse(entry.text)
    except nmea.NmeaError as exc:
        out["error"] = str(exc)
        out["text"] = entry.text
        return out
    if isinstance(sentence, nmea.Raw):
        out.update(sentence=sentence.talker + sentence.sid, fields=list(sentence.fields))
        return out
    talker = entry.text[1:3]
    out["sentence"] = talker + sentence.SID
    fields: dict[str, object] = {}
    for name, value in vars(sentence).items():
        fields[name] = value.hex() if isinstance(value, bytes) else value
    out["fields"] = fields
    data = getattr(sentence, "data", None)
    if isinstance(data, bytes) and data:
        out["packets"] = describe_frame(data)
    return out


def describe_frame(data: bytes) -> list[dict[str, object]]:
    """The Tacit packets in a frame, split as the link splits them (a rate-1 or rate-5 frame carries
    several), each decoded or with the reason it is not a packet."""
    found: list[dict[str, object]] = [_describe_packet(chunk) for chunk in from_frame(data)]
    if len(data) % PACKET_SIZE:
        found.append({"error": f"{len(data)} bytes is not a whole number of {PACKET_SIZE}-byte packets"})
    return found or [{"error": "no packet: the frame is all padding"}]


def _describe_packet(chunk: bytes) -> dict[str, object]:
    try:
        return packets.as_dict(packets.decode(chunk))
    except packets.PacketError as exc:
        return {"error": str(exc)}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="a modem log (time-stamped as the driver writes it, or bare NMEA)")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")


def _human(entry: dict[str, object]) -> str:
    head = f"{entry['line']:>6} {entry.get('time', '-')} {DIRECTIONS.get(str(entry.get('direction')), ' ')}"
    if "error" in entry:
        return f"{head} ERROR {entry['error']}: {entry.get('text', '')}"
    fields = entry.get("fields")
    shown = " ".join(f"{k}={v}" for k, v in fields.items()) if isinstance(fields, dict) else fields
    text = f"{head} {entry['sentence']} {shown}"
    for packet in entry.get("packets") or []:  # type: ignore[attr-defined]
        text += f"\n{'':>8}packet: {json.dumps(packet)}"
    return text


DIRECTIONS = {"to_modem": TO_MODEM, "from_modem": FROM_MODEM}


def run(args: argparse.Namespace) -> int:
    try:
        handle = open(args.file, encoding="ascii", errors="backslashreplace")
    except OSError as exc:
        print(f"tacit modem-log: cannot read {args.file}: {exc.strerror}", file=sys.stderr)
        return 1
    counts = {"sentences": 0, "errors": 0, "packets": 0}
    with handle:
        for entry in read_entries(handle):
            decoded = describe(entry)
            counts["errors" if "error" in decoded else "sentences"] += 1
            found: list[dict[str, object]] = decoded.get("packets", [])  # type: ignore[assignment]
            counts["packets"] += sum("error" not in packet for packet in found)
            print(json.dumps(decoded) if args.json else _human(decoded))
    if not args.json:
        print(
            f"{counts['sentences']} sentences, {counts['packets']} packets, {counts['errors']} malformed lines"
        )
    return 0
