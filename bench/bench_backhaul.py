"""The split shore under load: scripted gateways feeding one center through NATS JetStream into
PostgreSQL (issue 24, item 7).

A nats-server of its own (the users and permissions of ``tacit broker-config``, on a free port), a fresh
PostgreSQL database, N vehicles with their keys, spread over G gateways. Each vehicle's frames are real:
check-points signed and IMU priority packets from the codec, as the agent sends them
(``bench_server.frames``). Two phases, timed apart:

1. *publish*: each gateway publishes its vehicles' frames (interleaved, in order per vehicle), one at a
   time and each acknowledged by JetStream before the next, as a gateway's outbox publisher does;
2. *center*: ``tacit center``'s consumer takes the backlog from the stream, stores, de-duplicates,
   decodes and verifies every frame in PostgreSQL, batch by batch, while R API readers (processes) read
   the API of a server on the same database. Profiled (cProfile, the consumer's loop and its ingest
   thread together): where the time goes.

The figure is checked to be of accepted frames: every frame stored once, every check-point verified,
no packet refused, every priority packet vouched for; otherwise the benchmark stops with the counts.

Run: .venv/bin/python bench/bench_backhaul.py [--vehicles 100] [--gateways 10] [--frames 50]
     [--readers 4] [--batch 64] [--database-url postgresql+psycopg://postgres@127.0.0.1:5432/test]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import cProfile
import io
import multiprocessing
import os
import pstats
import shutil
import socket
import statistics
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator
from multiprocessing.queues import Queue
from multiprocessing.synchronize import Event as Flag
from pathlib import Path

import uvicorn
from bench_server import TOKEN, check_measured, client_process, frames
from sqlalchemy import create_engine, text
from tqdm import tqdm

from launch.split import throwaway_database
from server.app import create_app
from server.backhaul import access, subjects
from server.backhaul.broker import connect
from server.backhaul.center import Center
from server.backhaul.relay import RelayIngest
from server.backhaul.subjects import FrameMessage
from server.core.config import Settings
from server.core.db import make_engine, migrate
from server.core.events import Bus, Event
from server.link.state import IncomingFrame
from server.vehicles.schemas import VehicleIn
from server.vehicles.service import Vehicles
from tacit.streams import default_streams

POSTGRES = os.environ.get("TACIT_TEST_POSTGRES", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def broker(folder: Path, gateways: list[str]) -> Iterator[str]:
    """A nats-server with the configuration ``tacit broker-config`` writes; its URL."""
    port = free_port()
    access.write(folder, gateways, f"127.0.0.1:{port}", str(folder / "jetstream"))
    server = shutil.which("nats-server") or "/usr/sbin/nats-server"
    proc = subprocess.Popen(
        [server, "-c", str(folder / "nats-server.conf")], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        for _ in range(200):
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=0.2):
                break
            time.sleep(0.05)
        yield f"nats://127.0.0.1:{port}"
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def fleet(
    url: str, vehicles: int, per_vehicle: int, gateways: int
) -> tuple[dict[str, list[FrameMessage]], int]:
    """The vehicles in the store and their frames, by gateway (vehicle ``a`` on gateway ``a % G``, its
    frames interleaved with the others' in order); and how many check-points they hold."""
    service = Vehicles(make_engine(url))
    by_gateway: dict[str, list[list[bytes]]] = {f"gw{g}": [] for g in range(gateways)}
    addresses: dict[str, list[int]] = {name: [] for name in by_gateway}
    checkpoints = 0
    for address in tqdm(range(1, vehicles + 1), desc="vehicles' frames", unit="vehicle"):
        key = bytes.fromhex(service.create(VehicleIn(name=f"auv{address}", address=address)).key_hex)
        made, cps = frames(per_vehicle, 0.5, key, address, progress=False)
        gateway = f"gw{address % gateways}"
        by_gateway[gateway].append(made)
        addresses[gateway].append(address)
        checkpoints += cps
    at = time.time()
    out: dict[str, list[FrameMessage]] = {}
    for name, streams in by_gateway.items():
        rounds = max((len(s) for s in streams), default=0)
        out[name] = [
            FrameMessage(f"{name}-bench-{n}", name, address, 0, data, rate=1, snr_in=10.0, at=at + r)
            for n, (r, address, data) in enumerate(
                (r, address, s[r])
                for r in range(rounds)
                for address, s in zip(addresses[name], streams, strict=True)
                if r < len(s)
            )
        ]
    return out, checkpoints


async def publish(url: str, folder: Path, name: str, messages: list[FrameMessage]) -> None:
    """One scripted gateway: each message acknowledged by JetStream before the next (as the outbox's)."""
    nc = await connect(url, f"bench-{name}", auth=access.BrokerAuth.load(folder / f"gateway-{name}.toml"))
    js = nc.jetstream()
    for m in messages:
        await js.publish(subjects.frames(name), m.encode(), headers={subjects.MSG_ID: m.id})
    await nc.close()


def serve_api(url: str, port: int) -> None:
    """The API on the center's database, in its own process (the readers' server)."""
    app = create_app(Settings(database_url=url, map_enabled=False, write_tokens=[TOKEN]))
    uvicorn.run(app, host="127.0.0.1", port=port, log_level="warning")


def readers(url: str, count: int) -> tuple[list[multiprocessing.Process], Flag, Queue[list[float]]]:
    """The API's server and ``count`` readers, in processes of their own."""
    port = free_port()
    procs = [multiprocessing.Process(target=serve_api, args=(url, port), daemon=True)]
    procs[0].start()
    for _ in range(200):
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=0.2):
            break
        time.sleep(0.05)
    stop: Flag = multiprocessing.Event()
    results: Queue[list[float]] = multiprocessing.Queue()
    procs += [
        multiprocessing.Process(target=client_process, args=(port, stop, results)) for _ in range(count)
    ]
    for p in procs[1:]:
        p.start()
    return procs, stop, results


class Profiled:
    """cProfile of the event loop's thread and of the ingest's worker threads, merged."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.main = cProfile.Profile()
        self.workers: list[cProfile.Profile] = []
        self._local = threading.local()

    def wrap(self, ingest: RelayIngest) -> None:
        if not self.enabled:
            return
        handle = ingest.handle_batch

        def profiled(batch: list[IncomingFrame]) -> list[Event]:
            prof = getattr(self._local, "prof", None)
            if prof is None:
                prof = self._local.prof = cProfile.Profile()
                self.workers.append(prof)
            result: list[Event] = prof.runcall(handle, batch)
            return result

        ingest.handle_batch = profiled  # type: ignore[method-assign,assignment]

    def top(self, n: int) -> str:
        """The ingest threads' functions by own time, then the pipeline's own functions by cumulative
        time (its stages), then the event loop's (the consumer: fetch, acks; ``poll`` is its waiting)."""
        out = io.StringIO()
        ingest = pstats.Stats(self.workers[0], stream=out)
        for prof in self.workers[1:]:
            ingest.add(prof)
        out.write("--- ingest (worker thread), by own time\n")
        ingest.sort_stats("tottime").print_stats(n)
        out.write("--- the pipeline's stages (server/, tacit/), by cumulative time\n")
        ingest.sort_stats("cumulative").print_stats(r"/(server|tacit)/", n)
        out.write("--- the consumer's event loop, by own time\n")
        pstats.Stats(self.main, stream=out).sort_stats("tottime").print_stats(max(5, n // 3))
        return out.getvalue()


async def consume(center: Center, total: int, profile: Profiled) -> float:
    """The center takes the whole backlog; the seconds it took."""
    await center.connect()
    bar = tqdm(total=total, desc="center", unit="frame")
    start = time.perf_counter()
    if profile.enabled:
        profile.main.enable()
    try:
        while center.counters["messages"] < total:
            bar.update(await center.step())
    finally:
        if profile.enabled:
            profile.main.disable()
        bar.close()
    elapsed = time.perf_counter() - start
    await center.close()
    return elapsed


def stored(url: str) -> int:
    with create_engine(url).connect() as c:
        return int(c.execute(text("SELECT count(*) FROM frame")).scalar_one())


def run(options: argparse.Namespace, url: str, folder: Path) -> None:
    migrate(url)
    names = [f"gw{g}" for g in range(options.gateways)]
    messages, checkpoints = fleet(url, options.vehicles, options.frames, options.gateways)
    total = sum(len(m) for m in messages.values())
    with broker(folder / "broker", names) as nats_url:
        settings = Settings(database_url=url)
        center = Center(RelayIngest(make_engine(url), Bus(), default_streams(), settings), nats_url,
                        batch=options.batch, auth=access.BrokerAuth.load(folder / "broker" / "center.toml"))  # fmt: skip
        center.ingest.load_vehicles()
        profile, latencies = Profiled(options.profile), list[float]()
        profile.wrap(center.ingest)

        async def phases() -> tuple[float, float]:
            await center.connect()  # the streams
            await center.close()
            start = time.perf_counter()
            await asyncio.gather(*(publish(nats_url, folder / "broker", n, m) for n, m in messages.items()))
            published = time.perf_counter() - start
            procs, stop, results = readers(url, options.readers) if options.readers else ([], None, None)
            try:
                return published, await consume(center, total, profile)
            finally:
                if stop is not None and results is not None:
                    stop.set()
                    latencies.extend(x for _ in procs[1:] for x in results.get(timeout=30))
                for p in procs:
                    p.terminate()

        published, consumed = asyncio.run(phases())
    report(options, center, url, total, checkpoints, published, consumed, sorted(latencies))
    if options.profile:
        print(f"\nwhere the center's time goes (cProfile, top {options.top}; profiling slows it):")
        print(profile.top(options.top))


def report(options: argparse.Namespace, center: Center, url: str, total: int, checkpoints: int,
           published: float, consumed: float, latencies: list[float]) -> None:  # fmt: skip
    stats = center.ingest.stats
    if stored(url) != total or stats["packets"] != total:
        raise SystemExit(
            f"bench_backhaul: {stored(url)} of {total} frames stored, {stats['packets']} decoded"
        )
    check_measured(stats, checkpoints, url)
    print(
        f"\n{options.vehicles} vehicles on {options.gateways} gateways, {total} frames (half priority, "
        f"{checkpoints} check-points), PostgreSQL, batches of {options.batch}; "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    print(
        f"publish: {total / published:,.0f} frames/s into JetStream ({options.gateways} gateways, each acked)"
    )
    print(
        f"center: {total / consumed:,.0f} frames/s consumed, stored, decoded and verified "
        f"({stats['verified']} check-points verified, {stats['packets']} packets, {consumed:.1f} s)"
    )
    if len(latencies) >= 2:
        q = statistics.quantiles(latencies, n=100)
        print(
            f"API meanwhile ({options.readers} readers, {len(latencies)} requests): p50 {q[49] * 1000:.1f} ms  "
            f"p95 {q[94] * 1000:.1f} ms  p99 {q[98] * 1000:.1f} ms"
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--vehicles", type=int, default=100, help="1 to 127: a modem address each")
    parser.add_argument("--gateways", type=int, default=10)
    parser.add_argument("--frames", type=int, default=50, help="frames per vehicle")
    parser.add_argument(
        "--readers", type=int, default=4, help="API readers (processes) while the center works"
    )
    parser.add_argument("--batch", type=int, default=64, help="frames per fetch and commit")
    parser.add_argument("--top", type=int, default=20, help="cProfile entries printed")
    parser.add_argument(
        "--no-profile", dest="profile", action="store_false", help="measure without cProfile (it costs time)"
    )
    parser.add_argument(
        "--database-url", default=POSTGRES, help="a PostgreSQL server: a fresh database on it"
    )
    options = parser.parse_args()
    if not 1 <= options.vehicles <= 127:
        parser.error("--vehicles: 1 to 127 (the modems' addresses)")
    with tempfile.TemporaryDirectory() as tmp, throwaway_database(options.database_url, "tacit_bench") as url:
        run(options, url, Path(tmp))


if __name__ == "__main__":
    main()
