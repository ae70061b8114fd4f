"""Bad input to the REST API is a clear 4xx that changes nothing, never a 500 or a silent reset.

schemathesis never sends non-finite numbers (JSON has none), but Python's JSON parser reads ``NaN``,
``Infinity`` and ``1e999`` into floats: these property tests put them, and oversized strings, in every
numeric and string field of every request body.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from server.app import create_app
from server.core.config import Settings

OP = {"Authorization": "Bearer operator-token", "Content-Type": "application/json"}
OBS = {"Authorization": "Bearer observer-token"}
NON_FINITE = ["NaN", "Infinity", "-Infinity", "1e999", "-1e999"]

COMMAND = {"command": "move", "distance": 1.0, "angle": 0.0, "depth": 0.0, "speed": 0.0, "param_value": 0.0}
MISSION = {
    "name": "m",
    "number": 1,
    "duration_s": 60.0,
    "waypoints": [{"north": 1.0, "east": 1.0, "depth": 1.0}],
}
LIMITS = {"max_depth": 20.0, "max_distance": 50.0, "max_speed": 1.0, "geofence_radius": 100.0}
# (method, path, a valid body, the float fields as JSON paths)
BODIES = [
    ("post", "/api/v1/vehicles/1/commands", COMMAND, [("distance",), ("angle",), ("depth",), ("speed",),
                                                       ("param_value",)]),
    ("post", "/api/v1/vehicles/1/missions", MISSION, [("duration_s",), ("waypoints", 0, "north"),
                                                      ("waypoints", 0, "east"), ("waypoints", 0, "depth")]),
    ("put", "/api/v1/vehicles/1/limits", LIMITS, [(k,) for k in LIMITS]),
    ("post", "/api/v1/vehicles", {"name": "rov9", "address": 9, **LIMITS}, [(k,) for k in LIMITS]),
]  # fmt: skip


def _raw(body: dict, path: tuple, token: str) -> bytes:
    """The JSON text of ``body`` with the number at ``path`` replaced by ``token`` (NaN, 1e999...)."""
    marker = "__MARKER__"
    body = json.loads(json.dumps(body))
    target = body
    for step in path[:-1]:
        target = target[step]
    target[path[-1]] = marker
    return json.dumps(body).replace(f'"{marker}"', token).encode()


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory):
    tmp = tmp_path_factory.mktemp("bad-input")
    app = create_app(
        Settings(
            database_url=f"sqlite:///{tmp}/tacit.db",
            map_enabled=False,
            write_tokens=["operator-token"],
            read_tokens=["observer-token"],
        )
    )
    with TestClient(app) as c:
        assert (
            c.post("/api/v1/vehicles", json={"name": "rov1", "address": 2, **LIMITS}, headers=OP).status_code
            == 201
        )
        yield c


def _state(client: TestClient) -> tuple:
    return (
        client.get("/api/v1/vehicles", headers=OBS).json(),
        client.get("/api/v1/vehicles/1/commands", headers=OBS).json(),
        client.get("/api/v1/vehicles/1/missions", headers=OBS).json(),
    )


@pytest.mark.parametrize("method, url, body, paths", BODIES, ids=[f"{m} {u}" for m, u, _, _ in BODIES])
@pytest.mark.parametrize("token", NON_FINITE)
def test_non_finite_numbers_anywhere_are_422_naming_the_field(
    client: TestClient, method: str, url: str, body: dict, paths: list, token: str
) -> None:
    before = _state(client)
    for path in paths:
        response = client.request(method, url, content=_raw(body, path, token), headers=OP)
        assert response.status_code == 422, (path, token, response.status_code, response.text[:200])
        problem = response.json()  # the body is valid JSON (the NaN echoed as text, not a bare NaN)
        assert problem["field"] == ".".join(str(p) for p in path), problem
    assert _state(client) == before


@given(
    st.sampled_from(BODIES),
    st.data(),
    st.one_of(
        st.sampled_from(NON_FINITE),
        st.floats(allow_nan=True, allow_infinity=True).map(lambda x: repr(x) if math.isfinite(x) else "NaN"),
        st.integers(-(10**30), 10**30).map(str),
        st.text(max_size=20).map(json.dumps),
        st.just('"' + "x" * 100_000 + '"'),
        st.sampled_from(["null", "true", "[]", "{}"]),
    ),
)
@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
def test_any_value_in_any_field_is_below_500_and_json(
    client: TestClient, case: tuple, data: st.DataObject, token: str
) -> None:
    method, url, body, paths = case
    fields = [*paths, *[(k,) for k in body if not isinstance(body[k], (list, dict))]]
    path = data.draw(st.sampled_from(fields))
    response = client.request(method, url, content=_raw(body, path, token), headers=OP)
    assert response.status_code < 500, (url, path, token[:40], response.text[:200])
    response.json()


def test_oversized_key_and_name_are_422(client: TestClient) -> None:
    big = "ab" * 50_000  # a 100,000-byte key
    for body in ({"name": "rov3", "address": 3, "key": big}, {"name": "r" * 65, "address": 3}):
        response = client.post("/api/v1/vehicles", json=body, headers=OP)
        assert response.status_code == 422, response.text[:200]
    rotated = client.post("/api/v1/vehicles/1/key", json={"key": big}, headers=OP)
    assert rotated.status_code == 422 and rotated.json()["field"] == "key"
    just_over = client.post("/api/v1/vehicles/1/key", json={"key": "00" * 65}, headers=OP)
    assert just_over.status_code == 422 and just_over.json()["field"] == "key"


def test_partial_limits_update_changes_only_what_is_sent(client: TestClient) -> None:
    client.put("/api/v1/vehicles/1/limits", json=LIMITS, headers=OP)
    assert client.put("/api/v1/vehicles/1/limits", json={}, headers=OP).status_code == 200
    vehicle = client.get("/api/v1/vehicles/1", headers=OBS).json()
    assert {k: vehicle[k] for k in LIMITS} == LIMITS  # {} reset nothing (max depth stayed 20, not 100)
    client.put("/api/v1/vehicles/1/limits", json={"max_depth": 30}, headers=OP)
    vehicle = client.get("/api/v1/vehicles/1", headers=OBS).json()
    assert {k: vehicle[k] for k in LIMITS} == {**LIMITS, "max_depth": 30.0}


def test_infinite_mission_duration_is_refused(client: TestClient) -> None:
    response = client.post(
        "/api/v1/vehicles/1/missions", content=_raw(MISSION, ("duration_s",), "Infinity"), headers=OP
    )
    assert response.status_code == 422 and response.json()["field"] == "duration_s"


def test_read_routes_never_return_a_key(client: TestClient) -> None:
    for url in ("/api/v1/vehicles", "/api/v1/vehicles/1"):
        text = client.get(url, headers=OBS).text
        assert "key_hex" not in text and '"key"' not in text


def test_database_file_is_owner_only(tmp_path: Path) -> None:
    from server.core.db import make_engine

    path = tmp_path / "db" / "tacit.db"
    make_engine(f"sqlite:///{path}").dispose()
    assert path.stat().st_mode & 0o777 == 0o600  # it holds every vehicle's key
