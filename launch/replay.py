"""``tacit replay FILE.tlog``: what the protocol would have sent during a real dive.

The simulator streams the log as the vehicle (its own MAVLink frames), the agent compresses what it
hears and answers the shore's polls through the simulated link, and the server stores what arrives, as
in a mission; the dashboard shows it live. At the end a summary compares what the shore reconstructed
with what the vehicle measured (the agent's own tlog): the keys of ``tacit eval-compression --json``
for the IMU stream, plus ``packets_by_type``.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

from analysis.series import error_ratios, measured_samples
from launch.demo import DemoError, _log_to, _register, _secrets, free_port, shutdown, sign_in
from launch.stack import Stack, StackConfig
from tacit.packets import Stream
from tacit.private import private_dir
from tacit.streams import IMU_CHANNELS, default_streams


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("tlog", help="a MAVLink .tlog from ArduSub (e.g. tests/data/ardusub/small.tlog)")
    parser.add_argument("--time-scale", type=float, default=4.0, help="log seconds per wall second")
    parser.add_argument("--range", type=float, default=300.0, help="shore modem's distance (m)")
    parser.add_argument("--extra-loss", type=float, default=0.0, help="extra frame loss probability 0..1")
    parser.add_argument("--data-dir", default="data/replay", help="database, logs and the agent's tlog")
    parser.add_argument(
        "--port",
        type=int,
        default=8010,
        help="API and dashboard port: its URL and token are printed at once, to watch it live",
    )
    parser.add_argument(
        "--map-port", type=int, default=8090, help="the 3D map's port, to watch it live (0: no map)"
    )
    parser.add_argument(
        "--settle", type=float, default=25.0, help="seconds after the log ends for the last packets"
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="one JSON object per line: the live view's URLs and token at once, the summary last",
    )


def run(args: argparse.Namespace) -> int:
    from simulators.tlog_replay import read_tlog

    try:
        frames = read_tlog(args.tlog)
    except (OSError, ValueError) as exc:
        print(f"tacit replay: {exc}", file=sys.stderr)
        return 2
    duration = (frames[-1][0] - frames[0][0]) / args.time_scale
    try:
        summary = asyncio.run(_replay(args, duration))
    except DemoError as exc:
        print(f"tacit replay: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(summary))
    else:
        for key, value in summary.items():
            print(f"{key:>18}: {value}")
    return 0


async def _replay(args: argparse.Namespace, duration: float) -> dict:
    import httpx
    import uvicorn

    from server.app import create_app
    from server.core.config import Settings

    free_port("127.0.0.1", args.port)
    data = Path(args.data_dir).resolve()
    private_dir(data, narrow=True)
    _log_to(data / "server.log")
    secret = _secrets(data)
    for old in (data / "tlogs").glob("*.tlog"):
        old.unlink()
    (data / "agent-state.json").unlink(missing_ok=True)
    stack = Stack(
        StackConfig(
            data,
            range_m=args.range,
            time_scale=args.time_scale,
            extra_loss=args.extra_loss,
            replay=args.tlog,
            keys=secret["keys"][:1],
            write_tokens=[secret["token"]],
        )
    )
    await asyncio.to_thread(stack.start_sim)
    map_settings = {"map_port": args.map_port, "map_enabled": bool(args.map_port)}
    app = create_app(Settings(**stack.server_settings(port=args.port, **map_settings)))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=args.port, log_config=None))
    serving = asyncio.create_task(server.serve())
    started = time.time()
    api = f"http://127.0.0.1:{args.port}"
    try:
        while not server.started:
            if serving.done():
                raise DemoError(f"the server did not start (is port {args.port} free?)")
            await asyncio.sleep(0.05)
        async with httpx.AsyncClient(
            base_url=api, headers={"Authorization": f"Bearer {secret['token']}"}
        ) as http:
            await _register(http, stack.members[0])
        # the agent runs on the wall clock (no time_scale): it stamps what it hears as a real vehicle would
        stack.write_agent_config(max_silence=20, time_scale=None)
        stack.start_agent()
        live = {
            "dashboard_url": api + "/",
            "sign_in_url": sign_in(api, secret["token"]),
            "map_url": f"http://127.0.0.1:{app.state.map.port}" if app.state.map else None,
            "api_url": api + "/api/v1",
            "token": secret["token"],
            "data_dir": str(data),
            "seconds": round(duration + args.settle, 1),
        }
        if args.json:
            print(json.dumps(live), flush=True)
        else:
            view = (
                f"  3D map:    {live['map_url']}  (its panel asks for the token)\n" if live["map_url"] else ""
            )
            print(
                f"Replaying {args.tlog} ({live['seconds']} s). Watch it live:\n"
                f"  Dashboard, signed in as operator: {live['sign_in_url']}\n{view}"
                f"  Operator token: {live['token']}\n",
                flush=True,
            )
        stats = app.state.shore.ingest.stats
        # the dive, then the last packets' latency and a poll or two
        await wait_with_progress(duration + args.settle, lambda: stats["packets"])
        return _summary(app.state.shore.db, data, started)
    finally:
        await shutdown(stack, server, serving)


async def wait_with_progress(
    seconds: float,
    packets: Callable[[], int],
    file: TextIO | None = None,
    disable: bool | None = None,
    step: float = 0.5,
) -> None:
    """Wait ``seconds`` with a progress bar on stderr (seconds elapsed, packets stored so far); the bar
    is left out when stderr is not a terminal unless ``disable`` is False."""
    from tqdm import tqdm

    loop = asyncio.get_running_loop()
    end = loop.time() + seconds
    with tqdm(
        total=round(seconds, 1),
        unit="s",
        desc="replay",
        file=file,
        disable=disable,
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s {postfix}",
    ) as bar:
        while (left := end - loop.time()) > 0:
            await asyncio.sleep(min(step, left))
            bar.n = round(min(seconds, seconds - (end - loop.time())), 1)
            bar.set_postfix_str(f"{packets()} packets stored")
        bar.n = bar.total
        bar.refresh()


def _summary(db, data: Path, started: float) -> dict:
    """The shore's reconstruction against the vehicle's own log of what it measured."""
    from sqlmodel import Session, select

    from server.telemetry.models import Packet, Telemetry

    spec = default_streams()[Stream.KINEMATIC]
    # the log stamps a message when the agent's logger wrote it, not when the agent sampled it, and a
    # replay runs the dive faster than real time: a few ms of delay is a large part of the IMU's 0.25 s
    # tick, so a reconstruction is compared with the samples logged within a whole tick of it
    measured = measured_samples(data / "tlogs", "RAW_IMU", IMU_CHANNELS)
    with Session(db) as s:
        packets = s.exec(select(Packet).where(Packet.at >= started)).all()
        rows = s.exec(select(Telemetry).where(Telemetry.stream == "imu", Telemetry.certain)).all()
    ratios = [
        ratio
        for r in rows
        if (near := measured.near(r.time, spec.period))
        for ratio in error_ratios(r.values, near, spec.eps)
    ]
    imu = [
        p for p in packets if p.type == "priority" and "imu" in p.body.get("streams", [])
    ]  # shared packets
    arrived = {p.id: p.at for p in imu}  # the agent stamps what it hears with its clock, as the shore's
    latencies = [arrived[r.packet_id] - r.time for r in rows if r.packet_id in arrived]
    samples = measured.values.size
    return {
        "samples": samples, "packets": len(imu), "link_bits": len(imu) * 256,
        "bits_per_sample": round(len(imu) * 256 / samples, 3) if samples else None,
        "max_error_ratio": round(max(ratios), 4) if ratios else None,
        "rms_error_ratio": round(math.sqrt(sum(r * r for r in ratios) / len(ratios)), 4) if ratios else None,
        "max_latency_s": round(max(latencies), 2) if latencies else None,
        "packets_by_type": dict(Counter(f"{p.type}/{p.body.get('stream', '-')}" if p.type == "priority" else p.type
                                        for p in packets)),
    }  # fmt: skip
