"""The ``tacit`` command: one entry point that joins the apps.

Each subcommand lives in the module that owns its concept and exposes ``add_arguments(parser)`` and
``run(args) -> int``. Modules are imported only when their command is chosen, so an agent-only
install (no web stack) can run ``tacit agent``.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import logging
import os
import re
import signal
import sys
import threading
import time
from typing import NamedTuple

PARENT = "TACIT_PARENT_PID"  # a launcher's child ends when that process is gone (``end_with_parent``)


class Subcommand(NamedTuple):
    module: str
    extra: str  # the install extra (pyproject.toml) that holds this command's runtime dependencies
    help: str


COMMANDS: dict[str, Subcommand] = {
    "demo": Subcommand("launch.demo", "demo", "Start the whole system on simulators and open the operator's screen"),
    "serve": Subcommand("server.app", "server", "Run the shore control center (API, dashboard, 3D map, shore modem)"),
    "gateway": Subcommand("server.backhaul.gateway", "gateway", "Run a gateway: one shore modem relaying to the center over NATS"),
    "center": Subcommand("server.backhaul.center", "center", "Run the center: gateways' frames from NATS into the store"),
    "database": Subcommand("server.ops.backup", "", "Back up the center's database, or restore a backup into an empty one"),
    "backhaul-audit": Subcommand("server.backhaul.audit", "center", "Count each gateway's frames heard against those the center stored and decoded"),
    "broker-config": Subcommand("server.backhaul.access", "", "Write the NATS broker's accounts and credentials for a deployment's gateways"),
    "agent": Subcommand("vehicle_agent.agent", "agent", "Run the vehicle agent between ArduSub and the vehicle's modem"),
    "sim": Subcommand("simulators.run", "sim", "Start simulated Micro-Modems, acoustic channel and BlueROV2"),
    "replay": Subcommand("launch.replay", "demo", "Run a real .tlog through the agent and the simulated link"),
    "eval-compression": Subcommand("analysis.evaluate", "analysis", "Measure the compressor on a CSV or .tlog file"),
    "modem-log": Subcommand("tacit.modemlog", "", "Decode a Micro-Modem NMEA log: sentences, frames, packets"),
}  # fmt: skip


def _parser() -> argparse.ArgumentParser:
    listing = "\n".join(f"  {name:<18}{command.help}" for name, command in COMMANDS.items())
    parser = argparse.ArgumentParser(
        prog="tacit",
        description="Tacit: compressed acoustic communications for underwater vehicles.\n\n"
        f"commands:\n{listing}",
        epilog="Run 'tacit COMMAND --help' for a command's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--log-level", default="INFO", help="logging level (default INFO)")
    parser.add_argument("command", choices=list(COMMANDS), metavar="COMMAND", help="the command to run")
    return parser


def end_with_parent(parent: str | None, every: float = 0.5) -> None:
    """A launcher's child (``tacit demo``'s simulator, agents and gateways): SIGTERM to itself once its
    parent process ``parent`` is gone, however it ended (a SIGKILL leaves no chance to stop its
    children: the child notices it has been handed to another parent)."""
    if not parent or not parent.isdigit():
        return

    def watch() -> None:
        while os.getppid() == int(parent):
            time.sleep(every)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="end-with-parent", daemon=True).start()


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    top = _parser()
    first = next((i for i, a in enumerate(argv) if a in COMMANDS), None)
    if first is None:
        top.parse_args(argv)  # prints help or the error for an unknown command
        return 2
    options = top.parse_args(argv[: first + 1])
    command = COMMANDS[options.command]
    missing = missing_requirements(command.extra)
    if missing:
        return _missing(options.command, missing)
    try:
        module = importlib.import_module(command.module)
    except ModuleNotFoundError as exc:
        return _missing(options.command, [exc.name or str(exc)])
    end_with_parent(os.environ.pop(PARENT, None))  # not handed down to its own children
    parser = argparse.ArgumentParser(prog=f"tacit {options.command}", description=command.help)
    module.add_arguments(parser)
    args = parser.parse_args(argv[first + 1 :])
    logging.basicConfig(
        level=options.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    logging.getLogger("alembic").setLevel(logging.WARNING)  # its plugin set-up chatter is not for operators
    try:
        return int(module.run(args) or 0)
    except KeyboardInterrupt:
        return 130
    except ModuleNotFoundError as exc:  # commands import their heavier packages when they need them
        return _missing(options.command, [exc.name or str(exc)])


def missing_requirements(extra: str) -> list[str]:
    """The packages of an install extra (as pyproject.toml declares them) that are not installed.
    Empty when Tacit runs from a source tree without being installed (nothing to compare with)."""
    if not extra:
        return []
    try:
        requires = importlib.metadata.requires("tacit") or []
    except importlib.metadata.PackageNotFoundError:
        return []
    missing: list[str] = []
    for requirement in requires:
        spec, _, marker = requirement.partition(";")
        if marker.replace("'", '"').split("extra ==")[-1].strip().strip('"') != extra:
            continue
        name = re.split(r"[<>=!~\[ ]", spec.strip(), maxsplit=1)[0]
        if name == "tacit":  # an extra made of extras: tacit[agent,server]
            for nested in re.findall(r"\[(.*)\]", spec)[0].split(","):
                missing += [m for m in missing_requirements(nested.strip()) if m not in missing]
        elif not _installed(name):
            missing.append(name)
    return missing


def _installed(name: str) -> bool:
    try:
        importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


def _missing(name: str, packages: list[str]) -> int:
    """One line naming the extra to install, instead of a traceback."""
    extra = COMMANDS[name].extra
    requirement = f"tacit[{extra}]" if extra else "tacit"
    print(
        f"tacit {name}: needs {', '.join(packages)}, not installed; "
        f"install with: pip install '{requirement}'",
        file=sys.stderr,
    )
    return 2


if __name__ == "__main__":
    sys.exit(main())
