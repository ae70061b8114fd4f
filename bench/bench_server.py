"""The shore's ingest throughput and API latency under that load.

Frames (check-points and IMU priority packets, as a vehicle sends them) go through the link engine's
ingest (store, de-duplicate, decode, reconstruct, publish), not through a modem, as fast as one worker
can; meanwhile HTTP clients read the API of the real server (uvicorn, SQLite file) and we record the
latency of every request. ``--profile`` runs the ingest under cProfile and prints where a frame's
time goes (``bench/profiling.py``); its packets/s are then cProfile's, slower.

Run: .venv/bin/python bench/bench_server.py [--frames 5000] [--clients 4] [--database-url URL] [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import multiprocessing
import statistics
import tempfile
import threading
import time
from multiprocessing.queues import Queue

import httpx
import numpy as np
import uvicorn
from profiling import summary
from sqlmodel import Session, select
from tqdm import tqdm

from server.app import create_app
from server.core.config import Settings
from server.core.db import make_engine
from server.link.state import IncomingFrame
from server.telemetry.models import Packet, PacketTrust
from tacit import auth
from tacit.codec import PacketEncoder
from tacit.packets import CheckpointPacket, MissionState, cover_bitmap, with_seq
from tacit.streams import default_streams

TOKEN = "bench-token"
ADDRESS = 2


def frames(
    count: int,
    priority_share: float,
    key: bytes,
    address: int = ADDRESS,
    progress: bool = True,
    place: tuple[float, float] = (0.0, 0.0),
) -> tuple[list[bytes], int]:
    """Check-points and real codec output (a noisy IMU stream), in the order a vehicle sends them and
    signed as the agent signs them: each check-point covers the priority packets sent since the last one
    (a check-point is due before 12 are uncovered, as on the vehicle), its position ``place`` (north,
    east). Returns the frames and how many are check-points."""
    streams = list(default_streams().values())  # the server decodes every stream of a packet
    spec = streams[0]
    encoder = PacketEncoder(streams, max_latency=1.0)
    rng = np.random.default_rng(1)
    out: list[bytes] = []
    uncovered: list[tuple[int, bytes]] = []  # (seq, hash) of priority packets no check-point covered yet
    checkpoints = 0
    t0 = time.time() - 3600
    tick = 0
    bar = tqdm(total=count, desc="encoding frames", unit="frame", disable=not progress)
    while len(out) < count or uncovered:  # the last frame is a check-point: every packet is vouched for
        seq = len(out) % 256
        if rng.random() < priority_share and len(uncovered) < 12 and len(out) < count - 1:
            while not encoder.ready(t0 + tick * spec.period):
                encoder.push(0, t0 + tick * spec.period, rng.normal(0, 10, len(spec.channels)))
                tick += 1
            encoded = encoder.take()
            encoder.resolve(True)
            frame = auth.tag_priority(with_seq(encoded.packet, seq), key, address)
            uncovered.append((seq, auth.packet_hash(frame)))
        else:
            cp = CheckpointPacket(
                seq=seq,
                time=int(t0) + len(out),
                state=MissionState.PREPROGRAMMED,
                north=place[0],
                east=place[1],
                depth=float(len(out) % 100),
                temperature=20.0,
                covered=cover_bitmap(seq, [q for q, _ in uncovered]),
            )
            frame = auth.sign_checkpoint(cp, key, 1, address, [h for _, h in uncovered])
            uncovered, checkpoints = [], checkpoints + 1
        out.append(frame)
        bar.update()
    bar.close()
    return out, checkpoints


def check_measured(ingest_stats: dict[str, int], checkpoints: int, url: str) -> None:
    """The figure is of the accepted path only: every check-point verified, no packet refused, every
    priority packet vouched for; anything else stops the benchmark with the counts."""
    refused = {k: ingest_stats[k] for k in ("forged", "replayed", "unverifiable", "rejected")}
    engine = make_engine(url)
    with Session(engine) as s:
        pending = len(
            s.exec(
                select(Packet.id).where(Packet.type == "priority", Packet.auth != PacketTrust.VERIFIED)
            ).all()
        )
    engine.dispose()
    if any(refused.values()) or ingest_stats["verified"] != checkpoints or pending:
        raise SystemExit(
            f"bench_server: not the accepted path: {refused}, {ingest_stats['verified']} of "
            f"{checkpoints} check-points verified, {pending} priority packets not verified"
        )


def serve(app, port: int) -> uvicorn.Server:
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    threading.Thread(target=server.run, daemon=True).start()
    while not server.started:
        time.sleep(0.05)
    return server


def client_process(port: int, stop, results) -> None:
    """An API reader in its own process (as a browser would be), reporting its latencies at the end."""
    latencies: list[float] = []
    client_loop(port, stop, latencies)
    results.put(latencies)


def sse_process(port: int, stop, results) -> None:
    """A browser on the live event stream: counts the events it receives."""
    events = 0
    with (
        httpx.Client(
            base_url=f"http://127.0.0.1:{port}", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=None
        ) as http,
        http.stream("GET", "/api/v1/events") as stream,
    ):
        for line in stream.iter_lines():
            events += line.startswith("event:")
            if stop.is_set():
                break
    results.put(events)


def client_loop(port: int, stop, latencies: list[float]) -> None:
    headers = {"Authorization": f"Bearer {TOKEN}"}
    paths = ["/api/v1/packets?limit=20", "/api/v1/link", "/api/v1/vehicles", "/api/v1/telemetry?limit=50"]
    with httpx.Client(base_url=f"http://127.0.0.1:{port}", headers=headers, timeout=10) as http:
        i = 0
        while not stop.is_set():
            start = time.perf_counter()
            http.get(paths[i % len(paths)]).raise_for_status()
            latencies.append(time.perf_counter() - start)
            i += 1


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--frames", type=int, default=5000)
    parser.add_argument("--priority-share", type=float, default=0.5, help="fraction of priority packets")
    parser.add_argument("--clients", type=int, default=4, help="concurrent API readers (separate processes)")
    parser.add_argument("--batch", type=int, default=1, help="frames per group commit (1 = one at a time)")
    parser.add_argument("--sse-clients", type=int, default=3, help="browsers on the live event stream")
    parser.add_argument("--database-url", help="default: a SQLite file in a temporary folder")
    parser.add_argument("--port", type=int, default=8765)
    parser.add_argument("--profile", action="store_true", help="profile the ingest: where the time goes")
    options = parser.parse_args()
    url = options.database_url or f"sqlite:///{tempfile.mkdtemp()}/bench.db"
    app = create_app(Settings(database_url=url, map_enabled=False, write_tokens=[TOKEN]))
    server = serve(app, options.port)
    http = httpx.Client(
        base_url=f"http://127.0.0.1:{options.port}", headers={"Authorization": f"Bearer {TOKEN}"}
    )
    created = http.post("/api/v1/vehicles", json={"name": "bench", "address": ADDRESS})
    created.raise_for_status()
    made, checkpoints = frames(options.frames, options.priority_share, bytes.fromhex(created.json()["key"]))
    incoming = [IncomingFrame(ADDRESS, 1, f, 0, 30.0, 33.0, None) for f in made]

    stop = multiprocessing.Event()
    results: Queue[list[float]] = multiprocessing.Queue()
    clients = [
        multiprocessing.Process(target=client_process, args=(options.port, stop, results))
        for _ in range(options.clients)
    ]
    sse_results: Queue[int] = multiprocessing.Queue()
    browsers = [
        multiprocessing.Process(target=sse_process, args=(options.port, stop, sse_results))
        for _ in range(options.sse_clients)
    ]
    for c in clients + browsers:
        c.start()
    time.sleep(1.0)
    ingest = app.state.shore.ingest
    profile = cProfile.Profile() if options.profile else None
    start, cpu = time.perf_counter(), time.process_time()
    for i in tqdm(range(0, len(incoming), options.batch), desc="ingesting", unit="batch"):
        if profile is None:
            ingest.handle_batch(incoming[i : i + options.batch])
        else:
            profile.runcall(ingest.handle_batch, incoming[i : i + options.batch])
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
    stop.set()
    under_load = sorted(x for _ in clients for x in results.get(timeout=30))
    time.sleep(0.5)
    http.post("/api/v1/vehicles", json={"name": "wake", "address": 3})  # one more event wakes the readers up
    received = [sse_results.get(timeout=30) for _ in browsers]
    for c in clients + browsers:
        c.join(timeout=10)
    server.should_exit = True
    check_measured(ingest.stats, checkpoints, url)
    print(
        f"\ndatabase: {url.split(':')[0]}   frames: {len(incoming)} ({options.priority_share:.0%} priority), "
        f"{options.batch} per commit"
    )
    print(
        f"ingest: {len(incoming) / elapsed:,.0f} packets/s decoded, stored and published "
        f"({ingest.stats['packets']} stored, {ingest.stats['duplicates']} duplicates); "
        f"{len(incoming) / cpu:,.0f} per second of this process's CPU time (all its threads)"
    )
    if received:
        print(
            f"event stream: {len(browsers)} browsers received {min(received):,} to {max(received):,} events each "
            f"({app.state.shore.bus.published:,} published)"
        )
    if len(under_load) >= 2:
        q = statistics.quantiles(under_load, n=100)
        print(
            f"API under that load ({options.clients} clients, {len(under_load)} requests): "
            f"p50 {q[49] * 1000:.1f} ms  p95 {q[94] * 1000:.1f} ms  p99 {q[98] * 1000:.1f} ms"
        )
    if profile is not None:
        print(f"\nthe ingest of {len(incoming)} frames under cProfile (which slows it):")
        print(summary(profile, len(incoming)))


if __name__ == "__main__":
    main()
