from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, Request
from sqlmodel import Session, select

from server.api.deps import Id, db, db_write
from server.auth import require_read, require_write
from server.models import Vehicle
from server.schemas import KeyIn, Limits, VehicleCreated, VehicleIn, VehicleOut
from server.services import vehicles

router = APIRouter(prefix="/api/v1/vehicles", tags=["vehicles"])


def _out(vehicle: Vehicle) -> VehicleOut:
    return VehicleOut.model_validate(vehicle, from_attributes=True)


@router.post("", status_code=201, response_model=VehicleCreated, dependencies=[Depends(require_write)])
def create_vehicle(body: VehicleIn, request: Request, s: Session = Depends(db_write)) -> VehicleCreated:
    try:
        vehicle = vehicles.create(s, body)
    except vehicles.Conflict as exc:
        raise HTTPException(
            409 if exc.field != "key" else 422, {"detail": str(exc), "field": exc.field}
        ) from None
    request.app.state.link.vehicles_changed()
    return VehicleCreated(**_out(vehicle).model_dump(), key=vehicle.key_hex)


@router.get("", response_model=list[VehicleOut], dependencies=[Depends(require_read)])
def list_vehicles(s: Session = Depends(db)) -> list[VehicleOut]:
    return [_out(v) for v in s.exec(select(Vehicle).order_by(Vehicle.id))]


@router.get("/{vehicle_id}", response_model=VehicleOut, dependencies=[Depends(require_read)])
def get_vehicle(vehicle_id: Id, s: Session = Depends(db)) -> VehicleOut:
    return _out(_get(s, vehicle_id))


@router.put("/{vehicle_id}/limits", response_model=VehicleOut, dependencies=[Depends(require_write)])
def set_limits(vehicle_id: Id, body: Limits, s: Session = Depends(db_write)) -> VehicleOut:
    _get(s, vehicle_id)
    return _out(vehicles.set_limits(s, vehicle_id, body))


@router.post("/{vehicle_id}/key", response_model=VehicleCreated, dependencies=[Depends(require_write)])
def rotate_key(vehicle_id: Id, body: KeyIn, s: Session = Depends(db_write)) -> VehicleCreated:
    """Rotate the vehicle's key (at the surface: put the new key in the agent's configuration too)."""
    _get(s, vehicle_id)
    try:
        vehicle = vehicles.rotate_key(s, vehicle_id, body.key)
    except vehicles.Conflict as exc:
        raise HTTPException(422, {"detail": str(exc), "field": exc.field}) from None
    return VehicleCreated(**_out(vehicle).model_dump(), key=vehicle.key_hex)


def _get(s: Session, vehicle_id: Id) -> Vehicle:
    try:
        return vehicles.get(s, vehicle_id)
    except vehicles.NotFound as exc:
        raise HTTPException(404, {"detail": str(exc), "field": "vehicle_id"}) from None
