"""/docs works on an offline shore station: Swagger UI's files come from this server, not a CDN."""

from __future__ import annotations

import re
from pathlib import Path

from fastapi.testclient import TestClient

from server.app import create_app
from server.core.config import Settings
from tests.support.sqlite import migrated


def test_docs_load_only_local_assets(tmp_path: Path) -> None:
    settings = Settings(database_url=migrated(tmp_path / "tacit.db"), modem_url="", map_enabled=False)
    with TestClient(create_app(settings)) as client:
        page = client.get("/docs")
        assert page.status_code == 200 and "swagger-ui" in page.text
        assets = re.findall(r"""(?:src|href)=["']([^"']+)["']""", page.text)
        assert {"/docs-assets/swagger-ui-bundle.js", "/docs-assets/swagger-ui.css"} <= set(assets)
        assert not re.search(r"https?://", page.text)  # nothing from the internet
        for asset in assets:
            response = client.get(asset)
            assert response.status_code == 200 and len(response.content) > 500, asset
        assert "SwaggerUIBundle" in client.get("/docs-assets/swagger-ui-bundle.js").text
        assert client.get("/openapi.json").json()["info"]["title"] == "Tacit"
        assert client.get("/redoc").status_code == 404  # ReDoc would need a CDN: not offered
