"""``tacit sim``: simulated Micro-Modems on ptys, the acoustic channel and BlueROV2s, from one config.

A config file (TOML or JSON) lists the pieces; without one, the default is the paper's setup: a shore
modem (address 1) ``--range`` metres from home and a vehicle modem (address 2) riding a BlueROV2 in a
simulated river. Example (TOML)::

    seed = 1
    time_scale = 1.0
    [channel]               # any ChannelParameters field
    noise_level_db = 110
    extra_loss = 0.1
    [environment]
    kind = "river"          # or lake; or file = "env.json"
    [[modems]]
    address = 1
    name = "shore"
    position = [-500, 0, 1] # north, east, depth (m)
    link = "/tmp/tacit-shore"   # optional stable symlink to the pty
    tcp_port = 0                # optional: the dialect over TCP too (0 = any free port)
    [[modems]]
    address = 2
    name = "vehicle"
    attach = "rov1"         # rides this vehicle
    [[vehicles]]
    name = "rov1"
    tcp_port = 5777         # BlueOS's companion endpoint; 0 = any free port
    udp_port = 0            # ground stations: udpout:127.0.0.1:PORT
    position_source = false # true: a DVL/USBL gives a position fix (GUIDED works)
    current = [0.05, 0.0]   # water current, m/s north, east
    replay = ""             # a .tlog to stream instead of simulating

A vehicle's ``SIM_MODEM_LOSS`` parameter (PARAM_SET over its MAVLink, 0..1) takes the modem riding it out
of range while it runs, and back.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import signal
import sys
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from simulators.acoustics import ChannelParameters
from simulators.channel import Channel
from simulators.clock import RealtimeScheduler
from simulators.environment import Environment
from simulators.mavlink_vehicle import SimulatedVehicle
from simulators.micromodem import MicroModemEmulator
from simulators.parameters import MODEM_LOSS
from simulators.ports import PtyPort, TcpPort
from simulators.tlog_replay import TlogReplay
from tacit.config import check_keys

log = logging.getLogger("simulators")


@dataclass
class ModemSpec:
    address: int
    name: str = ""
    position: tuple[float, float, float] = (0.0, 0.0, 1.0)
    attach: str = ""
    link: str = ""
    tcp_port: int | None = None
    recorder: bool = False  # a hydrophone's recorder: reports every data frame it hears, whoever it is for


@dataclass
class VehicleSpec:
    name: str = "rov1"
    tcp_port: int = 0
    udp_port: int | None = 0
    udp_push: str = ""  # host:port to push telemetry to, as BlueOS does to the topside
    position_source: bool = False
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    heading_deg: float = 0.0
    current: tuple[float, float] = (0.0, 0.0)
    replay: str = ""
    seed: int = 1


@dataclass
class SimConfig:
    seed: int = 1
    time_scale: float = 1.0
    channel: dict[str, Any] = field(default_factory=dict)
    environment: dict[str, Any] = field(default_factory=lambda: {"kind": "river"})
    modems: list[ModemSpec] = field(default_factory=list)
    vehicles: list[VehicleSpec] = field(default_factory=list)

    @classmethod
    def default(cls, distance: float = 500.0, seed: int = 1, time_scale: float = 1.0) -> SimConfig:
        return cls(
            seed=seed,
            time_scale=time_scale,
            modems=[ModemSpec(1, "shore", (-distance, 0.0, 1.0)), ModemSpec(2, "vehicle", attach="rov1")],
            vehicles=[VehicleSpec("rov1", seed=seed)],
        )

    @classmethod
    def load(cls, path: str | Path) -> SimConfig:
        text = Path(path).read_text()
        data = json.loads(text) if str(path).endswith(".json") else tomllib.loads(text)
        return cls.from_dict(data)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SimConfig:
        check_keys("config", data, cls)
        modems = [ModemSpec(**_checked("modem", m, ModemSpec)) for m in data.pop("modems", [])]
        vehicles = [VehicleSpec(**_checked("vehicle", v, VehicleSpec)) for v in data.pop("vehicles", [])]
        config = cls(**data, modems=modems, vehicles=vehicles)
        config.validate()
        return config

    def validate(self) -> None:
        addresses = [m.address for m in self.modems]
        if len(set(addresses)) != len(addresses):
            raise ValueError(f"modem addresses must be unique: {addresses}")
        if any(not 1 <= a <= 127 for a in addresses):
            raise ValueError("modem addresses are 1-127")
        names = {v.name for v in self.vehicles}
        if len(names) != len(self.vehicles):
            raise ValueError(f"vehicle names must be unique: {[v.name for v in self.vehicles]}")
        for m in self.modems:
            if m.attach and m.attach not in names:
                raise ValueError(f"modem {m.address} is attached to unknown vehicle {m.attach!r}")
        unknown = set(self.channel) - {f.name for f in fields(ChannelParameters)}
        if unknown:
            raise ValueError(f"unknown channel parameters {sorted(unknown)}")
        if self.time_scale <= 0:
            raise ValueError("time_scale must be positive")


def _checked(what: str, data: dict[str, Any], cls: type) -> dict[str, Any]:
    check_keys(what, data, cls)
    return {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}


class SimWorld:
    """Everything the config describes, running on the current asyncio loop."""

    def __init__(self, config: SimConfig) -> None:
        self.config = config
        self.modems: dict[int, MicroModemEmulator] = {}
        self.ports: dict[int, list[PtyPort | TcpPort]] = {}
        self.vehicles: dict[str, SimulatedVehicle] = {}
        self.replays: dict[str, TlogReplay] = {}
        self._tasks: list[asyncio.Task[None]] = []

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        cfg = self.config
        self.scheduler = RealtimeScheduler(loop, cfg.time_scale)
        self.channel = Channel(self.scheduler, ChannelParameters(**{"seed": cfg.seed, **cfg.channel}))
        env_cfg = dict(cfg.environment)
        self.environment = (
            Environment.load(env_cfg["file"])
            if env_cfg.get("file")
            else Environment.generate(cfg.seed, env_cfg.get("kind", "river"))
        )
        for vehicle_spec in cfg.vehicles:
            await self._start_vehicle(vehicle_spec)
        for modem_spec in cfg.modems:
            await self._start_modem(modem_spec)

    async def _start_vehicle(self, spec: VehicleSpec) -> None:
        vehicle = SimulatedVehicle(
            self.scheduler,
            self.environment,
            seed=spec.seed,
            position_source=spec.position_source,
            current=spec.current,
        )
        vehicle.rov.north, vehicle.rov.east, vehicle.rov.depth = spec.start
        vehicle.rov.yaw = math.radians(spec.heading_deg)
        await vehicle.links.serve_tcp("127.0.0.1", spec.tcp_port)
        if spec.udp_port is not None:
            await vehicle.links.serve_udp("127.0.0.1", spec.udp_port)
        if spec.udp_push:
            host, _, port = spec.udp_push.rpartition(":")
            await vehicle.links.serve_udp("0.0.0.0", 0, push_to=(host, int(port)))
        if spec.replay:
            replay = TlogReplay(spec.replay, vehicle.links, self.config.time_scale)
            self.replays[spec.name] = replay
            self._tasks.append(asyncio.ensure_future(replay.run()))
        else:
            vehicle.start()
        self.vehicles[spec.name] = vehicle

    async def _start_modem(self, spec: ModemSpec) -> None:
        rov = self.vehicles[spec.attach].rov if spec.attach else None
        north, east, depth = (float(x) for x in spec.position)

        def position() -> tuple[float, float, float]:
            return (rov.north, rov.east, rov.depth) if rov is not None else (north, east, depth)

        def loss() -> float:  # a vehicle's modem taken out of range: its SIM_MODEM_LOSS, set over MAVLink
            return min(1.0, max(0.0, rov.params.get(MODEM_LOSS, 0.0))) if rov is not None else 0.0

        modem = MicroModemEmulator(
            spec.name or f"modem{spec.address}",
            spec.address,
            self.channel,
            self.scheduler,
            position,
            hears_all=spec.recorder,
            loss=loss,
        )
        pty = PtyPort(asyncio.get_running_loop(), modem.handle_line, spec.link or None)
        ports: list[PtyPort | TcpPort] = [pty]
        if spec.tcp_port is not None:
            tcp = TcpPort(modem.handle_line)
            await tcp.start(port=spec.tcp_port)
            ports.append(tcp)

        def output(line: str) -> None:
            for port in ports:
                port.write(line)

        modem.output = output
        self.modems[spec.address] = modem
        self.ports[spec.address] = ports
        modem.boot()

    def describe(self) -> dict[str, Any]:
        """What a script needs to connect: pty paths and MAVLink URLs."""
        modems = []
        for address, ports in self.ports.items():
            entry: dict[str, Any] = {
                "address": address,
                "name": self.modems[address].name,
                "pty": next(p for p in ports if isinstance(p, PtyPort)).path,
            }
            tcp = next((p for p in ports if isinstance(p, TcpPort)), None)
            entry["tcp"] = f"socket://127.0.0.1:{tcp.port}" if tcp else None
            modems.append(entry)
        vehicles = []
        for name, vehicle in self.vehicles.items():
            urls = [f"tcp:127.0.0.1:{vehicle.links.tcp_port}"]
            if vehicle.links.udp_port:
                urls.append(f"udpout:127.0.0.1:{vehicle.links.udp_port}")
            vehicles.append({"name": name, "mavlink": urls, "replay": bool(name in self.replays)})
        return {
            "modems": modems,
            "vehicles": vehicles,
            "vehicle": vehicles[0] if vehicles else None,
            "time_scale": self.config.time_scale,
        }

    def report(self) -> dict[str, Any]:
        """What crossed the channel, per modem and in total; the latest receptions that collided (when,
        what, from which modem to which: where two transmissions overlapped)."""
        return {
            "channel": dict(self.channel.stats),
            "collided": [entry for entry in self.channel.log if entry["collided"]][-50:],  # the latest
            "modems": {m.name: dict(m.counters) for m in self.modems.values()},
            "vehicles": {n: {**v.counters, **v.describe()} for n, v in self.vehicles.items()},
            "replays": {
                n: {"sent": r.sent, "ignored_commands": r.ignored_commands} for n, r in self.replays.items()
            },
        }

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        for vehicle in self.vehicles.values():
            vehicle.stop()
            vehicle.links.close()
        for ports in self.ports.values():
            for port in ports:
                port.close()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="a TOML or JSON file describing modems, vehicles and channel")
    parser.add_argument(
        "--range", type=float, default=500.0, help="default setup: shore modem range from home (m)"
    )
    parser.add_argument("--seed", type=int, default=1, help="random seed (channel, sensors, environment)")
    parser.add_argument("--time-scale", type=float, default=None, help="simulated seconds per wall second")
    parser.add_argument("--extra-loss", type=float, default=None, help="extra frame loss probability 0..1")
    parser.add_argument("--replay", help="stream this .tlog as the vehicle instead of simulating it")
    parser.add_argument("--position-source", action="store_true", help="the vehicle has a DVL/USBL fix")
    parser.add_argument(
        "--mavlink-port", type=int, default=None, help="vehicle MAVLink TCP port (default any)"
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object (ptys, MAVLink URLs) first"
    )


def build_config(args: argparse.Namespace) -> SimConfig:
    config = SimConfig.load(args.config) if args.config else SimConfig.default(args.range, args.seed)
    if args.time_scale is not None:
        config.time_scale = args.time_scale
    if args.extra_loss is not None:
        if not 0 <= args.extra_loss <= 1:
            raise ValueError("--extra-loss is a probability 0..1")
        config.channel["extra_loss"] = args.extra_loss
    for vehicle in config.vehicles[:1]:
        if args.replay:
            vehicle.replay = args.replay
        if args.position_source:
            vehicle.position_source = True
        if args.mavlink_port is not None:
            vehicle.tcp_port = args.mavlink_port
    config.validate()
    for vehicle in config.vehicles:
        if vehicle.replay and not Path(vehicle.replay).is_file():
            raise FileNotFoundError(f"{vehicle.replay}: no such file (the .tlog to replay)")
    return config


async def _serve(config: SimConfig, as_json: bool) -> None:
    world = SimWorld(config)
    await world.start()
    info = world.describe()
    if as_json:
        print(json.dumps(info), flush=True)
    else:
        for modem in info["modems"]:
            print(f"modem {modem['address']} ({modem['name']}): {modem['pty']}", flush=True)
        for vehicle in info["vehicles"]:
            print(f"vehicle {vehicle['name']}: {' '.join(vehicle['mavlink'])}", flush=True)
        print("Ctrl-C to stop.", flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    await stop.wait()
    report = world.report()
    await world.stop()
    print(
        json.dumps({"report": report}) if as_json else f"stopped; {json.dumps(report, indent=2)}", flush=True
    )


def run(args: argparse.Namespace) -> int:
    try:
        config = build_config(args)
    except (ValueError, OSError, tomllib.TOMLDecodeError) as exc:
        print(f"tacit sim: {exc}", file=sys.stderr)
        return 2
    asyncio.run(_serve(config, args.json))
    return 0
