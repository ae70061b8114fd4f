"""The shore under load while the link runs: many API clients writing and reading at once.

The whole system runs as processes (simulator, ``tacit serve``, agent on the square mission, so the
link keeps ingesting); N client threads, each with its own connection, write (record a mission, change
a vehicle's limits), queue commands for a vehicle that is not in the water and read (packets,
telemetry, link status, commands) as fast as the server answers, for a fixed time. Printed: requests,
errors (anything but a 2xx, or for a command the 429 of the full queue), latency percentiles, and the
ingest rate of what the vehicle sent meanwhile. The goal: 0 errors (never a 500 "database is locked").
Commands never leave for a vehicle ashore, so its queue fills at the server's cap
(``max_queued_commands``) and every later POST is refused by it: those are counted as refused, apart.

Run: .venv/bin/python bench/bench_load.py [--clients 50] [--seconds 60]
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
import threading
import time

import httpx
from tqdm import tqdm

from launch.rig import TOKEN, Rig
from server.core.config import Settings

KINDS = ("write", "command", "read")
READS = ["/packets?limit=50", "/telemetry?limit=200", "/link", "/vehicles/1/commands?limit=20", "/vehicles"]


def client(base: str, stop: threading.Event, seed: int, out: list[tuple[str, int, float]]) -> None:
    """One API client: its own connection, a mix of writes and reads until ``stop``."""
    rng = random.Random(seed)
    with httpx.Client(base_url=base, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60) as http:
        while not stop.is_set():
            kind = rng.choices(KINDS, weights=(4, 1, 5))[0]  # the mix of the earlier runs: 40/10/50 %
            call = {"write": _write, "command": _command, "read": _read}[kind]
            started = time.perf_counter()
            try:
                code = call(http, rng)
            except httpx.HTTPError:
                code = 0
            out.append((kind, code, time.perf_counter() - started))


def _write(http: httpx.Client, rng: random.Random) -> int:
    if rng.random() < 0.5:
        body = {
            "name": "survey",
            "number": rng.randint(2, 200),
            "waypoints": [{"north": 5, "east": 5, "depth": 1}],
        }
        return http.post("/vehicles/2/missions", json=body).status_code
    return http.put("/vehicles/2/limits", json={"max_depth": rng.uniform(10, 50)}).status_code


def _command(http: httpx.Client, rng: random.Random) -> int:
    return http.post("/vehicles/2/commands", json={"command": "goto_depth", "depth": 1.0}).status_code


def _read(http: httpx.Client, rng: random.Random) -> int:
    return http.get(rng.choice(READS)).status_code


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--clients", type=int, default=50)
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    rig = Rig(200.0, scale=5.0, mission=True)
    try:
        rig.http.post("/vehicles", json={"name": "ashore", "address": 9}).raise_for_status()
        rig.start_square()
        before = rig.http.get("/link").json()["ingest"]
        out: list[tuple[str, int, float]] = []
        stop = threading.Event()
        base = str(rig.http.base_url)
        threads = [threading.Thread(target=client, args=(base, stop, i, out)) for i in range(args.clients)]
        for thread in threads:
            thread.start()
        for _ in tqdm(range(int(args.seconds)), desc=f"{args.clients} clients", unit="s"):
            time.sleep(1.0)
        stop.set()
        for thread in threads:
            thread.join()
        after = rig.http.get("/link").json()["ingest"]
        report(out, args, before, after)
    finally:
        rig.close()
    failed = sum(_error(kind, code) for kind, code, _ in out)
    accepted = sum(kind == "write" and 200 <= code < 300 for kind, code, _ in out)
    if failed or not accepted or packets_meanwhile(before, after) == 0:
        print("FAILED: requests failed, no write was accepted or the link ingested nothing", file=sys.stderr)
        return 1
    return 0


def packets_meanwhile(before: dict, after: dict) -> int:
    return int(after["packets"] - before["packets"])


def _refused(kind: str, code: int) -> bool:
    return kind == "command" and code == 429


def _error(kind: str, code: int) -> bool:
    return not 200 <= code < 300 and not _refused(kind, code)


def report(out: list[tuple[str, int, float]], args: argparse.Namespace, before: dict, after: dict) -> None:
    print(f"\n{args.clients} clients for {args.seconds:.0f} s while the link ran the square mission")
    head = f"{'':>7} {'requests':>9} {'errors':>7} {'refused':>8} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8}"
    print(head)
    for kind in KINDS:
        rows = [(code, t) for k, code, t in out if k == kind]
        times = sorted(t * 1000 for _, t in rows)
        refused = sum(_refused(kind, code) for code, _ in rows)
        errors = sum(_error(kind, code) for code, _ in rows)
        p99 = times[min(len(times) - 1, int(0.99 * len(times)))] if times else float("nan")
        median = statistics.median(times) if times else float("nan")
        last = times[-1] if times else float("nan")
        print(f"{kind:>7} {len(rows):>9,} {errors:>7} {refused:>8,} {median:>8.1f} {p99:>8.1f} {last:>8.1f}")
    print(
        f"refused: a command beyond the vehicle's {Settings().max_queued_commands} waiting (429, by design)"
    )
    codes = sorted({code for kind, code, _ in out if _error(kind, code)})
    print(f"error codes: {codes or 'none'}")
    frames = after["frames"] - before["frames"]
    packets = packets_meanwhile(before, after)
    print(
        f"ingest meanwhile: {frames} frames, {packets} packets ({packets / args.seconds:.2f} packets/s, "
        f"as fast as the simulated acoustic link delivers them)"
    )


if __name__ == "__main__":
    sys.exit(main())
