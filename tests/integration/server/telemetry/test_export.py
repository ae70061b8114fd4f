"""Telemetry export through the API: CSV, Parquet and NetCDF (CF) files for a vehicle, a stream and a time
window, written to disk and read back: absent samples are empty cells (CSV), nulls (Parquet) and NaN
fill values (NetCDF); each row says how far it may be believed, and each file what its values mean."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from fastapi.testclient import TestClient
from scipy.io import netcdf_file
from sqlalchemy import insert

from server.app import create_app
from server.core.db import writing
from server.telemetry import repository
from server.telemetry.models import PacketTrust, Telemetry
from tacit.navigation import EARTH_RADIUS
from tacit.streams import ENV_PERIOD, IMU_PERIOD
from tests.support.api import OP, offline_settings

OBS = {"Authorization": "Bearer observer-token"}
T0 = 1_700_000_000.0
HEADER = [
    "time (seconds since 1970-01-01T00:00:00Z)",
    "tick",
    "in_tick",
    "certain",
    "verification",
    "temperature (degree_Celsius)",
    "depth (m)",
    "oxygen (mg/L)",
]
# the packets the samples came in: (auth, trusted), a sample verified when its packet is trusted
PACKETS = {
    "trusted": (PacketTrust.VERIFIED, True),
    "pending": (PacketTrust.PENDING, False),
    "untrusted": (PacketTrust.VERIFIED, False),
    "forged": (PacketTrust.FORGED, False),
}
# tick: its packet and the verification the export gives it (every other tick: "trusted", verified)
TICKS = {
    4: ("pending", "pending"),
    5: ("untrusted", "unverifiable"),
    6: (None, "unverifiable"),
    8: ("forged", "forged"),
}


def env(
    tick: int,
    values: list,
    certain: bool = True,
    vehicle_id: int = 1,
    packet: str | None = "trusted",
    ids: dict[str | None, int | None] | None = None,
) -> dict:
    packet_id = (ids or {}).get(packet)
    return {
        "vehicle_id": vehicle_id,
        "stream": "env",
        "tick": tick,
        "time": T0 + tick,
        "values": values,
        "certain": certain,
        "packet_id": packet_id,
        "verified": packet_id is not None and packet == "trusted",
    }


def add_packets(s, vehicle_id: int) -> dict[str | None, int | None]:
    frame = repository.add_frame(s, {"direction": "in", "src": 2, "dest": 1, "data": b""})
    ids: dict[str | None, int | None] = {None: None}
    for seq, (name, (auth, trusted)) in enumerate(PACKETS.items()):
        ids[name] = repository.add_packet(
            s,
            {
                "frame_id": frame,
                "vehicle_id": vehicle_id,
                "type": "priority",
                "seq": seq,
                "body": {},
                "auth": auth,
                "trusted": trusted,
            },
        )
    return ids


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    """One shore holding the samples the tests export, made once for the module: the tests only read
    what it holds (the one that writes adds a vehicle of its own)."""
    settings = offline_settings(tmp_path_factory.mktemp("export"), ping_interval=3600)
    with TestClient(create_app(settings)) as c:
        for name, address in (("rov1", 2), ("rov2", 3)):
            c.post("/api/v1/vehicles", json={"name": name, "address": address}, headers=OP)
        with writing(c.app.state.shore.db) as s:  # type: ignore[attr-defined]
            ids = add_packets(s, 1)
            rows = [
                env(i, [20.0 + 0.01 * i, 1.5, 8.0], packet=TICKS.get(i, ("trusted",))[0], ids=ids)
                for i in range(12_000)
            ]  # several fetches and row groups
            rows[3] = env(3, [20.5, None, 8.0], ids=ids)  # an absent sample
            rows[4] = env(4, [], certain=False, packet="pending", ids=ids)  # a lost span
            rows.append(env(9, [66.0, 6.6, 6.6], packet="forged", ids=ids))  # a forgery beside a genuine one
            rows.append(env(5, [99.0, 9.0, 9.0], vehicle_id=2))  # another vehicle's
            rows.append(env(5, [99.5, 9.0, 9.0], vehicle_id=2))  # ... and a second sample of its tick
            rows.append({**env(6, [1.0] * 9), "stream": "imu"})  # another stream
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
    assert list(rows[0]) == HEADER  # one plain header row: each name with its units
    time, temperature, depth = HEADER[0], HEADER[5], HEADER[6]
    assert len(rows) == 11_999 and [int(r["tick"]) for r in rows[:5]] == [0, 1, 2, 3, 4]  # less the forged
    assert float(rows[2][time]) == T0 + 2 and float(rows[2][temperature]) == pytest.approx(20.02)
    assert rows[3][depth] == "" and rows[3][temperature] == "20.5"  # absent: an empty cell
    assert [r["certain"] for r in rows[3:5]] == ["1", "0"] and rows[4][temperature] == ""
    window = download(
        client,
        tmp_path / "w.csv",
        "/api/v1/telemetry.csv",
        vehicle_id=1,
        stream="env",
        since=T0 + 10,
        until=T0 + 19,
    )
    with window.open(newline="") as f:
        assert [int(r["tick"]) for r in csv.DictReader(f)] == list(range(10, 20))


@pytest.mark.parametrize("suffix", ["csv", "parquet", "nc"])
def test_two_samples_of_one_tick_are_two_rows_numbered_in_it(
    client: TestClient, tmp_path: Path, suffix: str
) -> None:
    """A tick may hold several samples (a sensor faster than the stream's period): each is its own row at
    the tick's time, in the order measured, and ``in_tick`` says it is not a copy of the one before."""
    path = download(
        client, tmp_path / f"rov2.{suffix}", f"/api/v1/telemetry.{suffix}", vehicle_id=2, stream="env"
    )
    if suffix == "csv":
        with path.open(newline="") as f:
            rows = list(csv.DictReader(f))
        places = [int(r["in_tick"]) for r in rows]
        temperatures = [float(r[HEADER[5]]) for r in rows]
    elif suffix == "parquet":
        data = pq.read_table(path).to_pydict()
        places, temperatures = data["in_tick"], data["temperature"]
    else:
        with netcdf_file(path, mmap=False) as f:
            places = list(f.variables["in_tick"][:])
            temperatures = list(f.variables["temperature"][:])
    assert places == [0, 1] and temperatures == [99.0, 99.5]


@pytest.mark.parametrize("suffix", ["csv", "parquet", "nc"])
def test_each_sample_says_how_far_it_may_be_believed(client: TestClient, tmp_path: Path, suffix: str) -> None:
    """verified (its packet and its chain vouched for), pending (no check-point yet; a lost span keeps its
    packet's), unverifiable (vouched for, decoded on an unvouched state; or no packet at all), forged: left
    out unless asked for."""
    for include_forged in (False, True):
        path = download(
            client,
            tmp_path / f"env.{suffix}",
            f"/api/v1/telemetry.{suffix}",
            vehicle_id=1,
            stream="env",
            until=T0 + 20,
            include_forged=include_forged,
        )
        ticks, verification = read_verification(path)
        expected = [(tick, TICKS.get(tick, (None, "verified"))[1]) for tick in range(21)]
        if include_forged:
            expected.insert(10, (9, "forged"))  # the forgery dated as tick 9, beside it
        else:
            expected = [(tick, v) for tick, v in expected if v != "forged"]
        assert list(zip(ticks, verification, strict=True)) == expected


def read_verification(path: Path) -> tuple[list[int], list[str]]:
    """Each row's tick and verification, from any of the three formats."""
    if path.suffix == ".csv":
        with path.open(newline="") as f:
            rows = list(csv.DictReader(f))
        return [int(r["tick"]) for r in rows], [r["verification"] for r in rows]
    if path.suffix == ".parquet":
        data = pq.read_table(path).to_pydict()
        return data["tick"], data["verification"]
    with netcdf_file(path, mmap=False) as f:
        flag = f.variables["verification"]
        meanings = flag.flag_meanings.decode().split()
        assert list(flag.flag_values) == list(range(len(meanings)))
        return list(f.variables["tick"][:]), [meanings[v] for v in flag[:]]


def test_parquet_of_a_vehicle_stream_and_window(client: TestClient, tmp_path: Path) -> None:
    path = download(client, tmp_path / "env.parquet", "/api/v1/telemetry.parquet", vehicle_id=1, stream="env")
    table = pq.read_table(path)
    assert table.column_names == [
        "time",
        "tick",
        "in_tick",
        "certain",
        "verification",
        "temperature",
        "depth",
        "oxygen",
    ]
    assert str(table.schema.field("depth").type) == "double" and table.num_rows == 11_999
    assert pq.ParquetFile(path).metadata.num_row_groups >= 2
    data = table.to_pydict()
    assert data["tick"][:5] == [0, 1, 2, 3, 4] and data["time"][7] == T0 + 7
    assert data["depth"][3] is None and data["temperature"][3] == 20.5  # absent: null, not 0 or NaN
    assert data["certain"][3:5] == [True, False]
    assert math.isclose(data["temperature"][11_998], 20.0 + 0.01 * 11_999)
    window = pq.read_table(
        download(
            client,
            tmp_path / "w.parquet",
            "/api/v1/telemetry.parquet",
            vehicle_id=2,
            stream="env",
            since=T0,
            until=T0 + 100,
        )
    )
    assert window.to_pydict()["temperature"] == [99.0, 99.5]


def test_parquet_says_what_its_values_mean(client: TestClient, tmp_path: Path) -> None:
    schema = pq.read_schema(
        download(client, tmp_path / "env.parquet", "/api/v1/telemetry.parquet", vehicle_id=1, stream="env")
    )
    meta = {k.decode(): v.decode() for k, v in schema.metadata.items()}
    assert meta["vehicle_name"] == "rov1" and meta["vehicle_id"] == "1" and meta["stream"] == "env"
    assert meta["stream_period"] == str(ENV_PERIOD) and meta["stream_period_units"] == "s"
    assert meta["time_precision"] == str(ENV_PERIOD / 2) and meta["time_precision_units"] == "s"
    field = {k.decode(): v.decode() for k, v in schema.field("temperature").metadata.items()}
    assert field["units"] == "degree_Celsius" and field["error_bound"] == "0.05"
    assert field["standard_name"] == "sea_water_temperature"
    time = {k.decode(): v.decode() for k, v in schema.field("time").metadata.items()}
    assert time["units"] == "seconds since 1970-01-01T00:00:00Z"
    verification = schema.field("verification").metadata[b"comment"].decode()
    assert all(f"{v}: " in verification for v in ("verified", "pending", "unverifiable", "forged"))


def test_netcdf_follows_the_cf_conventions(client: TestClient, tmp_path: Path) -> None:
    path = download(client, tmp_path / "env.nc", "/api/v1/telemetry.nc", vehicle_id=1, stream="env")
    with netcdf_file(path, mmap=False) as f:
        assert f.Conventions == b"CF-1.8, ACDD-1.3" and f.featureType == b"trajectory"
        assert (
            f.vehicle_name == b"rov1"
            and f.vehicle_id == 1
            and f.stream == b"env"
            and f.stream_period == ENV_PERIOD
        )
        assert b"rov1" in f.title and f.history and f.source
        trajectory = f.variables["trajectory"]
        assert trajectory.cf_role == b"trajectory_id" and trajectory._Encoding == b"utf-8"
        assert trajectory[:].tobytes() == b"rov1"
        time = f.variables["time"]
        assert time.dimensions == ("obs",) and len(time[:]) == 11_999 and time[7] == T0 + 7
        assert (time.units, time.standard_name, time.axis) == (
            b"seconds since 1970-01-01T00:00:00Z",
            b"time",
            b"T",
        )
        temperature, depth, oxygen = (f.variables[c] for c in ("temperature", "depth", "oxygen"))
        assert (
            temperature.units == b"degree_Celsius" and temperature.standard_name == b"sea_water_temperature"
        )
        assert depth.units == b"m" and depth.standard_name == b"depth"
        assert (
            oxygen.units == b"mg/L" and oxygen.standard_name == b"mass_concentration_of_oxygen_in_sea_water"
        )
        assert (
            temperature.error_bound == 0.05 and temperature.error_bound.dtype == np.float64
        )  # not 0.0500000007
        assert temperature.coordinates == b"time tick in_tick depth" and f.stream_period.dtype == np.float64
        assert depth.positive == b"down" and "lat" not in f.variables  # no origin: no latitude
        assert temperature.ancillary_variables == b"certain verification"
        assert np.isnan(depth._FillValue) and depth._FillValue.dtype == np.float64 and depth.typecode() == "d"
        assert np.isnan(depth[3]) and temperature[3] == 20.5  # absent: NaN
        assert np.isnan(temperature[4]) and list(f.variables["certain"][3:5]) == [1, 0]
        certain = f.variables["certain"]
        assert list(certain.flag_values) == [0, 1] and certain.flag_meanings == b"uncertain certain"
        assert f.variables["verification"].flag_meanings == b"verified pending unverifiable forged"
        assert math.isclose(temperature[11_998], 20.0 + 0.01 * 11_999)


def test_netcdf_spells_the_imu_units_as_udunits_reads_them(client: TestClient, tmp_path: Path) -> None:
    """MAVLink's "mG" (milli-g) is no unit UDUNITS reads: the acceleration is in m s-2, scaled."""
    response = client.get("/api/v1/telemetry.nc", params={"vehicle_id": 1, "stream": "imu"}, headers=OBS)
    assert response.status_code == 200 and response.headers["content-type"] == "application/x-netcdf"
    (tmp_path / "imu.nc").write_bytes(response.content)
    with netcdf_file(tmp_path / "imu.nc", mmap=False) as f:
        units = {name: f.variables[name].units for name in ("xacc", "xgyro", "xmag")}
        assert units == {"xacc": b"9.80665e-3 m s-2", "xgyro": b"mrad/s", "xmag": b"mGauss"}
        assert f.variables["xacc"].error_bound == 10.0 and not hasattr(f.variables["xacc"], "standard_name")
        assert list(f.variables["xacc"][:]) == [1.0]


@pytest.mark.parametrize("suffix", ["csv", "parquet", "nc"])
def test_every_export_gives_each_channels_error_bound(client: TestClient, suffix: str) -> None:
    response = client.get(
        f"/api/v1/telemetry.{suffix}", params={"vehicle_id": 1, "stream": "env"}, headers=OBS
    )
    assert response.headers["tacit-error-bounds"] == "temperature=0.05, depth=0.05, oxygen=0.05"


@pytest.mark.parametrize("suffix", ["csv", "parquet", "nc"])
def test_export_refuses_an_unknown_stream_and_needs_a_reader(client: TestClient, suffix: str) -> None:
    refused = client.get(
        f"/api/v1/telemetry.{suffix}", params={"vehicle_id": 1, "stream": "sonar"}, headers=OBS
    )
    assert refused.status_code == 422 and refused.json()["field"] == "stream"
    assert (
        client.get(f"/api/v1/telemetry.{suffix}", params={"vehicle_id": 1, "stream": "env"}).status_code
        == 401
    )


@pytest.mark.parametrize("suffix", ["csv", "parquet", "nc"])
def test_mistakes_in_an_export_are_errors_not_empty_files(client: TestClient, suffix: str) -> None:
    """An unknown vehicle is a 404; an inverted window, or one holding none of the stream's samples, is a
    422 that says where the samples are (a header-only file would look like "no data was taken")."""
    url = f"/api/v1/telemetry.{suffix}"
    unknown = client.get(url, params={"vehicle_id": 99, "stream": "env"}, headers=OBS)
    assert unknown.status_code == 404 and unknown.json()["field"] == "vehicle_id"
    inverted = client.get(
        url, params={"vehicle_id": 2, "stream": "env", "since": T0 + 10, "until": T0}, headers=OBS
    )
    assert inverted.status_code == 422 and "after it ends" in inverted.json()["detail"]
    empty = client.get(url, params={"vehicle_id": 1, "stream": "imu", "since": T0 + 1e6}, headers=OBS)
    assert empty.status_code == 422 and "they span" in empty.json()["detail"]
    never = client.get(url, params={"vehicle_id": 2, "stream": "imu"}, headers=OBS)
    assert never.status_code == 422 and "no imu samples yet" in never.json()["detail"]


@pytest.mark.parametrize("suffix", ["csv", "parquet", "nc"])
def test_ticks_as_a_vehicle_counts_them_come_back_exact(
    client: TestClient, tmp_path: Path, suffix: str
) -> None:
    """A stream's tick counts its periods since 1970: the IMU's (4 Hz) are over 2^32 today, past any
    32-bit integer (the NetCDF export once failed on every real stream with a 500)."""
    address = 4 + ["csv", "parquet", "nc"].index(suffix)
    new = {"name": f"rov{address - 1}", "address": address}
    vehicle = client.post("/api/v1/vehicles", json=new, headers=OP).json()
    first = int(T0 / IMU_PERIOD)
    with writing(client.app.state.shore.db) as s:  # type: ignore[attr-defined]
        rows = [
            {**env(0, [0.1 * i] * 9, vehicle_id=vehicle["id"], packet=None), "stream": "imu"}
            | {"tick": first + i, "time": (first + i) * IMU_PERIOD}
            for i in range(3)
        ]
        s.execute(insert(Telemetry), rows)
        s.commit()
    path = download(
        client,
        tmp_path / f"imu.{suffix}",
        f"/api/v1/telemetry.{suffix}",
        vehicle_id=vehicle["id"],
        stream="imu",
    )
    ticks, _ = read_verification(path)
    assert first > 2**32 and [int(t) for t in ticks] == [first, first + 1, first + 2]


@pytest.mark.parametrize("suffix", ["csv", "parquet", "nc"])
def test_a_sample_sent_in_parts_is_one_row(client: TestClient, tmp_path: Path, suffix: str) -> None:
    """A stream's first sample leaves in parts (its first values coded finer): the rest comes in the next
    packet, stored as a part of the row before. The export joins them: one row per sample time, as
    certain and as trusted as its least, and a second sample of the same tick stays its own row."""
    body = {"name": f"parts-{suffix}", "address": 10 + ["csv", "parquet", "nc"].index(suffix)}
    answer = client.post("/api/v1/vehicles", json=body, headers=OP)
    assert answer.status_code == 201, answer.text
    vehicle = answer.json()
    with writing(client.app.state.shore.db) as s:  # type: ignore[attr-defined]
        ids = add_packets(s, vehicle["id"])
        first = env(1, [20.0, None, None], vehicle_id=vehicle["id"], ids=ids)
        rest = env(1, [None, 1.5, 8.0], vehicle_id=vehicle["id"], packet="pending", ids=ids) | {"part": True}
        again = env(1, [20.1, 1.6, 8.1], vehicle_id=vehicle["id"], ids=ids)
        after = env(2, [None, 1.7, 8.2], vehicle_id=vehicle["id"], ids=ids)  # not a part: a row with a blank
        s.execute(insert(Telemetry), [first, rest, again, after])
        s.commit()
    path = download(
        client,
        tmp_path / f"rov3.{suffix}",
        f"/api/v1/telemetry.{suffix}",
        vehicle_id=vehicle["id"],
        stream="env",
    )
    ticks, verification = read_verification(path)
    if suffix == "csv":
        with path.open(newline="") as f:
            depths = [r[HEADER[6]] for r in csv.DictReader(f)]
    elif suffix == "parquet":
        depths = pq.read_table(path).to_pydict()["depth"]
    else:
        with netcdf_file(path, mmap=False) as f:
            depths = list(f.variables["depth"][:])
    assert [int(t) for t in ticks] == [1, 1, 2]
    assert verification == ["pending", "verified", "verified"]
    assert [float(d) for d in depths] == [1.5, 1.6, 1.7]


ABOUT = {
    "deployment": "river-2026",
    "summary": "Temperature, depth and oxygen of a river survey by a BlueROV2.",
    "creator_name": "A. Diver",
    "creator_email": "diver@example.org",
    "creator_url": "https://example.org/diver",
    "institution": "Example Oceanographic",
    "publisher_name": "Example Data Center",
    "publisher_email": "data@example.org",
    "publisher_url": "https://example.org/data",
    "naming_authority": "org.example",
    "license": "CC-BY-4.0",
    "acknowledgment": "Example grant 42",
}


def test_netcdf_passes_the_ioos_compliance_checker(tmp_path: Path) -> None:
    """An export of a deployment that said who and what it is, with the fleet's origin and the vehicle's
    verified check-points, through the IOOS compliance checker (offline, its packaged standard-name
    table): CF-1.8 and ACDD-1.3 at full marks; each row's latitude and longitude is where the vehicle was
    between its check-points, and the file says the area and the time it covers."""
    settings = offline_settings(tmp_path, ping_interval=3600, origin=(41.5, -70.6), **ABOUT)
    with TestClient(create_app(settings)) as c:
        c.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=OP)
        with writing(c.app.state.shore.db) as s:  # type: ignore[attr-defined]
            frame = repository.add_frame(s, {"direction": "in", "src": 2, "dest": 1, "data": b""})
            for seq, (at, north, east, depth) in enumerate(
                ((T0 - 5, 0.0, 0.0, 0.0), (T0 + 95, 100.0, 50.0, 4.0))
            ):
                body = {"time": at, "north": north, "east": east, "depth": depth}
                row = {"frame_id": frame, "vehicle_id": 1, "type": "checkpoint", "seq": seq, "body": body}
                repository.add_packet(s, {**row, "at": at, "auth": PacketTrust.VERIFIED})
            s.execute(
                insert(Telemetry),
                [env(i, [20.0 + 0.01 * i, 1.5 + 0.01 * i, 8.0], packet=None) for i in range(100)],
            )
            s.commit()
        path = download(c, tmp_path / "env.nc", "/api/v1/telemetry.nc", vehicle_id=1, stream="env")
    report = tmp_path / "report.json"
    checker = Path(sys.executable).with_name("compliance-checker")
    done = subprocess.run(
        [str(checker), "--test", "cf:1.8", "--test", "acdd:1.3", "-f", "json", "-o", str(report), str(path)],
        capture_output=True,
        text=True,
    )
    scores = json.loads(report.read_text())
    assert done.returncode == 0, (done.stdout, done.stderr)
    for test in ("cf:1.8", "acdd:1.3"):
        failed = [
            (c["name"], c["value"], c["msgs"])
            for c in scores[test]["all_priorities"]
            if c["value"][0] < c["value"][1]
        ]
        assert failed == [], (test, failed)
    with netcdf_file(path, mmap=False) as f:
        assert f.creator_name == b"A. Diver" and f.license == b"CC-BY-4.0" and f.project == b"river-2026"
        assert f.time_coverage_start == b"2023-11-14T22:13:20.000Z" and f.time_coverage_duration == b"PT99S"
        lat, lon = f.variables["lat"][:], f.variables["lon"][:]
        assert lat[5] == pytest.approx(
            41.5 + math.degrees(10.0 / EARTH_RADIUS), abs=1e-9
        )  # 10 m north at T0 + 5
        assert f.geospatial_lat_min == np.nanmin(lat) and f.geospatial_lon_max == np.nanmax(lon)
        assert np.isnan(lat[-1])  # after the last check-point: not known
        assert (
            f.geospatial_vertical_min == 1.5
            and f.variables["temperature"].coordinates == b"time tick in_tick lat lon depth"
        )
