"""Operations of a shore process: ``/metrics`` in Prometheus' text format, parsed here, from a center
consuming a gateway's frames through a real nats-server and from a shore with its own modem; retention of the relayed frames'
records; backup and restore of the center's database, PostgreSQL and SQLite, restored into a fresh one
and read back."""

from __future__ import annotations

import asyncio
import contextlib
import re
import stat
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text

from launch.split import throwaway_database as postgres_database
from server.app import shore_app
from server.backhaul.center import Center
from server.backhaul.gateway import Gateway
from server.backhaul.outbox import Outbox
from server.backhaul.relay import RelayedIncoming
from server.backhaul.subjects import FrameMessage
from server.commands.schemas import CommandIn
from server.commands.service import CommandDesk
from server.core.config import Settings, SettingsError
from server.core.db import make_engine, migrate
from server.core.events import Bus
from server.link.state import IncomingFrame
from server.ops.process import operate
from server.ops.service import DAY, Retention
from server.vehicles.schemas import VehicleIn
from server.vehicles.service import Vehicles
from tacit import auth
from tacit.cli import main
from tacit.packets import CheckpointPacket, MissionState
from tests.integration.server.backhaul.test_frames_and_commands import hear, ingest_on, stored, until
from tests.support.api import OP, offline_settings
from tests.support.nats import NATS_SERVER, NatsServer, free_port

SAMPLE = re.compile(r'^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{((?:[a-zA-Z_]\w*="(?:[^"\\]|\\.)*",?)*)\})? (\S+)$')
LABEL = re.compile(r'([a-zA-Z_]\w*)="((?:[^"\\]|\\.)*)"')


def parse(exposition: str) -> dict[str, dict[tuple[tuple[str, str], ...], float]]:
    """Prometheus' text format, strictly: every sample's family has its HELP and TYPE first; the
    samples by family and labels."""
    families: dict[str, dict[tuple[tuple[str, str], ...], float]] = {}
    kinds: dict[str, str] = {}
    for line in exposition.splitlines():
        if line.startswith("# HELP "):
            families.setdefault(line.split()[2], {})
        elif line.startswith("# TYPE "):
            _, _, name, kind = line.split()
            assert kind in ("counter", "gauge") and name in families
            kinds[name] = kind
        else:
            match = SAMPLE.match(line)
            assert match, f"not a sample: {line!r}"
            name, _, labels, value = match.groups()
            assert name in kinds, f"{name} has no TYPE"
            key = tuple(sorted(LABEL.findall(labels or "")))
            families[name][key] = float(value)
    return families


@pytest.fixture
def sqlite_url(tmp_path: Path) -> str:
    url = f"sqlite:///{tmp_path}/center.db"
    migrate(url)
    return url


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[NatsServer]:
    server = NatsServer(tmp_path / "broker")
    server.start()
    try:
        yield server
    finally:
        server.stop()


@pytest.mark.skipif(not Path(NATS_SERVER).exists(), reason="nats-server is not installed")
def test_metrics_in_prometheus_format(broker: NatsServer, sqlite_url: str, tmp_path: Path) -> None:
    """Frames per gateway, the gateway's outbox and heartbeats, the backhaul's state and since when, the
    decode errors: from ``tacit center``'s listener, and the backhaul down after the broker stops."""
    settings = Settings(database_url=sqlite_url, metrics_port=free_port())
    url = f"http://127.0.0.1:{settings.metrics_port}/metrics"

    async def scrape() -> dict[str, dict[tuple[tuple[str, str], ...], float]]:
        async with httpx.AsyncClient() as client:
            for _ in range(100):  # the listener starts beside the consumer
                with contextlib.suppress(httpx.ConnectError):
                    response = await client.get(url)
                    break
                await asyncio.sleep(0.05)
        assert response.status_code == 200
        assert response.headers["content-type"].startswith("text/plain; version=0.0.4")
        return parse(response.text)

    async def main() -> None:
        outbox = Outbox(tmp_path / "ship.db", "ship")
        gateway = Gateway(outbox, broker.url, heartbeat=0.2)
        center = Center(ingest_on(sqlite_url), broker.url)
        center.guard.heartbeat = 0.2
        started = time.time()
        task = asyncio.create_task(operate(center, center.run(), center.ingest.db, settings))
        await gateway.start()
        try:
            hear(outbox, 1, 3)
            await until(lambda: len(stored(sqlite_url)) == 3, lambda: asyncio.sleep(0.05))
            await until(  # its events come in order: a heartbeat from before the publisher caught up first
                lambda: center.gateways.get("ship", {}).get("outbox") == 0, lambda: asyncio.sleep(0.05)
            )
            m = await scrape()
            ship = (("gateway", "ship"),)
            assert m["tacit_gateway_frames_total"][ship] == 3
            assert m["tacit_gateway_up"][ship] == 1
            assert m["tacit_gateway_outbox_waiting"][ship] == 0
            assert started <= m["tacit_gateway_state_since_timestamp_seconds"][ship] <= time.time()
            assert m["tacit_backhaul_up"][()] == 1
            assert m["tacit_backhaul_pending_frames"][()] == 0
            assert m["tacit_center_partitions"][()] == 16 and m["tacit_center_coordinator"][()] == 1
            assert m["tacit_ingest_total"][(("counter", "frames"),)] == 3
            assert m["tacit_decode_errors_total"][(("kind", "rejected"),)] == 0
            assert m["tacit_retention_pruned_total"][()] == 0
            broker.stop()
            await until(lambda: not center.up, lambda: asyncio.sleep(0.05))
            down = await scrape()
            assert down["tacit_backhaul_up"][()] == 0
            assert down["tacit_backhaul_state_since_timestamp_seconds"][()] > started
            await asyncio.sleep(0.7)  # three heartbeats missed
            assert (await scrape())["tacit_gateway_up"][ship] == 0
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
            await gateway.stop()
            await center.close()

    asyncio.run(main())


def relay(url: str, n: int, at: float) -> None:
    """``n`` frames from the ship's gateway into the center's store."""
    frames = [
        FrameMessage(f"ship-0a0b0c0d-{i}", "ship", 9, 0, bytes([i]), snr_in=5.0, at=at) for i in range(n)
    ]
    ingest_on(url).handle_batch([RelayedIncoming.of(f) for f in frames])


def count(url: str, table: str) -> int:
    with create_engine(url).connect() as c:
        return int(c.execute(text(f"SELECT count(*) FROM {table}")).scalar_one())


def test_retention_prunes_old_records_and_counts_them(sqlite_url: str) -> None:
    relay(sqlite_url, 4, time.time())
    retention = Retention(make_engine(sqlite_url), days=8)
    assert retention.prune() == 0
    assert retention.prune(now=time.time() + 9 * DAY) == 4 and retention.pruned == 4
    assert count(sqlite_url, "relayedframe") == 0 and count(sqlite_url, "frame") == 4  # the frames stay
    assert Retention(make_engine(sqlite_url), days=0).prune(now=time.time() + 1000 * DAY) == 0


def test_retention_must_outlive_the_frames_stream() -> None:
    with pytest.raises(SettingsError, match="at least 8"):
        Settings.load(env={"TACIT_RETENTION_DAYS": "3"})
    assert Settings.load(env={"TACIT_RETENTION_DAYS": "30"}).retention_days == 30


def campaign(url: str) -> None:
    """A vehicle, a command queued for it, frames relayed: what a restore must bring back."""
    migrate(url)
    db = make_engine(url)
    vehicle = Vehicles(db).create(VehicleIn(name="rov1", address=2))
    desk = CommandDesk(db, Bus(), lambda address: None, max_queued=5)
    desk.submit(vehicle.id or 0, CommandIn(command="hold"), "operator")
    relay(url, 5, time.time())


def contents(url: str) -> dict[str, int]:
    return {t: count(url, t) for t in ("vehicle", "command", "frame", "relayedframe")}


def backup_and_restore(source: str, target: str, file: Path) -> None:
    assert main(["database", "backup", str(file), "--database-url", source]) == 0
    assert stat.S_IMODE(file.stat().st_mode) == 0o600  # it holds the vehicles' keys
    assert main(["database", "restore", str(file), "--database-url", target]) == 0


def test_backup_and_restore_postgresql(postgres_server: str, tmp_path: Path) -> None:
    with postgres_database(postgres_server) as source, postgres_database(postgres_server) as target:
        campaign(source)
        backup_and_restore(source, target, tmp_path / "center.dump")
        assert (
            contents(target)
            == contents(source)
            == {"vehicle": 1, "command": 1, "frame": 5, "relayedframe": 5}
        )
        migrate(target)  # the restored database is at the running version's schema
        relay(target, 1, time.time())  # and a center goes on where it stopped: a duplicate is dropped
        assert count(target, "frame") == 5


def test_backup_and_restore_sqlite(
    sqlite_url: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    campaign(sqlite_url)
    target = f"sqlite:///{tmp_path}/restored/center.db"
    backup_and_restore(sqlite_url, target, tmp_path / "center.sqlite")
    assert (
        contents(target)
        == contents(sqlite_url)
        == {"vehicle": 1, "command": 1, "frame": 5, "relayedframe": 5}
    )
    assert main(["database", "restore", str(tmp_path / "center.sqlite"), "--database-url", target]) == 2
    assert "exists" in capsys.readouterr().err  # never over a database


def test_a_corrupt_truncated_or_unchecksummed_backup_restores_nothing(
    sqlite_url: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A flipped byte inside a value (the vehicle's name: SQLite's integrity check passes it), a cut-off
    file and a bare SQLite file are each refused in one line; no file or folder is left behind."""
    campaign(sqlite_url)
    good = tmp_path / "center.backup"
    assert main(["database", "backup", str(good), "--database-url", sqlite_url]) == 0
    data = good.read_bytes()
    flipped = data.replace(b"rov1", b"rov7", 1)
    assert flipped != data
    cases = {
        "flipped": (flipped, "corrupt (its SHA-256 is"),
        "truncated": (data[: len(data) // 2], "truncated or padded"),
        "bare": (Path(sqlite_url.removeprefix("sqlite:///")).read_bytes(), "not a Tacit backup"),
    }
    for name, (content, says) in cases.items():
        bad = tmp_path / f"{name}.backup"
        bad.write_bytes(content)
        target = tmp_path / "restored" / name / "center.db"
        assert main(["database", "restore", str(bad), "--database-url", f"sqlite:///{target}"]) == 2
        err = capsys.readouterr().err
        assert says in err and err.count("\n") == 1, err
        assert not (tmp_path / "restored").exists()
    assert main(["database", "restore", str(good), "--database-url", f"sqlite:///{tmp_path}/ok.db"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix in (".part", ".payload")) == []


def test_database_has_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["database", "--help"])
    assert stop.value.code == 0 and "restore" in capsys.readouterr().out


def test_a_shore_with_its_own_modem_serves_its_metrics(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """``tacit serve`` and the demo (``shore_app``): the shore modem, the link's counters, each vehicle's
    frames, packets and last heard, the ingest's counters, on a listener of their own, which stops with
    the app without a traceback."""
    settings = offline_settings(tmp_path, metrics_port=free_port())
    key = "6b" * 32
    with TestClient(shore_app(settings)) as client:
        body = {"name": "rov1", "address": 2, "key": key}
        assert client.post("/api/v1/vehicles", json=body, headers=OP).status_code == 201
        heard = time.time()
        frame = auth.sign_checkpoint(
            CheckpointPacket(seq=1, time=int(heard), state=MissionState.WAITING), bytes.fromhex(key), 1, 2, []
        )
        client.app.state.shore.ingest.handle(IncomingFrame(2, 1, frame))  # type: ignore[attr-defined]
        for _ in range(100):  # the listener starts beside the app
            with contextlib.suppress(httpx.ConnectError):
                response = httpx.get(f"http://127.0.0.1:{settings.metrics_port}/metrics")
                break
            time.sleep(0.05)
        assert client.get("/metrics").status_code == 404  # not on the operators' API
    assert response.headers["content-type"].startswith("text/plain; version=0.0.4")
    m = parse(response.text)
    rov1 = (("vehicle", "rov1"),)
    assert m["tacit_modem_ready"][()] == 0  # no modem: the API alone
    assert m["tacit_vehicle_frames_total"][rov1] == 1 and m["tacit_vehicle_packets_total"][rov1] == 1
    assert heard - 1 <= m["tacit_vehicle_last_heard_timestamp_seconds"][rov1] <= time.time()
    assert m["tacit_ingest_total"][(("counter", "frames"),)] == 1
    assert m["tacit_link_total"][(("counter", "polls"),)] == 0
    assert m["tacit_decode_errors_total"][(("kind", "forged"),)] == 0
    assert "Traceback" not in capfd.readouterr().err
