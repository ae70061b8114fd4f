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
import os
import sys
import threading
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from tacit import auth, nmea, packets
from tacit.link import from_frame
from tacit.packets import PACKET_SIZE, ControlPacket, PriorityPacket
from tacit.private import open_private, private_dir

TO_MODEM = ">"
FROM_MODEM = "<"


class ModemLog:
    """Appends sentences to a log file, flushed line by line (a crash loses nothing written)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        private_dir(self.path.parent)
        self._file: IO[str] = open_private(self.path, "a", encoding="ascii", errors="backslashreplace")
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


UNVERIFIED, VERIFIED, FORGED = "unverified", "verified", "forged"


@dataclass
class LogVerifier:
    """Checks packets' MACs with the vehicle's key: a control packet alone; a check-point together with
    the priority packets it covers, the last ones with those seqs seen earlier in the log (the shore
    vouches for priority packets the same way). Without a key nothing read from a log is verified:
    anyone with a modem can transmit any 32 bytes."""

    key: bytes
    address: int
    priority: dict[int, bytes] = field(default_factory=dict)  # seq -> hash of the last one seen

    def check(self, chunk: bytes, packet: packets.Packet) -> tuple[str, str]:
        """(verified, forged or unverified; why)."""
        if isinstance(packet, PriorityPacket):
            if not auth.tag_matches(chunk, {0: self.key}, self.address):
                return FORGED, "its tag does not match the key"
            self.priority[packet.seq] = auth.packet_hash(chunk)
            return UNVERIFIED, "vouched for only by a later check-point's MAC"
        matches = f"MAC matches the key of vehicle {self.address}"
        try:
            if isinstance(packet, ControlPacket):
                auth.verify(chunk, self.key, self.address)
                return VERIFIED, matches
            seqs = packet.covered_seqs()
            covered = [[self.priority[s]] if s in self.priority else [] for s in seqs]
            auth.verify_checkpoint(packet, {packet.key_parity: self.key}, self.address, covered)
        except auth.Unverifiable as exc:
            return UNVERIFIED, str(exc)
        except auth.BadMac as exc:
            return FORGED, str(exc)
        return VERIFIED, matches + (f"; vouches for the priority packets with seqs {seqs}" if seqs else "")


def describe(entry: LogEntry, verifier: LogVerifier | None = None) -> dict[str, object]:
    """Decode one log entry: the sentence, and the Tacit packets in its data if it carries any."""
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
    if problem := nmea.modem_error(sentence):
        out["modem_error"] = problem
    data = getattr(sentence, "data", None)
    if isinstance(data, bytes) and data:
        out["packets"] = describe_frame(data, verifier)
    return out


def describe_frame(data: bytes, verifier: LogVerifier | None = None) -> list[dict[str, object]]:
    """The Tacit packets in a frame, split as the link splits them (a rate-1 or rate-5 frame carries
    several), each decoded and marked verified, forged or unverified, or with the reason it is not a
    packet."""
    found = [_describe_packet(chunk, verifier) for chunk in from_frame(data)]
    if len(data) % PACKET_SIZE:
        found.append(
            {
                "error": f"{len(data)} bytes is not a whole number of {PACKET_SIZE}-byte packets",
                "bytes": data[len(data) - len(data) % PACKET_SIZE :].hex(),
            }
        )
    return found or [{"error": "no packet: the frame is all padding"}]


def _describe_packet(chunk: bytes, verifier: LogVerifier | None) -> dict[str, object]:
    try:
        packet = packets.decode(chunk)
    except packets.PacketError as exc:
        return {"error": str(exc), "bytes": chunk.hex()}
    if verifier is None:
        status, why = UNVERIFIED, "no key given (--key): anyone with a modem can send these bytes"
    else:
        status, why = verifier.check(chunk, packet)
    return {**packets.as_dict(packet), "auth": status, "auth_detail": why}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="a modem log (time-stamped as the driver writes it, or bare NMEA)")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--key", help="the vehicle's key (hex): verify control packets and check-points")
    parser.add_argument("--address", type=int, help="the vehicle's modem address (with --key)")


def _human(entry: dict[str, object]) -> str:
    head = f"{entry['line']:>6} {entry.get('time', '-')} {DIRECTIONS.get(str(entry.get('direction')), ' ')}"
    if "error" in entry:
        return f"{head} ERROR {entry['error']}: {entry.get('text', '')}"
    fields = entry.get("fields")
    shown = " ".join(f"{k}={v}" for k, v in fields.items()) if isinstance(fields, dict) else fields
    text = f"{head} {entry['sentence']} {shown}"
    if "modem_error" in entry:
        text += f"  [modem error: {entry['modem_error']}]"
    for packet in entry.get("packets") or []:  # type: ignore[attr-defined]
        text += f"\n{'':>8}{_human_packet(packet)}"
    return text


def _human_packet(packet: dict[str, object]) -> str:
    if "error" in packet:
        return f"not a Tacit packet ({packet['error']}): {packet.get('bytes', '')}"
    shown = {k: v for k, v in packet.items() if k not in ("auth", "auth_detail")}
    return f"{str(packet['auth']).upper()} packet ({packet['auth_detail']}): {json.dumps(shown)}"


DIRECTIONS = {"to_modem": TO_MODEM, "from_modem": FROM_MODEM}


def _verifier(args: argparse.Namespace) -> LogVerifier | None:
    """The verifier for --key and --address; raises ``ValueError`` for a bad or lone option."""
    if args.key is None and args.address is None:
        return None
    if args.key is None or args.address is None or not 1 <= args.address <= 127:
        raise ValueError("--key HEX and --address N (the vehicle's modem address, 1-127) go together")
    return LogVerifier(auth.parse_key(args.key), args.address)


def run(args: argparse.Namespace) -> int:
    try:
        verifier = _verifier(args)
        handle = open(args.file, encoding="ascii", errors="backslashreplace")
    except ValueError as exc:
        print(f"tacit modem-log: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"tacit modem-log: cannot read {args.file}: {exc.strerror}", file=sys.stderr)
        return 1
    with handle:
        try:
            _print(read_entries(handle), verifier, args.json)
            sys.stdout.flush()
        except BrokenPipeError:
            return _reader_gone()
    return 0


def _print(entries: Iterator[LogEntry], verifier: LogVerifier | None, as_json: bool) -> None:
    counts: Counter[str] = Counter()
    errors: Counter[str] = Counter()
    for entry in entries:
        decoded = describe(entry, verifier)
        counts["malformed" if "error" in decoded else "sentences"] += 1
        if "modem_error" in decoded:
            errors[str(decoded["modem_error"])] += 1
        found: list[dict[str, object]] = decoded.get("packets", [])  # type: ignore[assignment]
        counts.update(str(packet.get("auth", "not_packets")) for packet in found)
        print(json.dumps(decoded) if as_json else _human(decoded))
    if not as_json:
        print(_summary(counts, errors))


def _reader_gone() -> int:
    """The reader of stdout left (``tacit modem-log LOG | head``): stop quietly with a SIGPIPE-killed
    command's status. stdout is pointed at /dev/null first, or Python's own flush at exit would fail
    on the closed pipe and print another error."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return 141


def _summary(counts: Counter[str], errors: Counter[str]) -> str:
    packets_seen = sum(counts[s] for s in (VERIFIED, FORGED, UNVERIFIED))
    marks = ", ".join(f"{counts[s]} {s}" for s in (VERIFIED, FORGED, UNVERIFIED) if counts[s])
    listed = ", ".join(f"{n} {kind}" for kind, n in sorted(errors.items()))
    return (
        f"{counts['sentences']} sentences, {packets_seen} packets"
        + (f" ({marks})" if marks else "")
        + f", {counts['not_packets']} not Tacit packets, {counts['malformed']} malformed lines, "
        f"{errors.total()} modem errors" + (f" ({listed})" if listed else "")
    )
