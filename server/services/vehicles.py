"""Vehicles: registration, keys (rotation), limits."""

from __future__ import annotations

from sqlmodel import Session, select

from server.errors import Conflict, NotFound, Refused
from server.models import Vehicle
from server.schemas import Limits, VehicleIn
from tacit import auth


def create(s: Session, body: VehicleIn) -> Vehicle:
    if s.exec(select(Vehicle).where(Vehicle.name == body.name)).first():
        raise Conflict(f"a vehicle named {body.name!r} exists", "name")
    if s.exec(select(Vehicle).where(Vehicle.address == body.address)).first():
        raise Conflict(f"modem address {body.address} is taken", "address")
    try:
        key = auth.parse_key(body.key) if body.key else auth.new_key()
    except ValueError as exc:
        raise Refused(str(exc), "key") from None
    vehicle = Vehicle(name=body.name, address=body.address, key_hex=key.hex(),
                      **body.model_dump(include=set(Limits.model_fields)))  # fmt: skip
    s.add(vehicle)
    s.commit()
    s.refresh(vehicle)
    return vehicle


def get(s: Session, vehicle_id: int) -> Vehicle:
    vehicle = s.get(Vehicle, vehicle_id)
    if vehicle is None:
        raise NotFound(f"no vehicle {vehicle_id}", "vehicle_id")
    return vehicle


def set_limits(s: Session, vehicle_id: int, limits: Limits) -> Vehicle:
    vehicle = get(s, vehicle_id)
    for name, value in limits.model_dump(exclude_unset=True).items():  # a partial update changes only those
        setattr(vehicle, name, value)
    s.add(vehicle)
    s.commit()
    s.refresh(vehicle)
    return vehicle


def rotate_key(s: Session, vehicle_id: int, key_hex: str | None = None) -> Vehicle:
    """A new key for the vehicle. Commands already queued are re-signed with it when sent; the agent
    needs the same key in its configuration (done at the surface: an acoustic link must never carry
    a key)."""
    vehicle = get(s, vehicle_id)
    try:
        key = auth.parse_key(key_hex) if key_hex else auth.new_key()
    except ValueError as exc:
        raise Refused(str(exc), "key") from None
    if key.hex() == vehicle.key_hex:
        return vehicle  # the key it already has: nothing to stage, no new version
    if vehicle.previous_key_hex:  # keys.py names the previous key by version - 1: one rotation at a time
        raise Conflict("a key rotation is waiting for the vehicle's confirmation (its next check-point "
                       "signed with the new key); rotate again after that", "key")  # fmt: skip
    vehicle.previous_key_hex = vehicle.key_hex  # staged: see server.link.keys
    vehicle.key_hex = key.hex()
    vehicle.key_version += 1
    s.add(vehicle)
    s.commit()
    s.refresh(vehicle)
    return vehicle
