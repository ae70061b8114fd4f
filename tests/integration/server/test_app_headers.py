"""The dashboard's security headers (``server.app``): its Content-Security-Policy lets its frame load the
3D map, from the host the browser asked for on the map's port or from the map's public address
(``TACIT_MAP_URL``, behind a proxy), and nothing else; with no map, no frame at all."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from fastapi import Request
from fastapi.testclient import TestClient

from server.app import create_app, map_origin
from server.core.config import Settings
from tests.support.api import OP, offline_settings


def frame_src(response) -> str:  # type: ignore[no-untyped-def]
    found = re.search(r"frame-src ([^;]+);", response.headers["content-security-policy"])
    assert found, response.headers["content-security-policy"]
    return found.group(1)


def test_the_frame_may_load_the_map_from_the_host_the_browser_asked_for(tmp_path: Path) -> None:
    with TestClient(create_app(offline_settings(tmp_path, map_enabled=True, map_port=0))) as client:
        port = client.app.state.map.port
        assert port
        assert frame_src(client.get("/")) == f"http://testserver:{port}"
        asked = client.get("/", headers={"Host": "shore.local:8000"})
        assert frame_src(asked) == f"http://shore.local:{port}"
        for host in (b"evil.org; script-src *", b"a b", b"[::1]:8000"):
            request = Request(
                {
                    "type": "http",
                    "scheme": "http",
                    "path": "/",
                    "query_string": b"",
                    "headers": [(b"host", host)],
                }
            )
            found = map_origin(client.app.state.shore.settings, request, port)
            assert found == (f"http://[::1]:{port}" if host == b"[::1]:8000" else None), host
        config = client.get("/api/v1/config", headers=OP).json()
        assert (config["map_port"], config["map_url"]) == (port, None)


def test_behind_a_proxy_the_frame_loads_the_map_s_public_address(tmp_path: Path) -> None:
    settings = offline_settings(
        tmp_path, map_enabled=True, map_port=0, map_url="https://shore.example.org:8443/map/"
    )
    with TestClient(create_app(settings)) as client:
        assert frame_src(client.get("/")) == "https://shore.example.org:8443"
        config = client.get("/api/v1/config", headers=OP).json()
        assert config["map_url"] == "https://shore.example.org:8443/map/"


def test_without_a_map_nothing_is_framed(tmp_path: Path) -> None:
    with TestClient(create_app(offline_settings(tmp_path))) as client:
        assert frame_src(client.get("/")) == "'none'"
        assert client.get("/api/v1/config", headers=OP).json()["map_url"] is None


@pytest.mark.parametrize("url", ["javascript:alert(1)", "https://a.org; script-src *", "ftp://a.org"])
def test_a_map_url_that_is_not_one_is_refused(url: str) -> None:
    with pytest.raises(ValueError, match="map_url"):
        Settings(map_url=url)
