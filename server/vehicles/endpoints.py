"""Vehicle routes: register, list, read, limits, share of the channel, key rotation."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from server.api.deps import Id, LinkDep, SafetyDep, VehiclesDep, require_read, require_write
from server.core import errors
from server.core.errors import Conflict
from server.vehicles import keys
from server.vehicles.models import Vehicle
from server.vehicles.schemas import HomeIn, KeyIn, LimitsIn, ShareIn, VehicleCreated, VehicleIn, VehicleOut

router = APIRouter(prefix="/api/v1/vehicles", tags=["vehicles"])


def _out(vehicle: Vehicle) -> VehicleOut:
    fields = VehicleOut.model_validate(vehicle, from_attributes=True).model_dump(exclude={"key_rotation"})
    return VehicleOut(**fields, key_rotation=keys.rotation(vehicle))


def _created(vehicle: Vehicle) -> VehicleCreated:
    return VehicleCreated(**_out(vehicle).model_dump(), key=vehicle.key_hex)


@router.post(
    "",
    status_code=201,
    response_model=VehicleCreated,
    dependencies=[Depends(require_write)],
    responses=errors.responses(Conflict),
)
def create_vehicle(body: VehicleIn, vehicles: VehiclesDep, link: LinkDep) -> VehicleCreated:
    vehicle = vehicles.create(body)
    link.vehicles_changed()
    return _created(vehicle)


@router.get("", response_model=list[VehicleOut], dependencies=[Depends(require_read)])
def list_vehicles(vehicles: VehiclesDep) -> list[VehicleOut]:
    return [_out(v) for v in vehicles.every()]


@router.get("/{vehicle_id}", response_model=VehicleOut, dependencies=[Depends(require_read)])
def get_vehicle(vehicle_id: Id, vehicles: VehiclesDep) -> VehicleOut:
    return _out(vehicles.get(vehicle_id))


@router.put("/{vehicle_id}/limits", response_model=VehicleOut, dependencies=[Depends(require_write)])
def set_limits(vehicle_id: Id, body: LimitsIn, vehicles: VehiclesDep) -> VehicleOut:
    return _out(vehicles.set_limits(vehicle_id, body))


@router.put("/{vehicle_id}/share", response_model=VehicleOut, dependencies=[Depends(require_write)])
def set_share(vehicle_id: Id, body: ShareIn, vehicles: VehiclesDep, link: LinkDep) -> VehicleOut:
    """Change the vehicle's share of the acoustic channel at run time: with share 2 it gets twice the slots
    of a vehicle with share 1 (``GET /api/v1/link/schedule`` shows the schedule). Kept across restarts."""
    vehicle = vehicles.set_share(vehicle_id, body.share)
    link.share_changed(vehicle_id, body.share)
    return _out(vehicle)


@router.put("/{vehicle_id}/home", response_model=VehicleOut, dependencies=[Depends(require_write)])
def set_home(vehicle_id: Id, body: HomeIn, vehicles: VehiclesDep, safety: SafetyDep) -> VehicleOut:
    """Where the vehicle starts, m north and east of the fleet's one origin (its agent's ``[nav] home``):
    its mission's waypoints and its return home are relative to it on the screens. Refused (422) if a
    return there (queued, under way, at its mission's end or its lost-link action) would pass closer
    than the separation to another vehicle's plan."""
    safety.check_home(vehicle_id, body.home)
    return _out(vehicles.set_home(vehicle_id, body.home))


@router.post(
    "/{vehicle_id}/key",
    response_model=VehicleCreated,
    dependencies=[Depends(require_write)],
    responses=errors.responses(Conflict),
)
def rotate_key(vehicle_id: Id, body: KeyIn, vehicles: VehiclesDep) -> VehicleCreated:
    """Rotate the vehicle's key (at the surface: put the new key in the agent's configuration too)."""
    return _created(vehicles.rotate_key(vehicle_id, body.key))


@router.delete(
    "/{vehicle_id}/key/pending",
    response_model=VehicleOut,
    dependencies=[Depends(require_write)],
    responses=errors.responses(Conflict),
)
def cancel_key_rotation(vehicle_id: Id, vehicles: VehiclesDep) -> VehicleOut:
    """Cancel a key rotation the vehicle has not confirmed: the previous key (and its version) is current
    again. 409 if none waits. Only while the vehicle has not switched: one that said it holds the new key
    is sent commands and SYNCs signed with it, and confirms it with its next check-point."""
    return _out(vehicles.cancel_rotation(vehicle_id))
