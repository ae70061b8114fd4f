"""Which of a vehicle's keys to use: the staged rotation of ``tacit.auth`` on the shore.

After a rotation the vehicle may not hold the new key yet (it is installed at the surface, or ahead of
time as the agent's ``next_key``). Until a check-point signed with the new key arrives, commands are
signed with the last confirmed key (``previous_key_hex``, version ``key_version - 1``) and only SYNC
heartbeats use the new one: a vehicle that has the new key answers them with check-points signed with
it, which confirms it; one that has not keeps obeying commands signed with the old key, instead of
leaving every command "acknowledged" while it logs BadMac. Check-points are accepted under either.
"""

from __future__ import annotations

from server.models import Vehicle


def current(vehicle: Vehicle) -> tuple[int, bytes]:
    """The newest key (SYNC packets are signed with it)."""
    return vehicle.key_version, bytes.fromhex(vehicle.key_hex)


def for_commands(vehicle: Vehicle) -> tuple[int, bytes]:
    """The key the vehicle is known to hold."""
    if vehicle.previous_key_hex:
        return vehicle.key_version - 1, bytes.fromhex(vehicle.previous_key_hex)
    return current(vehicle)


def accepted(vehicle: Vehicle) -> dict[int, bytes]:
    """Every key a check-point may be signed with, by version."""
    keys = dict([current(vehicle)])
    if vehicle.previous_key_hex:
        keys[vehicle.key_version - 1] = bytes.fromhex(vehicle.previous_key_hex)
    return keys
