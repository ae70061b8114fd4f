"""schemathesis against the server's own OpenAPI: any request the schema allows (and many it does not)
gets an answer below 500, never a crash."""

from __future__ import annotations

import os
import tempfile

import schemathesis
from hypothesis import HealthCheck, settings

from server.app import create_app
from server.core.config import Settings
from server.core.db import migrate

_URL = f"sqlite:///{tempfile.mkdtemp(prefix='tacit-schemathesis-')}/tacit.db"
migrate(_URL)
APP = create_app(Settings(database_url=_URL, map_enabled=False, write_tokens=["fuzz-operator"]))
schema = schemathesis.openapi.from_asgi("/openapi.json", APP).exclude(path="/api/v1/events")


@schema.parametrize()
@settings(
    max_examples=int(os.environ.get("TACIT_API_EXAMPLES", "12")),
    deadline=None,
    suppress_health_check=list(HealthCheck),
)
def test_no_request_crashes_the_server(case) -> None:
    case.headers = {**(case.headers or {}), "Authorization": "Bearer fuzz-operator"}
    response = case.call()
    assert response.status_code < 500, (
        case.method,
        case.formatted_path,
        response.status_code,
        response.text[:300],
    )
