"""What the shore knows of a vehicle, how old it is and how sure: the last reported pose and its age,
and the pose predicted since (dead reckoning toward the current target) with an uncertainty that
grows with silence. Pure functions of the check-points, the mission and the command being followed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tacit.navigation import move_target
from tacit.packets import MissionState

DRIFT = 0.05  # m/s: how fast the uncertainty about a silent vehicle grows (currents, dead-reckoning error)
BASE_UNCERTAINTY = 1.0  # m: the reported position's own error (dead reckoning between fixes)
DEFAULT_SPEED = 0.5  # m/s when the vehicle's speed cannot be estimated from its check-points
MOVING = {
    MissionState.PREPROGRAMMED,
    MissionState.AWAITING_COMMAND,
    MissionState.SELF_DETERMINED,
    MissionState.COMMANDED,
    MissionState.RETURNING,
}
FOLLOWING = (MissionState.PREPROGRAMMED, MissionState.AWAITING_COMMAND)  # on the pre-programmed trajectory


def state_of(cp: dict) -> MissionState | None:
    """The mission state a check-point's body names (lower case), None if it names none."""
    try:
        return MissionState[str(cp.get("state", "")).upper()]
    except KeyError:
        return None


@dataclass(frozen=True)
class Estimate:
    north: float
    east: float
    depth: float
    radius: float  # m: the uncertainty (one circle, grows with silence)
    target: tuple[float, float, float] | None  # where the shore thinks the vehicle is going
    age: float  # s since the last report

    def as_dict(self) -> dict:
        return {
            "north": round(self.north, 2),
            "east": round(self.east, 2),
            "depth": round(self.depth, 2),
            "radius_m": round(self.radius, 2),
            "age_s": round(self.age, 1),
            "target": None if self.target is None else [round(x, 2) for x in self.target],
        }


def target_of(
    cp: dict, waypoints: list[dict] | None, command: dict | None, home: tuple[float, float] = (0.0, 0.0)
) -> tuple[float, float, float] | None:
    """Where the vehicle in check-point ``cp`` is steering, in the fleet's frame: its mission's waypoint
    (relative to its ``home``), home, the commanded target (``command``: the executing command and the
    pose it was given from), or None (staying put)."""
    state = state_of(cp)
    if state in FOLLOWING and waypoints:
        w = waypoints[min(int(cp.get("waypoint", 0)), len(waypoints) - 1)]
        return (home[0] + w["north"], home[1] + w["east"], w["depth"])
    if state is MissionState.RETURNING:
        return (home[0], home[1], cp["depth"])
    if state is MissionState.COMMANDED and command:
        if command["command"] == "goto_depth":
            return (cp["north"], cp["east"], command["depth"])
        if command["command"] == "move" and command.get("from"):
            f = command["from"]
            north, east = move_target(
                f["north"],
                f["east"],
                f["heading"],
                command["distance"],
                command["angle"],
                command.get("absolute_angle", False),
            )
            return (north, east, f["depth"] + command["depth"])
    return None


def estimate(
    cp: dict,
    heard_at: float,
    now: float,
    target: tuple[float, float, float] | None,
    speed: float | None = None,
) -> Estimate:
    """Dead reckoning from the last report toward ``target`` at ``speed`` (m/s) for the time since."""
    age = max(0.0, now - heard_at)
    north, east, depth = cp["north"], cp["east"], cp["depth"]
    moving = state_of(cp) in MOVING
    if target is not None and moving:
        step = (speed if speed is not None else DEFAULT_SPEED) * age
        dn, de, dd = target[0] - north, target[1] - east, target[2] - depth
        dist = math.hypot(dn, de)
        f = 1.0 if dist <= step else step / dist
        north, east = north + f * dn, east + f * de
        depth += math.copysign(min(abs(dd), 0.2 * age), dd)  # vertical rate about 0.2 m/s
    return Estimate(north, east, depth, BASE_UNCERTAINTY + DRIFT * age, target if moving else None, age)


def speed_between(a: dict, a_at: float, b: dict, b_at: float) -> float | None:
    """The speed (m/s, shore clock) between two check-points received at ``a_at`` and ``b_at``."""
    if b_at - a_at <= 0:
        return None
    return math.hypot(b["north"] - a["north"], b["east"] - a["east"]) / (b_at - a_at)
