"""Which of a vehicle's keys to use: the staged rotation of ``tacit.auth`` on the shore.

After a rotation the vehicle may not hold the new key yet (it is installed at the surface, or ahead of
time as the agent's ``next_key``). Commands and SYNC heartbeats are signed with the last confirmed key
(``previous_key_hex``, version ``key_version - 1``) until the vehicle says it holds the new one: a
check-point signed with the confirmed key whose *holds the next key* flag is set (``next_key_held``,
kept from the latest such check-point: a vehicle restarted without ``next_key`` clears it again). From
then on they are signed with the new key; the vehicle switches to it at the first it accepts and
confirms it with a check-point signed with it, which ends the rotation. A vehicle that never says so
never hears the new key, so its link stays alive. The flag names a version, not a key: the key staged
must be the one installed as ``next_key``. Check-points are accepted under either key. A rotation still
waiting can be cancelled (the previous key is current again).
"""

from __future__ import annotations

from server.vehicles.models import Vehicle


def pending(vehicle: Vehicle) -> bool:
    """Whether a rotation waits for the vehicle's confirmation."""
    return vehicle.previous_key_hex is not None


def current(vehicle: Vehicle) -> tuple[int, bytes]:
    """The newest key."""
    return vehicle.key_version, bytes.fromhex(vehicle.key_hex)


def for_commands(vehicle: Vehicle) -> tuple[int, bytes]:
    """The key the vehicle is known to hold (commands and SYNCs are signed with it)."""
    if vehicle.previous_key_hex and not vehicle.next_key_held:
        return vehicle.key_version - 1, bytes.fromhex(vehicle.previous_key_hex)
    return current(vehicle)


def accepted(vehicle: Vehicle) -> dict[int, bytes]:
    """Every key a check-point may be signed with, by version."""
    keys = dict([current(vehicle)])
    if vehicle.previous_key_hex:
        keys[vehicle.key_version - 1] = bytes.fromhex(vehicle.previous_key_hex)
    return keys


def rotation(vehicle: Vehicle) -> dict[str, float | int | bool] | None:
    """The waiting rotation as the API shows it: the new key's version, since when, whether the vehicle
    said it holds the new key (commands and SYNCs are signed with it then)."""
    if not pending(vehicle):
        return None
    return {
        "pending_version": vehicle.key_version,
        "since": vehicle.rotation_since or 0.0,
        "held": vehicle.next_key_held,
    }
