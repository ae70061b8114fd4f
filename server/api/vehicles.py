from __future__ import annotations

from fastapi import APIRouter, Depends
from sqlmodel import col, select

from server.api.deps import Id, LinkDep, ReadSession, WriteDep
from server.auth import require_read, require_write
from server.models import Vehicle
from server.schemas import KeyIn, Limits, VehicleCreated, VehicleIn, VehicleOut
from server.services import vehicles

router = APIRouter(prefix="/api/v1/vehicles", tags=["vehicles"])


def _out(vehicle: Vehicle) -> VehicleOut:
    return VehicleOut.model_validate(vehicle, from_attributes=True)


@router.post("", status_code=201, response_model=VehicleCreated, dependencies=[Depends(require_write)])
def create_vehicle(body: VehicleIn, write: WriteDep, link: LinkDep) -> VehicleCreated:
    with write() as s:
        vehicle = vehicles.create(s, body)
    link.vehicles_changed()
    return VehicleCreated(**_out(vehicle).model_dump(), key=vehicle.key_hex)


@router.get("", response_model=list[VehicleOut], dependencies=[Depends(require_read)])
def list_vehicles(s: ReadSession) -> list[VehicleOut]:
    return [_out(v) for v in s.exec(select(Vehicle).order_by(col(Vehicle.id)))]


@router.get("/{vehicle_id}", response_model=VehicleOut, dependencies=[Depends(require_read)])
def get_vehicle(vehicle_id: Id, s: ReadSession) -> VehicleOut:
    return _out(vehicles.get(s, vehicle_id))


@router.put("/{vehicle_id}/limits", response_model=VehicleOut, dependencies=[Depends(require_write)])
def set_limits(vehicle_id: Id, body: Limits, write: WriteDep) -> VehicleOut:
    with write() as s:
        return _out(vehicles.set_limits(s, vehicle_id, body))


@router.post("/{vehicle_id}/key", response_model=VehicleCreated, dependencies=[Depends(require_write)])
def rotate_key(vehicle_id: Id, body: KeyIn, write: WriteDep) -> VehicleCreated:
    """Rotate the vehicle's key (at the surface: put the new key in the agent's configuration too)."""
    with write() as s:
        vehicle = vehicles.rotate_key(s, vehicle_id, body.key)
    return VehicleCreated(**_out(vehicle).model_dump(), key=vehicle.key_hex)
