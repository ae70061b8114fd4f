"""Security defaults: closed CORS, a localhost bind, tokens from a private file, never logged."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.core.config import Settings, SettingsError
from tests.support.sqlite import migrated

SECRET = "very-secret-operator-token"


def app(tmp_path: Path, **kw: object) -> TestClient:
    settings = Settings(
        database_url=migrated(tmp_path / "t.db"), map_enabled=False, write_tokens=[SECRET], **kw
    )  # type: ignore[arg-type]
    return TestClient(create_app(settings))


def test_cors_is_closed_by_default_and_opens_only_for_configured_origins(tmp_path: Path) -> None:
    with app(tmp_path) as client:
        response = client.get("/api/v1/health", headers={"Origin": "http://evil.example"})
        assert "access-control-allow-origin" not in response.headers
    with app(tmp_path, cors_origins=["http://boat.local"]) as client:
        allowed = client.get("/api/v1/health", headers={"Origin": "http://boat.local"})
        refused = client.get("/api/v1/health", headers={"Origin": "http://evil.example"})
        assert allowed.headers["access-control-allow-origin"] == "http://boat.local"
        assert "access-control-allow-origin" not in refused.headers


def test_binds_to_localhost_unless_told() -> None:
    assert Settings().host == "127.0.0.1"
    assert Settings.load(env={"TACIT_HOST": "0.0.0.0"}).host == "0.0.0.0"


def test_tokens_come_from_a_private_file_only(tmp_path: Path) -> None:
    tokens = tmp_path / "tokens.toml"
    tokens.write_text(f'write_tokens = ["{SECRET}"]\nread_tokens = ["observer"]\n')
    tokens.chmod(0o644)
    with pytest.raises(SettingsError, match="chmod 600"):
        Settings.load(env={"TACIT_TOKEN_FILE": str(tokens)})
    tokens.chmod(0o600)
    loaded = Settings.load(env={"TACIT_TOKEN_FILE": str(tokens)})
    assert loaded.write_tokens == [SECRET] and loaded.read_tokens == ["observer"]


def test_tokens_are_never_logged(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG)
    with app(tmp_path) as client:
        client.post(
            "/api/v1/vehicles",
            json={"name": "rov1", "address": 2},
            headers={"Authorization": f"Bearer {SECRET}"},
        )
        client.post(
            "/api/v1/vehicles",
            json={"name": "rov2", "address": 3},
            headers={"Authorization": "Bearer wrong-guess"},
        )
        assert client.get(f"/api/v1/events?token={SECRET}").status_code == 401  # no tokens in URLs
    server_side = "\n".join(
        r.getMessage() for r in caplog.records if not r.name.startswith(("httpx", "httpcore"))
    )
    assert server_side and SECRET not in server_side and "wrong-guess" not in server_side
