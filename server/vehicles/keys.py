"""Which of a vehicle's keys to use: the staged rotation of ``tacit.auth`` on the shore.

After a rotation the vehicle may not hold the new key yet (it is installed at the surface, or ahead of
time as the agent's ``next_key``). Until a check-point signed with the new key arrives, commands and
SYNC heartbeats are signed with the last confirmed key (``previous_key_hex``, version
``key_version - 1``), so a vehicle without the new key keeps obeying commands and keeps its link alive
(its link-lost failsafe counts only authentic control packets). Only a probe, every ``probe_every``-th
SYNC (``server.link.heartbeat``), is signed with the new key: a vehicle that has it switches to it and
confirms it with a check-point signed with it; one that has not drops the probe. Check-points are
accepted under either key. A rotation still waiting can be cancelled (the previous key is current again).
"""

from __future__ import annotations

from server.vehicles.models import Vehicle


def pending(vehicle: Vehicle) -> bool:
    """Whether a rotation waits for the vehicle's confirmation."""
    return vehicle.previous_key_hex is not None


def current(vehicle: Vehicle) -> tuple[int, bytes]:
    """The newest key (probe SYNCs are signed with it while a rotation waits)."""
    return vehicle.key_version, bytes.fromhex(vehicle.key_hex)


def for_commands(vehicle: Vehicle) -> tuple[int, bytes]:
    """The key the vehicle is known to hold (commands and SYNCs are signed with it)."""
    if vehicle.previous_key_hex:
        return vehicle.key_version - 1, bytes.fromhex(vehicle.previous_key_hex)
    return current(vehicle)


def accepted(vehicle: Vehicle) -> dict[int, bytes]:
    """Every key a check-point may be signed with, by version."""
    keys = dict([current(vehicle)])
    if vehicle.previous_key_hex:
        keys[vehicle.key_version - 1] = bytes.fromhex(vehicle.previous_key_hex)
    return keys


def rotation(vehicle: Vehicle) -> dict[str, float | int] | None:
    """The waiting rotation as the API shows it: the new key's version, since when, probes sent."""
    if not pending(vehicle):
        return None
    return {
        "pending_version": vehicle.key_version,
        "since": vehicle.rotation_since or 0.0,
        "probes": vehicle.rotation_probes,
    }
