"""Local-frame geometry shared by the shore (limits, click-to-target) and the vehicle (dead reckoning).

Frame: north, east in metres from home, depth positive down; headings and bearings in degrees
clockwise from north. A control packet's angle is a heading change, or a bearing when absolute.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

EARTH_RADIUS = 6_378_137.0


def wrap180(angle: float) -> float:
    """An angle in (-180, 180]."""
    wrapped = (angle + 180.0) % 360.0 - 180.0
    return 180.0 if wrapped == -180.0 else wrapped


def course(heading: float, angle: float, absolute: bool) -> float:
    """The course (deg) a move follows: the bearing itself, or the heading turned by ``angle``."""
    return (angle if absolute else heading + angle) % 360.0


def move_target(
    north: float, east: float, heading: float, distance: float, angle: float, absolute: bool = False
) -> tuple[float, float]:
    c = math.radians(course(heading, angle, absolute))
    return north + distance * math.cos(c), east + distance * math.sin(c)


def distance_and_angle(
    north: float, east: float, heading: float, to_north: float, to_east: float, absolute: bool = False
) -> tuple[float, float]:
    """The (distance, angle) of a move from here to a point: what clicking the map fills in."""
    dn, de = to_north - north, to_east - east
    distance = math.hypot(dn, de)
    bearing = math.degrees(math.atan2(de, dn)) % 360.0
    return distance, (wrap180(bearing) if absolute else wrap180(bearing - heading))


@dataclass
class Origin:
    """Home, where north = east = 0 (flat-earth conversion: fine over a few kilometres)."""

    lat: float = 40.4862
    lon: float = -74.4518

    def to_global(self, north: float, east: float) -> tuple[float, float]:
        lat = self.lat + math.degrees(north / EARTH_RADIUS)
        lon = self.lon + math.degrees(east / (EARTH_RADIUS * math.cos(math.radians(self.lat))))
        return lat, lon

    def to_local(self, lat: float, lon: float) -> tuple[float, float]:
        north = math.radians(lat - self.lat) * EARTH_RADIUS
        east = math.radians(lon - self.lon) * EARTH_RADIUS * math.cos(math.radians(self.lat))
        return north, east


@dataclass(frozen=True)
class Pose:
    """Where a vehicle is and which way it points (local frame)."""

    north: float
    east: float
    depth: float
    heading: float

    @classmethod
    def from_checkpoint(cls, checkpoint: dict | None) -> Pose | None:
        """The pose a decoded check-point reports; None without one."""
        if not checkpoint:
            return None
        return cls(checkpoint["north"], checkpoint["east"], checkpoint["depth"], checkpoint["heading"])


@dataclass
class Target:
    """Where the navigator steers to."""

    north: float
    east: float
    depth: float
    heading: float | None = None  # hold this heading when arrived (default: keep the current one)
