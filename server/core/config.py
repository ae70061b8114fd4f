"""Server settings, in one typed place: defaults, then a TOML file, then ``TACIT_*`` environment variables.

Lists are comma-separated in the environment (``TACIT_WRITE_TOKENS=a,b``), as operators write them.
Secrets (tokens) come from the environment or from a file that only its owner may read
(``TACIT_TOKEN_FILE``); they are never logged.
"""

from __future__ import annotations

import os
import stat
import tomllib
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, ValidationError, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict


class SettingsError(ValueError):
    pass


Csv = Annotated[list[str], NoDecode]
Latitude = Annotated[float, Field(ge=-90, le=90)]
Longitude = Annotated[float, Field(ge=-180, le=180)]


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="TACIT_", extra="forbid", validate_assignment=True)

    database_url: str = "sqlite:///data/tacit.db"
    modem_url: str = ""  # empty: run without a shore modem (API and storage only)
    modem_address: int = Field(1, ge=0, le=127)
    modem_log: str = ""  # file to log every NMEA sentence, with time stamps
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    map_port: int = Field(8080, ge=0, le=65535)
    map_enabled: bool = True
    # the 3D map's address as browsers reach it (e.g. https://shore.example.org:8443 behind a proxy): the
    # dashboard frames it and its Content-Security-Policy allows it; empty: the dashboard's host on map_port
    map_url: str = Field("", pattern=r"^(https?://[A-Za-z0-9.\-]+(:[0-9]{1,5})?(/[A-Za-z0-9._~/\-]*)?)?$")
    write_tokens: Csv = []
    sign_in_failures: int = Field(10, ge=1)  # wrong tokens from one client within sign_in_window: then 429
    sign_in_window: float = Field(60.0, gt=0)  # s
    read_tokens: Csv = []
    cors_origins: Csv = []
    poll_interval: float = Field(2.0, gt=0)  # seconds between link slots when idle
    ping_interval: float = Field(120.0, gt=0)
    command_attempts: int = Field(4, ge=1)
    confirm_timeout: float = Field(120.0, gt=0)  # s: an ACKed command no check-point confirmed is sent again
    sound_speed: float = Field(1500.0, gt=0)
    shore_position: tuple[float, float, float] = (0.0, 0.0, 1.0)  # north, east, depth of the shore modem
    # latitude, longitude (deg) of the fleet's one origin, where north = east = 0 for every vehicle; None:
    # not known (the screens then show metres only)
    origin: tuple[Latitude, Longitude] | None = None
    default_range: float = Field(1000.0, gt=0)  # used for slot timing until a ping measures it
    sync_interval: float = Field(
        60.0, gt=0
    )  # s between SYNC heartbeats (a fifth of the agent's link_lost_timeout)
    sync_budget: float = Field(
        21600.0, ge=0
    )  # s of SYNCs pre-signed ahead for each vehicle's gateway, sent by it while the center's stop coming
    # (a backhaul outage); of the vehicles' time, like sync_interval; 0: none (docs/backhaul.md)
    sync_retry: float = Field(
        5.0, gt=0
    )  # s between SYNCs asking for a chain restart, until one is acknowledged
    time_scale: float = Field(1.0, gt=0)  # simulations faster than real time: acoustic timings divide by this
    max_queued_commands: int = Field(20, ge=1)  # per vehicle: more waiting for the link are refused (429)
    command_share: int = Field(3, ge=1)  # command slots in a row before the vehicle's next slot polls
    stranger_frames_kept: int = Field(1000, ge=0)  # frames from unknown modem addresses: the newest kept
    state_save_interval: float = Field(
        30.0, ge=0
    )  # s between saves of a vehicle's link and decoder state (0: with every batch); server.link.ingest
    restart_min_interval: float = Field(
        60.0, gt=0
    )  # s: an unauthenticated packet asks for a chain restart at
    # most this often (the agent's check-point interval)
    restart_sends: int = Field(2, ge=1)  # a chain-restart request is sent this often, ACKed or not
    nats_url: str = "nats://127.0.0.1:4222"  # the center's broker (docs/backhaul.md)
    nats_credentials: str = ""  # this role's credentials file (`tacit broker-config`); empty: no accounts
    nats_ca: str = ""  # the CA of the broker's certificate, for a tls:// URL
    nats_insecure: bool = False  # no credentials, on a broker without accounts: development only
    deployment: str = ""  # the split shore's name on its broker: prefixes its subjects, streams, consumers
    metrics_host: str = "127.0.0.1"  # a shore process's /metrics listener (Prometheus: server.ops)
    metrics_port: int = Field(9464, ge=0, le=65535)  # 0: none
    retention_days: float = Field(0.0, ge=0)  # relayed frames' records older are deleted; 0: kept for ever
    max_skew: float = Field(120.0, gt=0)  # s a check-point may be ahead of the shore's clock and raise the
    # replay floor to its time (beyond, only to the shore's time)
    # The center's safety functions (server/safety): a command whose planned path passes closer than this
    # to another vehicle's is refused; predicted positions within it plus both uncertainties warn.
    separation: float = Field(5.0, gt=0)  # m, centre to centre
    separation_check_interval: float = Field(5.0, gt=0)  # s between warning checks (silence grows doubt)
    # The team missions' restructuring rule (server/missions/plans.py ``restructure``): when a team vehicle
    # reports a time-sensitive anomaly, this many of the others get a waypoint this far from it.
    restructure_vehicles: int = Field(2, ge=0)
    restructure_radius: float = Field(15.0, gt=0)  # m
    restructure_auto: bool = False  # apply the proposal at once; otherwise an operator confirms it
    # --- what the exported data say of themselves (ACDD-1.3 attributes of the NetCDF export; the
    # deployment's name above is their project) ---
    summary: str = ""  # a paragraph on what the data are; empty: one the shore writes (vehicle, stream)
    creator_name: str = ""  # who collected the data (a person or an institution); empty: not said
    creator_email: str = ""
    creator_url: str = ""
    institution: str = ""
    publisher_name: str = ""  # who distributes the data
    publisher_email: str = ""
    publisher_url: str = ""
    naming_authority: str = ""  # reverse-DNS of the ids' authority, e.g. edu.whoi
    license: str = ""  # the data's licence, e.g. CC-BY-4.0
    acknowledgment: str = ""  # funding and thanks
    # --- the center and its gateways (docs/backhaul.md) ---
    routing_window: float = Field(120.0, gt=0)  # s of frames a gateway's score for a vehicle is made of
    routing_margin: float = Field(3.0, ge=0)  # dB another gateway must score better by to take a vehicle
    routing_dwell: float = Field(60.0, ge=0)  # s a vehicle stays on its gateway before it may move again
    routing_snr_cap: float = Field(30.0)  # dB: the most a gateway's claimed SNR of a frame counts for
    gateway_faulty_slots: int = Field(3, ge=1)  # N: a gateway holding a command for N of its slots, with
    # nothing of its vehicle heard through it and no attempt reported, is faulty (also one whose ACK a
    # check-point refutes): routed around for ``gateway_quarantine`` s
    gateway_quarantine: float = Field(600.0, ge=0)  # s a faulty gateway is routed around after its fault
    gateway_timeout: float = Field(30.0, gt=0)  # s without a heartbeat or event: the gateway is down
    dispatch_receipt: float = Field(10.0, gt=0)  # s a gateway has to report a command stored, else the
    # center sends it through the next gateway (the first never sends it after that: ``start_by``)
    tdma_slot: float = Field(12.0, gt=0)  # s: each gateway's slot in the frame of the gateways on a band
    tdma_guard: float = Field(1.1, ge=0)  # s at each end of a slot: range / 2c + clock error (3 km, NTP)
    center_lease: float = Field(5.0, ge=1)  # s: a center process's lease on a frames partition or on the
    # coordinator's role, renewed every third of it; a killed process's are taken over after it

    @field_validator("write_tokens", "read_tokens", "cors_origins", mode="before")
    @classmethod
    def _comma_separated(cls, value: Any) -> Any:
        if isinstance(value, str):
            return [item.strip() for item in value.split(",") if item.strip()]
        return value

    @field_validator("retention_days")
    @classmethod
    def _outlives_the_stream(cls, value: float) -> float:
        """A record must outlive every redelivery of its message: the frames stream keeps them 7 days."""
        if 0 < value < 8:
            raise ValueError("retention_days is 0 (keep) or at least 8 (the frames stream keeps 7 days)")
        return value

    @field_validator("shore_position", "origin", mode="before")
    @classmethod
    def _position(cls, value: Any) -> Any:
        return tuple(float(x) for x in value.split(",")) if isinstance(value, str) else value

    @classmethod
    def load(cls, path: str | Path | None = None, env: dict[str, str] | None = None) -> Settings:
        """The file's values, overridden by the environment (``env``, default ``os.environ``)."""
        env = dict(os.environ if env is None else env)
        values: dict[str, Any] = tomllib.loads(Path(path).read_text()) if path else {}
        for name in cls.model_fields:
            raw = env.get(f"TACIT_{name.upper()}")
            if raw is not None:
                values[name] = raw
        if env.get("TACIT_TOKEN_FILE"):
            values.update(_read_token_file(Path(env["TACIT_TOKEN_FILE"])))
        try:
            return cls.model_validate(values)
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(str(p) for p in first["loc"]) or "settings"
            raise SettingsError(f"{path or 'environment'}: {where}: {first['msg']}") from None


def _read_token_file(path: Path) -> dict[str, list[str]]:
    """A TOML file with ``write_tokens`` / ``read_tokens``; refused if others may read it."""
    mode = path.stat().st_mode
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise SettingsError(f"{path}: token file must not be readable by group or others (chmod 600)")
    data = tomllib.loads(path.read_text())
    return {k: list(v) for k, v in data.items() if k in ("write_tokens", "read_tokens")}
