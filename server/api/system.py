"""The server's own routes: health and the caller's role and name."""

from __future__ import annotations

from fastapi import APIRouter

from server.api.deps import Reader, ScreensDep, SettingsDep
from server.backhaul.access import BrokerMode
from server.screens.schemas import Health, RoleOut

router = APIRouter(prefix="/api/v1", tags=["data"])


@router.get("/health", response_model=Health)
def health(screens: ScreensDep, settings: SettingsDep) -> Health:
    broker = BrokerMode.of(settings.nats_credentials, settings.nats_insecure)
    return Health(status="ok", modem=screens.link_status()["modem"], broker=broker)


@router.get("/whoami", response_model=RoleOut)
def whoami(found: Reader) -> RoleOut:
    """The caller's role (``write``: operator, ``read``: observer) and name."""
    return RoleOut(role=found.role.value, name=found.name)
