"""A vehicle's configuration checked before a dive: ``tacit agent --check``, each problem on one line.

``load`` reads the configuration as the agent starts with it and lists what is wrong: the file, each
setting's type and range, the key, the limits, the mission plans (each inside the limits) and the
folders the agent writes. ``tacit agent`` starts on none of these: it prints them and exits with
``EXIT_CONFIG``, which its systemd unit does not restart on (a restart cannot mend a configuration).
``--check`` also tries what only the vehicle can answer: that the modem's serial port opens for this
user, and that an autopilot answers on the MAVLink endpoint with ``SYSID_MYGCS`` the agent's system id
(ArduSub ignores MANUAL_CONTROL from any other). It sends no heartbeat and changes nothing.
"""

from __future__ import annotations

import errno
import math
import os
import pwd
import sys
import time
import tomllib
import typing
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from tacit import auth
from tacit.packets import VERSIONS
from tacit.params import LostAction
from vehicle_agent.agent import AgentConfig
from vehicle_agent.mavlink_io import GCS_SYSTEM_ID
from vehicle_agent.mission import MissionPlan

EXIT_CONFIG = 2  # the configuration is refused: the unit's RestartPreventExitStatus
EXIT_UNREADY = 1  # --check found a problem
POSITIVE = (
    "link_lost_timeout", "checkpoint_interval", "plume_threshold", "explore_distance", "max_latency",
    "max_silence", "time_scale", "limits.max_depth", "limits.max_distance", "limits.geofence_radius",
    "limits.max_speed", "nav.cruise_speed", "nav.drag_length", "nav.arrive_radius",
)  # fmt: skip
MAVLINK_TIMEOUT = 5.0  # s for the autopilot's first heartbeat and its SYSID_MYGCS


@dataclass(frozen=True)
class Problem:
    """What is wrong, and with which setting (``limits.max_depth``, ``missions[2]``, ``modem_url``)."""

    setting: str
    message: str

    def __str__(self) -> str:
        return f"{self.setting}: {self.message}"


@dataclass
class Loaded:
    """A configuration as read: the agent's settings and plans (when readable), and every problem."""

    path: Path
    config: AgentConfig | None = None
    plans: dict[int, MissionPlan] = field(default_factory=dict)
    problems: list[Problem] = field(default_factory=list)


def load(path: str | Path) -> Loaded:
    """The configuration at ``path`` and what is wrong with it, without trying any device."""
    loaded = Loaded(Path(path))
    try:
        loaded.config = AgentConfig.load(path)
    except OSError as exc:
        loaded.problems.append(Problem("config", f"cannot read {path}: {exc.strerror or exc}"))
    except tomllib.TOMLDecodeError as exc:
        loaded.problems.append(Problem("config", f"{path} is not TOML: {exc}"))
    except (ValueError, TypeError) as exc:
        loaded.problems.append(Problem("config", str(exc)))
    if loaded.config is None:
        return loaded
    config = loaded.config
    typed = _types(config)
    loaded.problems += typed
    if typed:  # ranges and plans compare numbers: not with a value of the wrong type
        return loaded
    loaded.problems += _private(loaded.path) + _keys(config) + _values(config) + _folders(config)
    loaded.plans = _plans(config, loaded.path.resolve().parent, loaded.problems)
    return loaded


def _settings(config: AgentConfig) -> list[tuple[str, Any, type]]:
    """Every setting as (dotted name, value, declared type), the [limits] and [nav] tables' too."""
    out: list[tuple[str, Any, type]] = []
    for prefix, obj in (("", config), ("limits.", config.limits), ("nav.", config.nav)):
        hints = typing.get_type_hints(type(obj))
        out += [(prefix + f.name, getattr(obj, f.name), hints[f.name]) for f in fields(obj)]
    return [(name, value, kind) for name, value, kind in out if name not in ("limits", "nav")]


def _types(config: AgentConfig) -> list[Problem]:
    words = {int: "a whole number", float: "a number", str: "text", list: "a list"}
    problems = []
    for name, value, kind in _settings(config):
        base = typing.get_origin(kind) or kind
        accepted: tuple[type, ...] = (int, float) if base is float else (base,)
        if base in words and (isinstance(value, bool) or not isinstance(value, accepted)):
            problems.append(Problem(name, f"must be {words[base]}, not {value!r}"))
    return problems


def _private(path: Path) -> list[Problem]:
    """The file holds the vehicle's key: no one but root and the service user may read it."""
    if path.stat().st_mode & 0o007:
        return [Problem("config", f"{path} is readable by every user: chmod 640 {path} (it holds the key)")]
    return []


def _keys(config: AgentConfig) -> list[Problem]:
    problems = []
    for name, text in (("key", config.key), ("next_key", config.next_key)):
        if name == "next_key" and not text:
            continue
        try:
            auth.parse_key(text)
        except ValueError as exc:
            problems.append(Problem(name, f"not a key ({exc}): put the vehicle's key from the shore here"))
    if config.next_key and config.next_key.strip().lower() == config.key.strip().lower():
        problems.append(Problem("next_key", "is the current key: next_key is the key of key_version + 1"))
    if config.key_version < 1:
        problems.append(
            Problem("key_version", f"is 1 or more (the shore's key_version), not {config.key_version}")
        )
    return problems


def _values(config: AgentConfig) -> list[Problem]:
    values = {name: value for name, value, _ in _settings(config)}
    problems = [
        Problem(name, f"must be more than 0, not {values[name]}")
        for name in POSITIVE
        if not (values[name] > 0 and math.isfinite(values[name]))
    ]
    if config.lost_action not in {a.value for a in LostAction}:
        problems.append(
            Problem("lost_action", f"is one of {', '.join(LostAction)}, not {config.lost_action!r}")
        )
    if config.address == config.shore_address or config.address in config.gateways:
        problems.append(Problem("address", f"{config.address} is also the shore's modem address"))
    if config.protocol not in VERSIONS:
        speaks = " or ".join(map(str, VERSIONS))
        problems.append(
            Problem("protocol", f"is {speaks} (what the shore registered it as), not {config.protocol}")
        )
    if config.max_clock_correction < 0:
        problems.append(
            Problem("max_clock_correction", f"must be 0 or more, not {config.max_clock_correction}")
        )
    return problems


def _folders(config: AgentConfig) -> list[Problem]:
    """The folders the agent writes: each writable by this user, or creatable by it."""
    wanted = [("state_file", Path(config.state_file).parent)]
    wanted += [("tlog_dir", Path(config.tlog_dir))] if config.tlog_dir else []
    wanted += [("modem_log", Path(config.modem_log).parent)] if config.modem_log else []
    problems = []
    for name, folder in wanted:
        existing = next(p for p in (folder, *folder.parents) if p.exists())
        if existing.is_dir() and os.access(existing, os.W_OK | os.X_OK):
            continue
        where = f"{folder}" if existing == folder else f"{folder} cannot be made: {existing}"
        problems.append(Problem(name, f"{where} is not a folder the user {_user()} may write in"))
    return problems


def _plans(config: AgentConfig, base: Path, problems: list[Problem]) -> dict[int, MissionPlan]:
    """Every mission plan that reads and stays inside the limits; a problem for each that does not."""
    plans: dict[int, MissionPlan] = {}
    for index, entry in enumerate(config.missions):
        where = f"missions[{index}]"
        try:
            plan = config.plan(entry, base)
        except OSError as exc:
            problems.append(Problem(where, f"cannot read {exc.filename}: {exc.strerror}"))
            continue
        except KeyError:
            problems.append(Problem(where, f"names neither a file nor a built-in plan: {entry}"))
            continue
        except (ValueError, TypeError) as exc:
            problems.append(Problem(where, str(exc)))
            continue
        if plan.number in plans:
            problems.append(
                Problem(where, f"mission number {plan.number} is also {plans[plan.number].name}'s")
            )
        for north, east, depth in plan.waypoints:
            refusal = config.limits.check_target(north, east, depth)
            if refusal is not None:
                problems.append(
                    Problem(
                        where, f"{plan.name}: waypoint ({north:g}, {east:g}, {depth:g}): {refusal.message}"
                    )
                )
                break
        plans.setdefault(plan.number, plan)
    return plans


# --- what only the vehicle can answer ---------------------------------------------------------------


def modem_problems(url: str) -> list[Problem]:
    """The modem's serial port (or pyserial URL) opens for this user at 19200 baud."""
    import serial

    try:
        serial.serial_for_url(url, baudrate=19200, timeout=0.1).close()
    except (serial.SerialException, OSError, ValueError) as exc:
        reason = {
            errno.ENOENT: "no such device (is the modem's USB serial adapter plugged in? ls /dev/serial/by-id/)",
            errno.EACCES: f"permission denied for the user {_user()} (the service user is in the dialout group)",
            errno.EBUSY: "busy: another program holds it",
        }.get(getattr(exc, "errno", None) or 0, str(exc))
        return [Problem("modem_url", f"{url}: {reason}")]
    return []


def mavlink_problems(url: str, timeout: float = MAVLINK_TIMEOUT) -> list[Problem]:
    """An autopilot answers on ``url`` and its SYSID_MYGCS is the agent's system id."""
    from pymavlink import mavutil

    try:
        conn = mavutil.mavlink_connection(url, source_system=GCS_SYSTEM_ID, source_component=191, retries=0)
    except (OSError, ValueError) as exc:
        reason = getattr(exc, "strerror", None) or exc
        return [Problem("mavlink_url", f"{url}: {reason} (is BlueOS, or the autopilot, up?)")]
    try:
        return _autopilot(conn, url, timeout)
    finally:
        conn.close()


def _autopilot(conn: Any, url: str, timeout: float) -> list[Problem]:
    """The autopilot's heartbeat (a ground station's is not one), then its SYSID_MYGCS."""

    def ask() -> (
        None
    ):  # also makes a udpout endpoint answer; no heartbeat: ArduSub's GCS failsafe counts them
        conn.mav.param_request_read_send(conn.target_system, conn.target_component, b"SYSID_MYGCS", -1)

    ask()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        beat = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        if beat is not None and beat.type != mav.MAV_TYPE_GCS and beat.autopilot != mav.MAV_AUTOPILOT_INVALID:
            break
    else:
        return [
            Problem("mavlink_url", f"{url}: no autopilot's heartbeat within {timeout:g} s (is BlueOS up?)")
        ]
    conn.target_system, conn.target_component = beat.get_srcSystem(), beat.get_srcComponent()
    deadline = time.monotonic() + timeout
    ask()
    while time.monotonic() < deadline:
        value = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
        if value is not None and value.param_id == "SYSID_MYGCS":
            if int(value.param_value) == GCS_SYSTEM_ID:
                return []
            return [
                Problem(
                    "mavlink_url",
                    f"{url}: the autopilot's SYSID_MYGCS is {int(value.param_value)}: it ignores the agent's "
                    f"MANUAL_CONTROL (set it to {GCS_SYSTEM_ID})",
                )
            ]
    return [Problem("mavlink_url", f"{url}: the autopilot did not say its SYSID_MYGCS within {timeout:g} s")]


def _user() -> str:
    return pwd.getpwuid(os.geteuid()).pw_name


# --- the command --------------------------------------------------------------------------------------


def check(path: str, timeout: float = MAVLINK_TIMEOUT) -> int:
    """``tacit agent --check``: every problem on its own line, then one line saying whether to dive."""
    loaded = load(path)
    problems = list(loaded.problems)
    config = loaded.config
    if config is not None and isinstance(config.modem_url, str):
        problems += modem_problems(config.modem_url)
    if config is not None and isinstance(config.mavlink_url, str):
        problems += mavlink_problems(config.mavlink_url, timeout)
    for problem in problems:
        print(f"{path}: {problem}", flush=True)
    if problems or config is None:
        print(f"{path}: {len(problems)} problem(s): not ready to dive", flush=True)
        return EXIT_UNREADY
    missions = ", ".join(f"{number} {plan.name}" for number, plan in sorted(loaded.plans.items()))
    print(
        f"{path}: ready: vehicle {config.address}, modem {config.modem_url}, autopilot on "
        f"{config.mavlink_url} (SYSID_MYGCS {GCS_SYSTEM_ID}), missions {missions or 'none'}",
        flush=True,
    )
    return 0


def starting(path: str) -> Loaded | None:
    """The configuration ``tacit agent`` starts with; None after printing every problem (exit with
    ``EXIT_CONFIG``)."""
    loaded = load(path)
    for problem in loaded.problems:
        print(f"tacit agent: {path}: {problem}", file=sys.stderr, flush=True)
    if loaded.problems:
        print(
            f"tacit agent: not started: {len(loaded.problems)} problem(s) in {path} "
            f"(tacit agent --check --config {path} tries the modem and the autopilot too)",
            file=sys.stderr,
            flush=True,
        )
        return None
    return loaded
