"""Server settings: environment variables ``TACIT_*`` override a TOML file, which overrides defaults.

Secrets (tokens) are read from the environment or from a file that only its owner may read; they are
never logged.
"""

from __future__ import annotations

import os
import stat
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path

from tacit.config import check_keys


class SettingsError(ValueError):
    pass


@dataclass
class Settings:
    database_url: str = "sqlite:///data/tacit.db"
    modem_url: str = ""  # empty: run without a shore modem (API and storage only)
    modem_address: int = 1
    modem_log: str = ""  # file to log every NMEA sentence, with time stamps
    host: str = "127.0.0.1"
    port: int = 8000
    map_port: int = 8080
    map_enabled: bool = True
    write_tokens: list[str] = field(default_factory=list)
    read_tokens: list[str] = field(default_factory=list)
    cors_origins: list[str] = field(default_factory=list)
    poll_interval: float = 2.0  # seconds between link slots when idle
    ping_interval: float = 120.0
    command_attempts: int = 4
    confirm_timeout: float = 120.0  # s: an ACKed command no check-point has confirmed is sent again
    sound_speed: float = 1500.0
    shore_position: tuple[float, float, float] = (0.0, 0.0, 1.0)  # north, east, depth of the shore modem
    default_range: float = 1000.0  # used for slot timing until a ping measures it
    time_scale: float = 1.0  # simulations faster than real time: acoustic timings divide by this

    @classmethod
    def load(cls, path: str | Path | None = None, env: dict[str, str] | None = None) -> Settings:
        values: dict[str, object] = {}
        if path:
            values.update(tomllib.loads(Path(path).read_text()))
        env = dict(os.environ if env is None else env)
        try:
            check_keys(str(path), values, cls)
        except ValueError as exc:
            raise SettingsError(str(exc)) from None
        known = {f.name: f for f in fields(cls)}
        for name, f in known.items():
            raw = env.get(f"TACIT_{name.upper()}")
            if raw is not None:
                values[name] = _parse(name, str(f.type), raw)
        token_file = env.get("TACIT_TOKEN_FILE")
        if token_file:
            values.update(_read_token_file(Path(token_file)))
        settings = cls(**values)  # type: ignore[arg-type]
        if isinstance(settings.shore_position, list):
            settings.shore_position = tuple(settings.shore_position)  # type: ignore[assignment]
        return settings


def _parse(name: str, kind: str, raw: str) -> object:
    try:
        if kind.startswith("list"):
            return [item.strip() for item in raw.split(",") if item.strip()]
        if kind == "bool":
            return raw.strip().lower() in ("1", "true", "yes", "on")
        if kind == "int":
            return int(raw)
        if kind == "float":
            return float(raw)
        if kind.startswith("tuple"):
            return tuple(float(x) for x in raw.split(","))
    except ValueError:
        raise SettingsError(f"TACIT_{name.upper()}: cannot read {raw!r} as {kind}") from None
    return raw


def _read_token_file(path: Path) -> dict[str, list[str]]:
    """A TOML file with ``write_tokens`` / ``read_tokens``; refused if others may read it."""
    mode = path.stat().st_mode
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise SettingsError(f"{path}: token file must not be readable by group or others (chmod 600)")
    data = tomllib.loads(path.read_text())
    return {k: list(v) for k, v in data.items() if k in ("write_tokens", "read_tokens")}
