"""The split shore under load: scripted gateways feeding the center through NATS JetStream into
PostgreSQL (issue 24, item 7), with one center process or several sharing the partitions.

A nats-server of its own (the users and permissions of ``tacit broker-config``, on a free port), a fresh
PostgreSQL database, N vehicles with their keys, spread over G gateways. Each vehicle's frames are real:
check-points signed and IMU priority packets from the codec, as the agent sends them
(``bench_server.frames``). Two phases, timed apart:

1. *publish*: each gateway publishes its vehicles' frames (interleaved, in order per vehicle), one at a
   time and each acknowledged by JetStream before the next, as a gateway's outbox publisher does;
2. *center*: C center processes (``--centers``, each ``tacit center``'s consumers: ``Center.run`` with
   its leases, its share of the partitions, its live events relayed to the others) take the backlog from
   the stream, store, de-duplicate, decode and verify every frame in PostgreSQL, batch by batch, while R
   API readers (processes) read the API of a server on the same database. The clock runs from when every
   center process is announced among the others (so that none takes a partition it would hand over)
   until every frame is stored and decoded. Profiled (cProfile, the first process's loop and its ingest
   thread together): where the time goes.

The figure is checked to be of accepted frames: every frame stored once, every check-point verified,
no packet refused, every priority packet vouched for; otherwise the benchmark stops with the counts.
``--centers 1 2`` runs both on the same frames (a fresh database and broker each) and prints what the
second process added.

Run (from bench/): ../.venv/bin/python bench_backhaul.py [--vehicles 100] [--gateways 10] [--frames 50]
     [--readers 4] [--batch 64] [--centers 1 2] [--no-profile]
     [--database-url postgresql+psycopg://postgres@127.0.0.1:5432/test]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import cProfile
import io
import math
import multiprocessing
import os
import pstats
import secrets
import shutil
import socket
import statistics
import subprocess
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from multiprocessing.queues import Queue
from multiprocessing.synchronize import Event as Flag
from pathlib import Path

import uvicorn
from bench_server import TOKEN, check_measured, client_process, frames
from sqlalchemy import Engine, create_engine, text
from tqdm import tqdm

from launch.split import throwaway_database
from server.app import create_app
from server.backhaul import access, subjects
from server.backhaul.broker import connect, ensure_streams
from server.backhaul.center import DURABLE, Center
from server.backhaul.leases import Leases
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
LEASE = 5.0  # s: the center processes' leases (the setting's default)
SPACING = 25.0  # m between the simulated vehicles' places, north and east: none within the separation


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
    vehicles: int, per_vehicle: int, gateways: int
) -> tuple[dict[int, bytes], dict[str, list[FrameMessage]], int]:
    """The vehicles' keys by modem address and their frames, by gateway (vehicle ``a`` on gateway
    ``a % G``, its frames interleaved with the others' in order); and how many check-points they hold.
    Made once for every run of ``--centers``."""
    keys = {address: secrets.token_bytes(32) for address in range(1, vehicles + 1)}
    by_gateway: dict[str, list[list[bytes]]] = {f"gw{g}": [] for g in range(gateways)}
    addresses: dict[str, list[int]] = {name: [] for name in by_gateway}
    checkpoints = 0
    for address, key in tqdm(keys.items(), desc="vehicles' frames", unit="vehicle"):
        apart = (SPACING * (address // 100), SPACING * (address % 100))  # no separation warnings
        made, cps = frames(per_vehicle, 0.5, key, address, progress=False, place=apart)
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
    return keys, out, checkpoints


def register(url: str, keys: dict[int, bytes]) -> None:
    service = Vehicles(make_engine(url))
    for address, key in keys.items():
        service.create(VehicleIn(name=f"auv{address}", address=address, key=key.hex()))


async def publish(url: str, folder: Path, name: str, messages: list[FrameMessage]) -> None:
    """One scripted gateway: each message acknowledged by JetStream before the next (as the outbox's)."""
    nc = await connect(url, f"bench-{name}", auth=access.BrokerAuth.load(folder / f"gateway-{name}.toml"))
    js = nc.jetstream()
    for m in messages:
        subject = subjects.frames(name, subjects.partition(m.src))
        await js.publish(subject, m.encode(), headers={subjects.MSG_ID: m.id})
    await nc.close()


async def publish_all(url: str, folder: Path, messages: dict[str, list[FrameMessage]]) -> float:
    """The streams made (as a center makes them), then every gateway's frames; the seconds it took."""
    nc = await connect(url, "bench-center", auth=access.BrokerAuth.load(folder / "center.toml"))
    await ensure_streams(nc.jetstream())
    await nc.close()
    start = time.perf_counter()
    await asyncio.gather(*(publish(url, folder, n, m) for n, m in messages.items()))
    return time.perf_counter() - start


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
        if not self.workers:
            return ""
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


@dataclass(frozen=True)
class CenterJob:
    """What a center process of the benchmark needs (picklable: it is spawned)."""

    url: str
    nats_url: str
    credentials: Path
    name: str
    count: int  # center processes in all
    batch: int
    profile: bool
    top: int


async def announce(job: CenterJob, auth: access.BrokerAuth) -> None:
    """This process among the center's members, and all ``count`` of them there: each process's first
    share of the partitions is then its final one (no hand-over while the clock runs)."""
    nc = await connect(job.nats_url, f"bench-{job.name}", auth=auth)
    leases = Leases(nc.jetstream(), DURABLE, job.name, LEASE)
    await leases.open()
    await leases.renew()
    while len(await leases.members()) < job.count:
        await asyncio.sleep(0.05)
        await leases.renew()
    await nc.close()


def center_process(
    job: CenterJob, ready: Queue[str], stop: Flag, results: Queue[tuple[dict[str, int], str]]
) -> None:
    """One ``tacit center`` process's consumers (``Center.run``: leases, its partitions, its live events
    relayed), until ``stop``; then its ingest's counters and, profiled, where its time went."""
    auth = access.BrokerAuth.load(job.credentials)
    ingest = RelayIngest(make_engine(job.url), Bus(), default_streams(), Settings(database_url=job.url))
    center = Center(ingest, job.nats_url, batch=job.batch, auth=auth, instance=job.name, lease=LEASE)
    profile = Profiled(job.profile)
    profile.wrap(ingest)

    async def main() -> None:
        ingest.bus.bind(asyncio.get_running_loop())  # its events relayed to the other processes, as live
        await announce(job, auth)
        ready.put(job.name)
        task = asyncio.create_task(center.run())
        if profile.enabled:
            profile.main.enable()
        while not stop.is_set():
            await asyncio.sleep(0.1)
        if profile.enabled:
            profile.main.disable()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)

    asyncio.run(main())
    results.put((dict(ingest.stats), profile.top(job.top)))


def decoded(db: Engine) -> int:
    with db.connect() as c:
        return int(c.execute(text("SELECT count(*) FROM packet")).scalar_one())


def centers(
    options: argparse.Namespace, count: int, url: str, nats_url: str, folder: Path, total: int
) -> tuple[float, list[tuple[dict[str, int], str]]]:
    """``count`` center processes take the backlog; the seconds from their start until every frame was
    stored and decoded, and each one's counters and profile."""
    spawn = multiprocessing.get_context("spawn")  # a fresh interpreter, as ``tacit center`` is
    ready: Queue[str] = spawn.Queue()
    results: Queue[tuple[dict[str, int], str]] = spawn.Queue()
    stop: Flag = spawn.Event()
    jobs = [
        CenterJob(url, nats_url, folder / "center.toml", f"bench{i}", count, options.batch,
                  options.profile, options.top)
        for i in range(count)
    ]  # fmt: skip
    procs = [spawn.Process(target=center_process, args=(job, ready, stop, results)) for job in jobs]
    for p in procs:
        p.start()
    for _ in procs:
        ready.get(timeout=120)
    db = create_engine(url)  # one connection, polled: not one started every 0.1 s
    start = time.perf_counter()
    bar = tqdm(total=total, desc=f"{count} center process(es)", unit="frame")
    while (done := decoded(db)) < total:
        bar.update(done - bar.n)
        if not all(p.is_alive() for p in procs):
            raise SystemExit("bench_backhaul: a center process died")
        time.sleep(0.1)
    elapsed = time.perf_counter() - start
    bar.update(done - bar.n)
    bar.close()
    stop.set()
    out = [results.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(timeout=30)
    db.dispose()
    return elapsed, out


def stored(url: str) -> int:
    with create_engine(url).connect() as c:
        return int(c.execute(text("SELECT count(*) FROM frame")).scalar_one())


@dataclass
class Figures:
    centers: int
    published: float  # s
    consumed: float  # s
    latencies: list[float]
    stats: Counter[str]


def run(
    options: argparse.Namespace,
    count: int,
    keys: dict[int, bytes],
    messages: dict[str, list[FrameMessage]],
    checkpoints: int,
    url: str,
    folder: Path,
) -> Figures:
    migrate(url)
    register(url, keys)
    total = sum(len(m) for m in messages.values())
    latencies = list[float]()
    with broker(folder / "broker", list(messages)) as nats_url:
        published = asyncio.run(publish_all(nats_url, folder / "broker", messages))
        procs, stop, results = readers(url, options.readers) if options.readers else ([], None, None)
        try:
            consumed, out = centers(options, count, url, nats_url, folder / "broker", total)
        finally:
            if stop is not None and results is not None:
                stop.set()
                latencies.extend(x for _ in procs[1:] for x in results.get(timeout=30))
            for p in procs:
                p.terminate()
                p.join(timeout=10)  # before its database is dropped
    stats: Counter[str] = Counter()
    for each, _ in out:
        stats.update(each)
    figures = Figures(count, published, consumed, sorted(latencies), stats)
    report(options, figures, [each for each, _ in out], url, total, checkpoints)
    if options.profile:
        print(
            f"\nwhere the first center process's time goes (cProfile, top {options.top}; profiling slows it):"
        )
        print(out[0][1])
    return figures


def p99(latencies: list[float]) -> float:
    return statistics.quantiles(latencies, n=100)[98] * 1000 if len(latencies) >= 2 else math.nan


def report(
    options: argparse.Namespace,
    figures: Figures,
    each: list[dict[str, int]],
    url: str,
    total: int,
    checkpoints: int,
) -> None:
    stats = figures.stats
    if stored(url) != total or stats["packets"] != total:
        raise SystemExit(
            f"bench_backhaul: {stored(url)} of {total} frames stored, {stats['packets']} decoded"
        )
    check_measured(stats, checkpoints, url)
    print(
        f"\n{options.vehicles} vehicles on {options.gateways} gateways, {total} frames ({total - checkpoints} "
        f"priority, {checkpoints} check-points), PostgreSQL, batches of {options.batch}, {figures.centers} center "
        f"process(es); load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    print(
        f"publish: {total / figures.published:,.0f} frames/s into JetStream ({options.gateways} gateways, "
        "each acked)"
    )
    shares = ", ".join(str(s["packets"]) for s in each)
    print(
        f"center: {total / figures.consumed:,.0f} frames/s consumed, stored, decoded and verified "
        f"({stats['verified']} check-points verified, {stats['packets']} packets decoded: {shares} by "
        f"process; {figures.consumed:.1f} s)"
    )
    if len(figures.latencies) >= 2:
        q = statistics.quantiles(figures.latencies, n=100)
        print(
            f"API meanwhile ({options.readers} readers, {len(figures.latencies)} requests): p50 "
            f"{q[49] * 1000:.1f} ms  p95 {q[94] * 1000:.1f} ms  p99 {q[98] * 1000:.1f} ms"
        )


def compare(runs: list[Figures], total: int) -> None:
    """What each further center process added to the first run's."""
    first = runs[0]
    print("\ncenter processes: frames/s stored and decoded, API p99 (ms)")
    for figures in runs:
        rate = total / figures.consumed
        gain = rate / (total / first.consumed) - 1
        print(f"  {figures.centers}: {rate:,.0f} frames/s ({gain:+.0%}), p99 {p99(figures.latencies):.0f} ms")


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
    parser.add_argument(
        "--centers",
        type=int,
        nargs="+",
        default=[1],
        help="center processes sharing the partitions; several values: a run with each, on the same "
        "frames, then what each added (default 1)",
    )
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
    if not all(1 <= n <= subjects.PARTITIONS for n in options.centers):
        parser.error(f"--centers: 1 to {subjects.PARTITIONS} (the frames partitions)")
    keys, messages, checkpoints = fleet(options.vehicles, options.frames, options.gateways)
    runs = []
    for count in options.centers:
        with (
            tempfile.TemporaryDirectory() as tmp,
            throwaway_database(options.database_url, "tacit_bench") as url,
        ):
            runs.append(run(options, count, keys, messages, checkpoints, url, Path(tmp)))
    if len(runs) > 1:
        compare(runs, sum(len(m) for m in messages.values()))


if __name__ == "__main__":
    main()
