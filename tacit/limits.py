"""A vehicle's limits: the one rule the shore checks before sending and the vehicle checks on arrival.

The shore refuses a command that breaks them (HTTP 422 naming the field) so no slot on the link is
spent on it; the vehicle checks again against its own configured limits and its own pose, because the
shore's view is old, and reports the ``Reason`` in its next check-point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tacit import navigation
from tacit.navigation import Pose
from tacit.packets import Command, Reason


@dataclass(frozen=True)
class Refusal:
    """Why a command is refused: the reason code the vehicle reports, the field at fault, in words."""

    reason: Reason
    field: str
    message: str


@dataclass(frozen=True)
class Limits:
    max_depth: float = 100.0  # m
    max_distance: float = 500.0  # m per move
    geofence_radius: float = 1000.0  # m from home
    max_speed: float = 1.0  # m/s

    def check(
        self,
        command: Command,
        distance: float = 0.0,
        angle: float = 0.0,
        depth: float = 0.0,
        speed: float = 0.0,
        absolute: bool = False,
        pose: Pose | None = None,
    ) -> Refusal | None:
        """The refusal of a command (None: within limits). Without a pose, only what needs none."""
        if speed > self.max_speed:
            return Refusal(
                Reason.OUT_OF_LIMITS, "speed", f"speed {speed} m/s exceeds the vehicle's {self.max_speed} m/s"
            )
        if command is Command.MOVE:
            return self._move(distance, angle, depth, absolute, pose)
        if command is Command.GOTO_DEPTH:
            return self._depth(depth, "the target depth")
        return None

    def _move(
        self, distance: float, angle: float, change: float, absolute: bool, pose: Pose | None
    ) -> Refusal | None:
        if distance > self.max_distance:
            return Refusal(
                Reason.OUT_OF_LIMITS,
                "distance",
                f"distance {distance} m exceeds the vehicle's {self.max_distance} m per move",
            )
        if pose is None:
            if abs(change) > self.max_depth:
                return Refusal(
                    Reason.OUT_OF_LIMITS,
                    "depth",
                    f"depth change {change} m exceeds the vehicle's {self.max_depth} m",
                )
            return None
        north, east = navigation.move_target(pose.north, pose.east, pose.heading, distance, angle, absolute)
        return self.check_target(north, east, pose.depth + change)

    def check_target(self, north: float, east: float, depth: float) -> Refusal | None:
        """Whether a point may be steered to: inside the geofence, between the surface and max depth."""
        refused = self._depth(depth, "the target depth")
        if refused is None and math.hypot(north, east) > self.geofence_radius:
            return Refusal(
                Reason.GEOFENCE,
                "distance",
                f"the target is {math.hypot(north, east):.0f} m from home, "
                f"outside the {self.geofence_radius:.0f} m geofence",
            )
        return refused

    def _depth(self, depth: float, what: str) -> Refusal | None:
        if 0 <= depth <= self.max_depth:
            return None
        return Refusal(
            Reason.OUT_OF_LIMITS, "depth", f"{what} {depth:.2f} m is outside 0 .. {self.max_depth} m"
        )
