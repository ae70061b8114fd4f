"""Telemetry export through the API: CSV and Parquet files for a vehicle, a stream and a time window,
written to disk and read back; absent samples are empty cells (CSV) and nulls (Parquet)."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import insert

from server.app import create_app
from server.db import writing
from server.models import Telemetry
from server.settings import Settings

OP = {"Authorization": "Bearer operator-token"}
OBS = {"Authorization": "Bearer observer-token"}
T0 = 1_700_000_000.0


def env(tick: int, values: list, certain: bool = True, vehicle_id: int = 1) -> dict:
    return {"vehicle_id": vehicle_id, "stream": "env", "tick": tick, "time": T0 + tick, "values": values,
            "certain": certain}  # fmt: skip


@pytest.fixture
def client(tmp_path: Path):
    settings = Settings(database_url=f"sqlite:///{tmp_path}/tacit.db", modem_url="", map_enabled=False,
                        write_tokens=["operator-token"], read_tokens=["observer-token"], ping_interval=3600)  # fmt: skip
    with TestClient(create_app(settings)) as c:
        for name, address in (("rov1", 2), ("rov2", 3)):
            c.post("/api/v1/vehicles", json={"name": name, "address": address}, headers=OP)
        rows = [env(i, [20.0 + 0.01 * i, 1.5, 8.0]) for i in range(12_000)]  # several fetches and row groups
        rows[3] = env(3, [20.5, None, 8.0])  # an absent sample
        rows[4] = env(4, [20.5, 1.5, 8.0], certain=False)
        rows.append(env(5, [99.0, 9.0, 9.0], vehicle_id=2))  # another vehicle's
        rows.append({**env(6, [1.0] * 9), "stream": "imu"})  # another stream
        with writing(c.app.state.shore.db) as s:  # type: ignore[attr-defined]
            s.execute(insert(Telemetry), rows)
            s.commit()
        yield c


def download(client: TestClient, path: Path, url: str, **params: object) -> Path:
    response = client.get(url, params=params, headers=OBS)
    assert response.status_code == 200, response.text
    assert "attachment" in response.headers["content-disposition"]
    path.write_bytes(response.content)
    return path


def test_csv_of_a_vehicle_stream_and_window(client: TestClient, tmp_path: Path) -> None:
    path = download(client, tmp_path / "env.csv", "/api/v1/telemetry.csv", vehicle_id=1, stream="env")
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["time", "tick", "certain", "temperature", "depth", "oxygen"]
    assert len(rows) == 12_000 and [int(r["tick"]) for r in rows[:5]] == [0, 1, 2, 3, 4]
    assert float(rows[2]["time"]) == T0 + 2 and float(rows[2]["temperature"]) == pytest.approx(20.02)
    assert rows[3]["depth"] == "" and rows[3]["temperature"] == "20.5"  # absent: an empty cell
    assert [r["certain"] for r in rows[3:5]] == ["1", "0"]
    window = download(client, tmp_path / "w.csv", "/api/v1/telemetry.csv", vehicle_id=1, stream="env",
                      since=T0 + 10, until=T0 + 19)  # fmt: skip
    with window.open(newline="") as f:
        assert [int(r["tick"]) for r in csv.DictReader(f)] == list(range(10, 20))


def test_parquet_of_a_vehicle_stream_and_window(client: TestClient, tmp_path: Path) -> None:
    path = download(client, tmp_path / "env.parquet", "/api/v1/telemetry.parquet", vehicle_id=1, stream="env")
    table = pq.read_table(path)
    assert table.column_names == ["time", "tick", "certain", "temperature", "depth", "oxygen"]
    assert str(table.schema.field("depth").type) == "double" and table.num_rows == 12_000
    assert pq.ParquetFile(path).metadata.num_row_groups >= 2
    data = table.to_pydict()
    assert data["tick"][:5] == [0, 1, 2, 3, 4] and data["time"][7] == T0 + 7
    assert data["depth"][3] is None and data["temperature"][3] == 20.5  # absent: null, not 0 or NaN
    assert data["certain"][3:5] == [True, False]
    assert math.isclose(data["temperature"][11_999], 20.0 + 0.01 * 11_999)
    window = pq.read_table(download(client, tmp_path / "w.parquet", "/api/v1/telemetry.parquet", vehicle_id=2,
                                    stream="env", since=T0, until=T0 + 100))  # fmt: skip
    assert window.to_pydict()["temperature"] == [99.0]
    empty = pq.read_table(download(client, tmp_path / "e.parquet", "/api/v1/telemetry.parquet", vehicle_id=1,
                                   stream="imu", since=T0 + 1e6))  # fmt: skip
    assert empty.num_rows == 0 and "zmag" in empty.column_names


@pytest.mark.parametrize("suffix", ["csv", "parquet"])
def test_export_refuses_an_unknown_stream_and_needs_a_reader(client: TestClient, suffix: str) -> None:
    refused = client.get(
        f"/api/v1/telemetry.{suffix}", params={"vehicle_id": 1, "stream": "sonar"}, headers=OBS
    )
    assert refused.status_code == 422 and refused.json()["field"] == "stream"
    assert (
        client.get(f"/api/v1/telemetry.{suffix}", params={"vehicle_id": 1, "stream": "env"}).status_code
        == 401
    )
