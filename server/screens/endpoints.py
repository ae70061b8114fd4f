"""What the operator's screens read beyond the raw data: the command form for a vehicle, what the shore
knows of a vehicle and how sure it is, the link's airtime by use, the browser's configuration."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from server.api.deps import Id, ScreensDep, require_read
from server.screens.schemas import CommandForm, Fleet, LinkShares, ScreenConfig, VehicleEstimate

router = APIRouter(prefix="/api/v1", tags=["data"])


@router.get("/vehicles/{vehicle_id}/form", response_model=CommandForm, dependencies=[Depends(require_read)])
def command_form(vehicle_id: Id, screens: ScreensDep) -> CommandForm:
    """Each command's fields with label, unit, range and hint (the packet's ranges narrowed by this
    vehicle's limits): what both the dashboard and the map's panel offer and check before sending."""
    return CommandForm.model_validate(screens.form(vehicle_id))


@router.get(
    "/vehicles/{vehicle_id}/estimate", response_model=VehicleEstimate, dependencies=[Depends(require_read)]
)
def estimate(vehicle_id: Id, screens: ScreensDep) -> VehicleEstimate:
    """The last reported check-point with its age, and the shore's predicted pose since (dead reckoning
    toward the current target) with an uncertainty radius that grows with silence."""
    return VehicleEstimate.model_validate(screens.estimate(vehicle_id))


@router.get("/fleet", response_model=Fleet, dependencies=[Depends(require_read)])
def fleet(screens: ScreensDep) -> Fleet:
    """Every vehicle as both screens list it: its colour, state, last report (vehicle clock, and on the
    shore's with the clock offset), predicted pose with its uncertainty, battery, link quality, whether it
    is overdue for its place in the schedule, and its airtime; the fleet's origin in latitude and
    longitude when known."""
    return Fleet.model_validate(screens.fleet())


@router.get("/link/shares", response_model=LinkShares, dependencies=[Depends(require_read)])
def link_shares(screens: ScreensDep) -> LinkShares:
    """The link's airtime by use (commands, polls, check-points, priority data) as seconds and shares,
    and the bits saved against sending every sample; counted from the database, polls since start."""
    return LinkShares.model_validate(screens.shares())


@router.get("/config", response_model=ScreenConfig)
def config(screens: ScreensDep) -> ScreenConfig:
    """What the browser needs (no secrets): the map's port, the streams' channels with units, what
    the mission states mean, the commands' fields (packet ranges; per vehicle with its limits at
    ``/vehicles/{id}/form``) and the simulated time scale (1 on a real deployment)."""
    return ScreenConfig.model_validate(screens.config())
