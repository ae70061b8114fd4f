"""``tacit demo``: the whole system on simulators, wired together, running the paper's square mission.

Processes: the simulator (Micro-Modems on ptys joined by the acoustic channel, BlueROV2s in a river
with a warm plume next to the square) and one vehicle agent per vehicle (``--vehicles N``, each running
the square around its own home) run as children; the server (API,
dashboard, 3D map, shore modem) runs in this process. Everything lives in ``--data-dir``: the SQLite
database, the pty links, logs, the agents' state, and ``secrets.json`` (operator token and every vehicle's
key, readable only by you). Ctrl-C or SIGTERM stops the agent, then the simulator, then the server, which
closes the database cleanly.

``--gateways N`` runs the split shore instead (``launch.split``): N simulated shore modems, a
``tacit gateway`` on each and ``tacit center``, children too, on a broker of the demo's own and this
machine's PostgreSQL; ``--pid PART`` prints one part's process id, to stop or signal it alone.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import secrets
import signal
import sys
import webbrowser
from pathlib import Path
from typing import Any
from urllib.parse import quote

from launch import split
from launch.stack import Member, Stack, StackConfig, StackError, gateway_name, write_private
from tacit.private import open_private, private_dir

PLUME_RIVER = {
    "surface_temp": 21.0,
    "thermocline_depth": 8.0,
    "thermocline_drop": 3.0,
    "front_angle_deg": 45.0,
    "front_offset": 60.0,
    "front_width": 8.0,
    "front_step": 1.0,
    "plume_north": 24.0,
    "plume_east": 14.0,
    "plume_depth": 2.0,
    "plume_sigma": 6.0,
    "plume_sigma_z": 3.0,
    "plume_excess": 3.0,
    "patches": [[0.05, 0.05, -0.03, 0.4]],
}
DEMO_CHECKPOINT_INTERVAL = 20.0  # s (vehicle clock) between the demo agents' check-points
LAPS = 5  # one lap of the 20 m square takes about 90 s: five give a newcomer time to look around
SQUARE = {
    "name": "square",
    "number": 1,
    "duration_s": 1800,
    "waypoints": [{"north": 0, "east": 0, "depth": 2.0}]
    + [
        {"north": n, "east": e, "depth": 2.0}
        for _ in range(LAPS)
        for n, e in ((20, 0), (20, 20), (0, 20), (0, 0))
    ],
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--range", type=float, default=300.0, help="shore modem's distance from home (m)")
    parser.add_argument("--extra-loss", type=float, default=0.0, help="extra frame loss probability 0..1")
    parser.add_argument("--time-scale", type=float, default=1.0, help="simulated seconds per wall second")
    parser.add_argument("--host", default="127.0.0.1", help="bind address (default: this machine only)")
    parser.add_argument("--port", type=int, default=8000, help="API and dashboard port")
    parser.add_argument("--map-port", type=int, default=8080, help="3D map port")
    parser.add_argument(
        "--metrics-port",
        type=int,
        help="/metrics (Prometheus) port on --host (default: a free one, printed with the URLs; 0: none)",
    )
    parser.add_argument(
        "--data-dir",
        help="where the demo keeps its files (default data/demo; with --gateways data/demo-gateways)",
    )
    parser.add_argument(
        "--mission", help="a mission JSON file (default: the paper's 20 m square at 2 m, 5 laps)"
    )
    parser.add_argument("--vehicles", type=int, default=1, help="simulated vehicles sharing the channel")
    parser.add_argument(
        "--gateways",
        type=int,
        default=0,
        help="a split shore: this many shore modems, each with its gateway, and a center (needs NATS and "
        "PostgreSQL; the last vehicle flies from the first gateway's water into the second's)",
    )
    parser.add_argument(
        "--nats",
        default=None,
        help="with --gateways: a broker configured by `tacit broker-config --deployment demo` (with "
        "--broker-dir); default: a nats-server of the demo's own, on a free port",
    )
    parser.add_argument(
        "--broker-dir", type=Path, default=None, help="with --nats: the folder of its credentials files"
    )
    parser.add_argument(
        "--postgres",
        default="postgresql+psycopg://postgres@127.0.0.1:5432/test",
        help="with --gateways: a PostgreSQL server and a database on it to create the demo's database from",
    )
    parser.add_argument(
        "--pid",
        metavar="PART",
        help="print the process id of a running split demo's part (center, broker, gateway-gw1, relay-gw1, "
        "sim, agent, agent-rov2, ...) in --data-dir, and exit",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--headless", action="store_true", help="do not open a browser")
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object (URLs, token, simulator) first"
    )


def _secrets(data: Path, vehicles: int = 1) -> dict[str, Any]:
    """The operator's token, an observer's (read-only) token and each vehicle's key (``keys``, first
    vehicle first), kept between runs; a fleet larger than last time gets keys for the newcomers."""
    path = data / "secrets.json"
    values = json.loads(path.read_text()) if path.exists() else {}
    keys = values.get("keys") or [values[k] for k in ("key",) if k in values]  # an older file: one "key"
    wanted = {
        "token": values.get("token") or secrets.token_urlsafe(24),
        "read_token": values.get("read_token") or secrets.token_urlsafe(24),
        "keys": keys + [secrets.token_hex(32) for _ in range(vehicles - len(keys))],
    }
    if wanted != values:
        write_private(path, json.dumps(wanted))
    return wanted


def _log_to(path: Path) -> None:
    """Everything to the log file; only warnings and errors on the terminal."""
    root = logging.getLogger()
    for handler in root.handlers:
        handler.setLevel(logging.WARNING)
    file_handler = logging.StreamHandler(open_private(path))
    file_handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root.addHandler(file_handler)
    root.setLevel(logging.INFO)


def run(args: argparse.Namespace) -> int:
    if not 0 <= args.extra_loss <= 1 or args.time_scale <= 0 or not 1 <= args.vehicles <= 20:
        print("tacit demo: --extra-loss is 0..1, --time-scale positive and --vehicles 1..20", file=sys.stderr)
        return 2
    if not 0 <= args.gateways <= 5:
        print("tacit demo: --gateways is 0 (one shore) .. 5", file=sys.stderr)
        return 2
    args.data_dir = args.data_dir or ("data/demo-gateways" if args.gateways else "data/demo")
    if args.pid:
        try:
            print(split.part_pid(Path(args.data_dir), args.pid))
        except LookupError as exc:
            print(f"tacit demo: {exc}", file=sys.stderr)
            return 1
        return 0
    mixed = split.other_layout(Path(args.data_dir), bool(args.gateways))
    if mixed:
        print(f"tacit demo: {mixed}", file=sys.stderr)
        return 2
    if args.gateways and bool(args.nats) != bool(args.broker_dir):
        print("tacit demo: --nats and --broker-dir go together", file=sys.stderr)
        return 2
    if args.gateways:
        absent = split_missing(args)
        if absent:
            print(f"tacit demo: {absent}", file=sys.stderr)
            return 1
    try:
        mission = json.loads(Path(args.mission).read_text()) if args.mission else SQUARE
    except (OSError, ValueError) as exc:
        print(f"tacit demo: cannot read the mission: {exc}", file=sys.stderr)
        return 2
    try:
        return asyncio.run(_demo(args, mission))
    except (DemoError, StackError) as exc:
        print(f"tacit demo: {exc}", file=sys.stderr)
        return 1


class DemoError(RuntimeError):
    pass


def split_missing(args: argparse.Namespace) -> str | None:
    """What the split shore needs and does not have, in one line: the center's packages, the broker,
    the database."""
    from tacit.cli import missing_requirements

    packages = missing_requirements("center")
    if packages:
        return f"--gateways needs {', '.join(packages)}: pip install 'tacit[center]'"
    return split.missing(args.nats, args.postgres)


async def _demo(args: argparse.Namespace, mission: dict[str, Any]) -> int:
    free_port(args.host, args.port)
    if args.metrics_port is None:
        args.metrics_port = any_free_port(args.host)
    elif args.metrics_port:
        free_port(args.host, args.metrics_port, "--metrics-port (0: none)")
    data = Path(args.data_dir).resolve()
    private_dir(private_dir(data, narrow=True) / "missions")
    _log_to(data / "server.log")
    secret = _secrets(data, args.vehicles)
    (data / "missions" / "mission.json").write_text(json.dumps(mission))
    (data / "missions" / "travel.json").write_text(json.dumps(split.TRAVEL))
    stack = Stack(
        StackConfig(
            data,
            range_m=args.range,
            time_scale=args.time_scale,
            extra_loss=args.extra_loss,
            seed=args.seed,
            environment=PLUME_RIVER,
            vehicles=args.vehicles,
            keys=secret["keys"][: args.vehicles],
            write_tokens=[secret["token"]],
            read_tokens=[secret["read_token"]],
            gateways=args.gateways,
            noise_db=split.NOISE_DB if args.gateways else None,
        )
    )
    plans = {m.index: split.TRAVEL if _travels(m, args) else mission for m in stack.members}
    names = [gateway_name(i) for i in range(args.gateways)]
    broker = split.Broker(data, names, args.nats, args.broker_dir)
    broker.start()  # on this thread: its server ends with this process, however that ends
    try:
        return await _run(args, secret, stack, plans, broker)
    finally:
        broker.stop()


async def _run(
    args: argparse.Namespace,
    secret: dict[str, Any],
    stack: Stack,
    plans: dict[int, Any],
    broker: split.Broker,
) -> int:
    """The children, the server and the missions, until stopped; the broker is started already."""
    import httpx
    import uvicorn

    from server.app import shore_app
    from server.core.config import Settings

    data = stack.dir
    overrides = {
        "host": args.host,
        "port": args.port,
        "map_port": args.map_port,
        "metrics_host": args.host,
        "metrics_port": args.metrics_port,
        "poll_interval": 2.0,
    }
    database = ""
    server: Any = None
    serving: asyncio.Task[None] | None = None
    if args.gateways:  # the center first (stopped last: it stores what the gateways send to the end), a
        # child of its own, to be killed and started again alone
        database = await asyncio.to_thread(split.database, args.postgres, data)
        values = {
            **split.center_settings(stack, database, args.time_scale),
            **overrides,
            "nats_url": broker.url,
            "nats_credentials": str(broker.credentials("center")),
            "deployment": split.DEPLOYMENT.name,
        }
        config = split.write_center_config(stack, values)
        center = stack.spawn(["center", "--config", str(config), "--instance", "demo-center"], "center.log")
        map_port = args.map_port
    sim_info = await asyncio.to_thread(stack.start_sim)
    for index, name in enumerate(gateway_name(i) for i in range(args.gateways)):
        stack.start_gateway(index, broker.url, broker.credentials(f"gateway-{name}"), split.DEPLOYMENT.name)
    for member in stack.members:  # up before the server: a mission started at once finds its agent listening
        plan = "travel.json" if plans[member.index] is split.TRAVEL else "mission.json"
        stack.write_agent_config(
            member.index,
            checkpoint_interval=_checkpoint_interval(args),
            missions=[{"file": f"missions/{plan}"}],
            **({"link_lost_timeout": split.LINK_LOST_TIMEOUT} if args.gateways else {}),
            **({"plume_threshold": 1e6} if plans[member.index] is split.TRAVEL else {}),  # no detours
        )
        stack.start_agent(member.index)
    if args.gateways:
        split.write_parts(stack, broker)
    else:
        app = shore_app(Settings(**stack.server_settings(**overrides)))
        server = uvicorn.Server(uvicorn.Config(app, host=args.host, port=args.port, log_config=None))
        serving = asyncio.create_task(server.serve())
    try:
        api = f"http://{args.host}:{args.port}"
        if server is None:
            await _answering(api, center, stack.dir / "center.log")
        else:
            while not server.started:
                if serving is not None and serving.done():
                    raise DemoError(f"the server did not start (is port {args.port} free?)")
                await asyncio.sleep(0.05)
            map_port = app.state.map.port
        async with httpx.AsyncClient(
            base_url=api, headers={"Authorization": f"Bearer {secret['token']}"}
        ) as http:
            missions = [
                await _mission(http, member, plans[member.index], _checkpoint_interval(args))
                for member in stack.members
            ]
            info = {
                "api_url": api + "/api/v1",
                "dashboard_url": api + "/",
                "map_url": f"http://{args.host}:{map_port}",
                "metrics_url": f"http://{args.host}:{args.metrics_port}/metrics"
                if args.metrics_port
                else None,
                "token": secret["token"],
                "read_token": secret["read_token"],
                "sign_in_url": sign_in(api, secret["token"]),
                "observer_url": sign_in(api, secret["read_token"]),
                "time_scale": args.time_scale,
                "modems": sim_info["modems"],
                "vehicle": sim_info["vehicle"],
                "vehicles": [_described(m, sim_info) for m in stack.members],
                "data_dir": str(data),
            }
            interrupted = asyncio.Event()  # before anything is announced or started: a SIGTERM then is a stop
            loop = asyncio.get_running_loop()
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.add_signal_handler(sig, interrupted.set)
            _announce(info, args)
            for mission_id in missions:
                await http.post(f"/api/v1/missions/{mission_id}/start")
            watching = (
                [asyncio.create_task(split.watch_routes(http, _say)),
                 asyncio.create_task(split.keep_broker(broker, stack, _say))]
                if args.gateways else []
            )  # fmt: skip
            waiter = asyncio.create_task(interrupted.wait())
            await asyncio.wait({waiter, *([serving] if serving else [])}, return_when=asyncio.FIRST_COMPLETED)
            for task in watching:
                task.cancel()
        return 0
    finally:
        await shutdown(stack, server, serving)
        _channel(stack.sim_report())
        if args.gateways:
            for line in await asyncio.to_thread(split.audit, stack, database):
                _say(line)


def sign_in(api: str, token: str) -> str:
    """The dashboard's link that signs in with ``token`` (the part after # never reaches the server)."""
    return f"{api}/#token={quote(token)}"


async def _answering(api: str, center: Any, log: Path, timeout: float = 120.0) -> None:
    """Wait until the center's API answers; a center that exits first fails the demo (its log named)."""
    import httpx

    deadline = asyncio.get_running_loop().time() + timeout
    async with httpx.AsyncClient(base_url=api, timeout=2) as http:
        while True:
            if center.poll() is not None:
                raise DemoError(f"the center stopped at start; see {log}")
            try:
                if (await http.get("/api/v1/health")).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            if asyncio.get_running_loop().time() > deadline:
                raise DemoError(f"the center did not answer in {timeout:.0f} s; see {log}")
            await asyncio.sleep(0.2)


def _plans(args: argparse.Namespace) -> str:
    if args.gateways > 1:
        return (
            f"{args.gateways} gateways (gw1 .. gw{args.gateways}, 900 m apart) and a center on NATS and "
            f"PostgreSQL; rov{args.vehicles} flies 500 m east from gw1's water into gw2's, the others fly "
            "the square around their homes. Each vehicle's gateway is printed as the center assigns it."
        )
    return "Each vehicle is starting the square mission around its home."


def _channel(report: dict[str, Any]) -> None:
    """The simulated channel's figures at exit, in frames at the modem each transmission was for (a
    cycle-init, an ACK or a ping counts as one frame), and overheard by the others; where collisions
    were, if any."""
    c = report.get("channel", {})
    if "addressed" not in c:  # the simulator said nothing (it did not start, or was killed)
        return
    lost, collided, deaf = c["addressed_lost"], c["addressed_collided"], c["addressed_deaf"]
    _say(
        f"channel: {c['transmissions']} transmissions (cycle-inits, data, ACKs, pings). At the modem each was "
        f"for, {c['addressed'] - lost} of {c['addressed']} frames arrived and {lost} were lost: {collided} in "
        f"collisions, {deaf} while that modem was transmitting, {lost - collided - deaf} to range and noise "
        f"(a cycle-init, an ACK or a ping counts as one frame). The other modems overheard "
        f"{c['overheard'] - c['overheard_lost']} of {c['overheard']}."
    )
    for entry in report.get("collided", [])[-5:]:
        _say(f"  collided at {entry['to']}: {entry['kind']} from {entry['from']} (t={entry['time']:.1f} s)")


def _say(line: str) -> None:
    print(line, flush=True)


def _travels(member: Member, args: argparse.Namespace) -> bool:
    """The vehicle that flies from the first gateway's water into the second's: the last, with gateways."""
    return args.gateways > 1 and member.index == args.vehicles - 1


def free_port(host: str, port: int, option: str = "--port") -> None:
    """Fail in one line, before anything starts, if the API's port (or ``option``'s) is taken."""
    from server.app import PortBusy, check_port

    try:
        check_port(host, port, option)
    except PortBusy as exc:
        raise DemoError(str(exc)) from None


def any_free_port(host: str) -> int:
    """A port nothing listens on now (the demo's /metrics unless one is asked for: demos and tests run
    side by side)."""
    import socket

    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])


async def shutdown(stack: Stack, server: Any, serving: asyncio.Task | None) -> None:
    """Children in reverse order of start (agents, gateways, simulator, and a split shore's center last:
    it stores what the gateways sent to the end), then the server in this process, if any, which closes
    the database cleanly."""
    await asyncio.to_thread(stack.close)
    if server is None or serving is None:
        return
    server.should_exit = True
    try:
        await serving
    except SystemExit:  # uvicorn could not start (the caller says why); not a traceback at exit
        pass


def _checkpoint_interval(args: argparse.Namespace) -> float:
    """The demo's agents' check-point interval (s, vehicle clock): registered with each vehicle too."""
    return split.CHECKPOINT_INTERVAL if args.gateways else DEMO_CHECKPOINT_INTERVAL


async def _register(http: Any, member: Member, report_interval: float | None = None) -> int:
    """A vehicle of the demo: created (with its agent's check-point interval, when given), or found from
    an earlier run by its address (and given its key and its home)."""
    body = {**member.registration(), "max_depth": 20.0}
    if report_interval is not None:
        body["report_interval"] = report_interval
    created = await http.post("/api/v1/vehicles", json=body)
    if created.status_code == 201:
        return created.json()["id"]
    existing = next(
        (v for v in (await http.get("/api/v1/vehicles")).json() if v["address"] == member.address), None
    )
    if existing is None:  # refused for another reason (a name or key another vehicle has): say which
        raise DemoError(f"vehicle {member.name} not registered: {created.json()['detail']}")
    rotated = await http.post(f"/api/v1/vehicles/{existing['id']}/key", json={"key": member.key})
    if rotated.status_code != 200:
        raise DemoError(f"vehicle {member.name}: {rotated.json()['detail']}")
    await http.put(f"/api/v1/vehicles/{existing['id']}/home", json={"home": list(member.home)})
    return existing["id"]


async def _mission(http: Any, member: Member, mission: dict[str, Any], report_interval: float) -> int:
    """Register the vehicle and queue the mission for it; the mission's id. The plan's waypoints are
    relative to each vehicle's home (``vehicle_agent.navigator``): every vehicle flies its plan (the
    square) around its own start."""
    vehicle_id = await _register(http, member, report_interval)
    queued = await http.post(f"/api/v1/vehicles/{vehicle_id}/missions", json=mission)
    return int(queued.json()["id"])


def _described(member: Member, sim_info: dict[str, Any]) -> dict[str, Any]:
    return {
        "name": member.name,
        "address": member.address,
        "home": list(member.home),
        "mavlink": sim_info["vehicles"][member.index]["mavlink"],
    }


def _vehicle_lines(vehicle: dict[str, Any]) -> str:
    """A vehicle of the banner: its modem, its home, the agent's MAVLink endpoint and a ground station's."""
    agent = next(url for url in vehicle["mavlink"] if url.startswith("tcp:"))
    station = next((url for url in vehicle["mavlink"] if url.startswith("udpout:")), None)
    lines = (
        f"  Vehicle {vehicle['name']}: modem address {vehicle['address']}, home {vehicle['home'][0]:g} m north "
        f"{vehicle['home'][1]:g} m east, MAVLink {agent} (its agent's)\n"
    )
    if station is not None:
        host_port = station.removeprefix("udpout:")
        lines += (
            f"    ground station: UDP {host_port} (mavproxy.py --master={station}; QGroundControl: a UDP "
            f"link with server {host_port})\n"
        )
    return lines


def _announce(info: dict[str, Any], args: argparse.Namespace) -> None:
    if args.json:
        print(json.dumps(info), flush=True)
    else:
        scale = (
            f"Simulated time runs {args.time_scale:g}x faster than the clock (--time-scale).\n"
            if args.time_scale != 1
            else "Real time (--time-scale 4 to watch it faster).\n"
        )
        print(
            f"\nTacit demo is running (data in {info['data_dir']}).\n"
            f"  Dashboard, signed in as operator: {info['sign_in_url']}\n"
            f"  Dashboard for an observer (read only): {info['observer_url']}\n"
            f"  3D map:    {info['map_url']}  (its panel asks for a token: paste the operator token)\n"
            f"  API:       {info['api_url']}  (docs: {info['dashboard_url']}docs)\n"
            + (f"  Metrics:   {info['metrics_url']}  (Prometheus)\n" if info.get("metrics_url") else "")
            + f"  Operator token: {info['token']}\n  Observer token: {info['read_token']}\n"
            f"  (tokens also in {Path(info['data_dir']) / 'secrets.json'}; the part after # never reaches the server)\n"
            + "".join(_vehicle_lines(v) for v in info["vehicles"])
            + f"{scale}{_plans(args)} Ctrl-C stops everything.\n",
            flush=True,
        )
    if not args.headless:
        webbrowser.open(info["sign_in_url"])
