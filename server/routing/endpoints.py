"""Routing routes: every vehicle's gateway and why, the gateways, an operator's pin."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from server.api.deps import Id, RoutingDep, ScreensDep, require_read, require_write
from server.routing.schemas import GatewayOut, PinIn, RouteOut

router = APIRouter(prefix="/api/v1", tags=["routing"])


@router.get("/routing", response_model=list[RouteOut], dependencies=[Depends(require_read)])
def list_routes(routing: RoutingDep) -> list[RouteOut]:
    """Every vehicle's gateway, whether an operator pinned it, since when and why, and how each gateway
    heard it in the routing window (the scores the assignment compares)."""
    alive = routing.alive()
    return [RouteOut.of(route, alive) for route in routing.routes()]


@router.get("/gateways", response_model=list[GatewayOut], dependencies=[Depends(require_read)])
def list_gateways(screens: ScreensDep) -> list[GatewayOut]:
    """The gateways the center has heard from (none on a single shore, ``tacit serve``), as the dashboard
    and the map show them: up or silent and since when, place, modem, outbox, last outage, frames
    relayed and the vehicles assigned."""
    return [GatewayOut.model_validate(g) for g in screens.gateways()]


@router.put("/vehicles/{vehicle_id}/gateway", response_model=RouteOut, dependencies=[Depends(require_write)])
def pin_vehicle(vehicle_id: Id, body: PinIn, routing: RoutingDep) -> RouteOut:
    """Pin the vehicle to a gateway: its commands go through it first whatever the scores (404 for an
    unknown vehicle or gateway)."""
    return RouteOut.of(routing.pin(vehicle_id, body.gateway), routing.alive())


@router.delete(
    "/vehicles/{vehicle_id}/gateway", response_model=RouteOut, dependencies=[Depends(require_write)]
)
def unpin_vehicle(vehicle_id: Id, routing: RoutingDep) -> RouteOut:
    """Unpin the vehicle: the assignment chooses its gateway again."""
    return RouteOut.of(routing.pin(vehicle_id, None), routing.alive())
