"""Sign-in throttling (``server.core.security.Throttle``): wrong tokens from one address are refused for a
while, whatever comes next from it, while other addresses still sign in; old failures are forgotten."""

from __future__ import annotations

from functools import partial
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.core.config import Settings
from server.core.errors import TooMany
from server.core.security import Actor, Role, Throttle, configured
from tests.support.api import offline_settings


def test_wrong_tokens_from_one_address_are_throttled_and_others_still_sign_in(tmp_path: Path) -> None:
    settings = offline_settings(tmp_path)
    app = create_app(settings)
    other = TestClient(app, client=("10.0.0.2", 4000))  # the app's lifespan runs in the one below
    with TestClient(app, client=("10.0.0.9", 4000)) as guesser:
        for n in range(settings.sign_in_failures):
            assert (
                guesser.get("/api/v1/vehicles", headers={"Authorization": f"Bearer guess-{n}"}).status_code
                == 401
            )
        for token in ("guess-again", "operator-token"):  # refused whatever it is, the right one too
            throttled = guesser.get("/api/v1/vehicles", headers={"Authorization": f"Bearer {token}"})
            assert throttled.status_code == 429
            assert 1 <= int(throttled.headers["Retry-After"]) <= settings.sign_in_window
        assert (
            other.get("/api/v1/vehicles", headers={"Authorization": "Bearer observer-token"}).status_code
            == 200
        )
        assert (
            other.post(
                "/api/v1/vehicles",
                json={"name": "rov1", "address": 2},
                headers={"Authorization": "Bearer operator-token"},
            ).status_code
            == 201
        )


def test_the_throttle_forgets_failures_older_than_its_window() -> None:
    settings = Settings(write_tokens=["operator-token"], sign_in_failures=2, sign_in_window=60.0)
    now = [0.0]
    throttle = Throttle(settings, partial(configured, settings), clock=lambda: now[0])
    assert throttle.actor("wrong", "a") is None and throttle.actor("wrong", "a") is None
    with pytest.raises(TooMany):
        throttle.actor("operator-token", "a")
    operator = Actor("config-operator-1", Role.WRITE)
    assert throttle.actor("operator-token", "b") == operator
    now[0] = 60.5
    assert throttle.actor("operator-token", "a") == operator
