"""Vehicles: registration, keys (staged rotation, ``server.vehicles.keys``), limits."""

from __future__ import annotations

from sqlalchemy import Engine

from server.core.db import Tx, now, reading, writing
from server.core.errors import Conflict, NotFound, Refused
from server.vehicles import keys
from server.vehicles import repository as repo
from server.vehicles.models import Vehicle
from server.vehicles.schemas import LimitsIn, VehicleIn
from tacit import auth


def get(s: Tx, vehicle_id: int) -> Vehicle:
    """The vehicle, or ``NotFound`` (HTTP 404)."""
    vehicle = repo.get(s, vehicle_id)
    if vehicle is None:
        raise NotFound(f"no vehicle {vehicle_id}", "vehicle_id")
    return vehicle


def _key(key_hex: str | None) -> bytes:
    try:
        return auth.parse_key(key_hex) if key_hex else auth.new_key()
    except ValueError as exc:
        raise Refused(str(exc), "key") from None


def _unshared(s: Tx, key: bytes, vehicle_id: int | None = None) -> bytes:
    """``key``, unless another vehicle holds it: a shared key would let one vehicle's shore traffic
    command the other (``Conflict``, HTTP 409)."""
    holder = repo.using_key(s, key.hex(), vehicle_id)
    if holder is not None:
        raise Conflict(f"key already used by vehicle {holder.name}", "key")
    return key


class Vehicles:
    def __init__(self, db: Engine) -> None:
        self.db = db

    def get(self, vehicle_id: int) -> Vehicle:
        with reading(self.db) as s:
            return get(s, vehicle_id)

    def named(self, name: str) -> Vehicle | None:
        with reading(self.db) as s:
            return repo.by_name(s, name)

    def every(self) -> list[Vehicle]:
        with reading(self.db) as s:
            return repo.every(s)

    def create(self, body: VehicleIn) -> Vehicle:
        with writing(self.db) as s:
            if repo.by_name(s, body.name):
                raise Conflict(f"a vehicle named {body.name!r} exists", "name")
            if repo.by_address(s, body.address):
                raise Conflict(f"modem address {body.address} is taken", "address")
            vehicle = Vehicle(
                name=body.name,
                address=body.address,
                key_hex=_unshared(s, _key(body.key)).hex(),
                home_north=body.home[0],
                home_east=body.home[1],
                lost_action=body.lost_action,
                protocol=body.protocol,
                report_interval=body.report_interval,
                **body.model_dump(include=set(LimitsIn.model_fields)),
            )
            return repo.save(s, vehicle)

    def set_limits(self, vehicle_id: int, limits: LimitsIn) -> Vehicle:
        with writing(self.db) as s:
            vehicle = get(s, vehicle_id)
            for name, value in limits.model_dump(exclude_unset=True).items():  # a partial update: only those
                setattr(vehicle, name, value)
            return repo.save(s, vehicle)

    def set_share(self, vehicle_id: int, share: float) -> Vehicle:
        """The vehicle's weight in the MAC's schedule (kept: a restart keeps it)."""
        with writing(self.db) as s:
            vehicle = get(s, vehicle_id)
            vehicle.share = share
            return repo.save(s, vehicle)

    def set_home(self, vehicle_id: int, home: tuple[float, float]) -> Vehicle:
        """Where the vehicle starts in the fleet's frame (as its agent's ``[nav] home`` says)."""
        with writing(self.db) as s:
            vehicle = get(s, vehicle_id)
            vehicle.home_north, vehicle.home_east = home
            return repo.save(s, vehicle)

    def rotate_key(self, vehicle_id: int, key_hex: str | None = None) -> Vehicle:
        """A new key for the vehicle. Commands already queued are re-signed with it when sent; the agent
        needs the same key in its configuration (done at the surface: an acoustic link must never carry
        a key)."""
        with writing(self.db) as s:
            vehicle = get(s, vehicle_id)
            key = _unshared(s, _key(key_hex), vehicle_id)
            if key.hex() == vehicle.key_hex:
                return vehicle  # the key it already has: nothing to stage, no new version
            if keys.pending(vehicle):  # keys.py names the previous key by version - 1: one rotation at a time
                raise Conflict(
                    "a key rotation is waiting for the vehicle's confirmation (its next check-point "
                    "signed with the new key); rotate again after that, or cancel it first "
                    f"(DELETE /api/v1/vehicles/{vehicle_id}/key/pending)",
                    "key",
                )
            vehicle.previous_key_hex = vehicle.key_hex  # staged: see server.vehicles.keys
            vehicle.key_hex = key.hex()
            vehicle.key_version += 1
            vehicle.rotation_since, vehicle.next_key_held = now(), False
            return repo.save(s, vehicle)

    def cancel_rotation(self, vehicle_id: int) -> Vehicle:
        """Undo a rotation the vehicle has not confirmed: the previous key is current again, with its
        version; ``Conflict`` (HTTP 409) if none waits."""
        with writing(self.db) as s:
            vehicle = get(s, vehicle_id)
            if not keys.pending(vehicle):
                raise Conflict(f"vehicle {vehicle.name} has no key rotation waiting", "key")
            vehicle.key_hex, vehicle.previous_key_hex = vehicle.previous_key_hex or "", None
            vehicle.key_version -= 1
            vehicle.rotation_since, vehicle.next_key_held = None, False
            return repo.save(s, vehicle)
