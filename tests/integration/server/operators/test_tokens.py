"""Operators are people: tokens created through the API carry a name into every command, expire, are
revoked at once, and are never stored in clear; the settings' tokens still work, named."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlmodel import Session, select

from server.app import create_app
from server.core.config import Settings
from server.core.db import now, writing
from server.core.errors import TooMany, Unauthorized
from server.core.security import Actor, Throttle
from server.operators import repository as repo
from server.operators.models import Operator
from tests.support.sqlite import migrated

ROOT = {"Authorization": "Bearer root-token"}
WATCHER = {"Authorization": "Bearer watcher-token"}


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings(
        database_url=migrated(tmp_path / "tacit.db"),
        map_enabled=False,
        write_tokens=["spare-token", "root-token"],
        read_tokens=["watcher-token"],
    )
    with TestClient(create_app(settings)) as client:
        assert (
            client.post("/api/v1/vehicles", json={"name": "rov1", "address": 2}, headers=ROOT).status_code
            == 201
        )
        yield client


def create(client: TestClient, name: str, role: str = "write", **kw: object) -> dict:
    response = client.post("/api/v1/operators", json={"name": name, "role": role, **kw}, headers=ROOT)
    assert response.status_code == 201, response.text
    return response.json()


def test_settings_tokens_still_work_and_are_named(client: TestClient) -> None:
    assert client.get("/api/v1/whoami", headers=ROOT).json() == {"role": "write", "name": "config-operator-2"}
    assert client.get("/api/v1/whoami", headers=WATCHER).json() == {
        "role": "read",
        "name": "config-observer-1",
    }
    assert client.get("/api/v1/whoami", headers=bearer("guess")).status_code == 401


def test_an_operators_command_records_its_name(client: TestClient) -> None:
    alice = create(client, "alice")
    assert alice["created_by"] == "config-operator-2" and alice["expires_at"] > now()
    headers = bearer(alice["token"])
    assert client.get("/api/v1/whoami", headers=headers).json() == {"role": "write", "name": "alice"}
    sent = client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=headers)
    assert sent.status_code == 202 and sent.json()["issued_by"] == "alice"
    listed = client.get("/api/v1/vehicles/1/commands", headers=WATCHER).json()
    assert [c["issued_by"] for c in listed] == ["alice"]
    mission = client.post("/api/v1/vehicles/1/missions", json={"name": "m", "number": 3}, headers=ROOT)
    started = client.post(f"/api/v1/missions/{mission.json()['id']}/start", headers=headers)
    assert started.json()["issued_by"] == "alice"


def test_an_observer_reads_but_cannot_create_operators(client: TestClient) -> None:
    bob = create(client, "bob", "read", expires_in_s=None)
    assert bob["expires_at"] is None
    headers = bearer(bob["token"])
    assert client.get("/api/v1/whoami", headers=headers).json() == {"role": "read", "name": "bob"}
    refused = client.post("/api/v1/operators", json={"name": "eve", "role": "write"}, headers=headers)
    assert refused.status_code == 403
    assert (
        client.post("/api/v1/operators", json={"name": "eve", "role": "write"}, headers=WATCHER).status_code
        == 403
    )
    assert (
        client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=headers).status_code
        == 403
    )


def test_names_are_unique_and_the_settings_names_reserved(client: TestClient) -> None:
    create(client, "alice")
    again = client.post("/api/v1/operators", json={"name": "alice", "role": "read"}, headers=ROOT)
    assert again.status_code == 409 and again.json()["field"] == "name"
    reserved = client.post(
        "/api/v1/operators", json={"name": "config-operator-9", "role": "read"}, headers=ROOT
    )
    assert reserved.status_code == 422 and reserved.json()["field"] == "name"


def test_revoking_refuses_the_token_at_once(client: TestClient) -> None:
    carol = create(client, "carol")
    headers = bearer(carol["token"])
    assert client.get("/api/v1/whoami", headers=headers).status_code == 200
    revoked = client.delete(f"/api/v1/operators/{carol['id']}", headers=ROOT)
    assert revoked.status_code == 200 and revoked.json()["revoked_at"] is not None
    refused = client.get("/api/v1/whoami", headers=headers)
    assert refused.status_code == 401 and "revoked at" in refused.json()["detail"]
    assert refused.headers["www-authenticate"] == "Bearer"
    assert client.delete("/api/v1/operators/99", headers=ROOT).status_code == 404
    listed = client.get("/api/v1/operators", headers=ROOT).json()
    assert [(o["name"], o["created_by"], o["revoked_at"] is not None) for o in listed] == [
        ("carol", "config-operator-2", True)
    ]
    assert all("token" not in o for o in listed)


def test_an_expired_token_is_refused_saying_when(client: TestClient) -> None:
    dave = create(client, "dave", expires_in_s=3600)
    headers = bearer(dave["token"])
    assert client.get("/api/v1/whoami", headers=headers).status_code == 200
    with writing(client.app.state.shore.db) as s:  # an hour later
        operator = repo.get(s, dave["id"])
        assert operator is not None
        operator.expires_at = now() - 1
        repo.save(s, operator)
    refused = client.get("/api/v1/whoami", headers=headers)
    assert refused.status_code == 401 and "expired at" in refused.json()["detail"]


def test_the_token_is_never_stored_in_clear(client: TestClient, tmp_path: Path) -> None:
    erin = create(client, "erin")
    with Session(client.app.state.shore.db) as s:
        stored = s.exec(select(Operator)).one()
    assert erin["token"] not in stored.token_hash and len(stored.token_hash) == 64
    assert erin["token"].encode() not in (tmp_path / "tacit.db").read_bytes()


def test_expired_or_revoked_tokens_count_as_wrong_ones_for_the_throttle() -> None:
    def revoked(token: str) -> Actor | None:
        raise Unauthorized("this token was revoked at 2026-11-24T08:00:00+00:00")

    throttle = Throttle(Settings(sign_in_failures=2), revoked)
    for _ in range(2):
        with pytest.raises(Unauthorized):
            throttle.actor("old-token", "a")
    with pytest.raises(TooMany):
        throttle.actor("old-token", "a")


def test_an_operator_cannot_create_a_token_that_outlives_its_own(client: TestClient) -> None:
    short = create(client, "frank", expires_in_s=60)
    headers = bearer(short["token"])
    for longer in (3600, None):
        refused = client.post(
            "/api/v1/operators",
            json={"name": "mallory", "role": "write", "expires_in_s": longer},
            headers=headers,
        )
        assert refused.status_code == 422 and refused.json()["field"] == "expires_in_s", refused.text
        assert "may not outlive it" in refused.json()["detail"]
    within = client.post(
        "/api/v1/operators", json={"name": "grace", "role": "read", "expires_in_s": 30}, headers=headers
    )
    assert within.status_code == 201 and within.json()["expires_at"] <= short["expires_at"]
    assert [o["name"] for o in client.get("/api/v1/operators", headers=ROOT).json()] == ["frank", "grace"]


def events_until_closed(client: TestClient, headers: dict[str, str], then: Callable[[], None]) -> list[str]:
    """The lines of a live event stream opened with ``headers``, ``then`` run once it is connected, read
    until the server closes it."""
    lines: list[str] = []
    with client.stream("GET", "/api/v1/events", headers=headers) as stream:
        for line in stream.iter_lines():
            lines.append(line)
            if line == ": connected":
                then()
    return lines


def test_a_revoked_tokens_event_stream_ends_at_its_next_event(client: TestClient) -> None:
    heidi = create(client, "heidi", "read")

    def revoke_then_command() -> None:
        assert client.delete(f"/api/v1/operators/{heidi['id']}", headers=ROOT).status_code == 200
        assert (
            client.post("/api/v1/vehicles/1/commands", json={"command": "hold"}, headers=ROOT).status_code
            == 202
        )

    lines = events_until_closed(client, bearer(heidi["token"]), revoke_then_command)
    assert lines[-3] == "event: end" and "this token was revoked at" in lines[-2], lines
    assert not any(line.startswith("event: command") for line in lines)  # the event after revocation withheld
    assert client.get("/api/v1/events", headers=bearer(heidi["token"])).status_code == 401


def test_an_expiring_tokens_event_stream_ends_when_it_expires(client: TestClient) -> None:
    ivan = create(client, "ivan", "read", expires_in_s=1.0)
    lines = events_until_closed(client, bearer(ivan["token"]), lambda: None)  # no event at all
    assert lines[-3] == "event: end" and "this token expired at" in lines[-2], lines
    assert time.time() >= ivan["expires_at"]
