"""Pure geometry in the fleet's shared local frame (m north, m east, m depth): the distance between two
planned paths (3D segments, centre to centre), convex hulls and simple polygons in the horizontal plane.
No state and no I/O: the separation check, the lost-link check and the team missions' lanes build on it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Point = tuple[float, float, float]  # north, east, depth
Flat = tuple[float, float]  # north, east
EPS = 1e-12


def _sub(a: Point, b: Point) -> Point:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _dot(a: Point, b: Point) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _along(p: Point, d: Point, k: float) -> Point:
    return (p[0] + k * d[0], p[1] + k * d[1], p[2] + k * d[2])


def _clamp(x: float) -> float:
    return min(1.0, max(0.0, x))


def _parameters(d1: Point, d2: Point, r: Point) -> tuple[float, float]:
    """Where on p0 + s d1 and q0 + t d2 (s, t in 0..1) the two segments come closest (Ericson,
    Real-Time Collision Detection 5.1.9); ``r`` is p0 - q0. A segment of length 0 is a point."""
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    if a <= EPS:
        return 0.0, (_clamp(f / e) if e > EPS else 0.0)
    c = _dot(d1, r)
    if e <= EPS:
        return _clamp(-c / a), 0.0
    b = _dot(d1, d2)
    denom = a * e - b * b
    s = _clamp((b * f - c * e) / denom) if denom > EPS else 0.0
    t = (b * s + f) / e
    if t < 0:
        return _clamp(-c / a), 0.0
    if t > 1:
        return _clamp((b - c) / a), 1.0
    return s, t


def segment_distance(p0: Point, p1: Point, q0: Point, q1: Point) -> float:
    """The closest distance between segments p0-p1 and q0-q1 (either may be a single point)."""
    d1, d2 = _sub(p1, p0), _sub(q1, q0)
    s, t = _parameters(d1, d2, _sub(p0, q0))
    return math.dist(_along(p0, d1, s), _along(q0, d2, t))


def _cross(o: Flat, a: Flat, b: Flat) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def convex_hull(points: Sequence[Flat]) -> list[Flat]:
    """The convex hull, counter-clockwise (monotone chain); one or two points when degenerate."""
    unique = sorted(set(points))
    if len(unique) <= 2:
        return unique
    lower: list[Flat] = []
    upper: list[Flat] = []
    for chain, ordered in ((lower, unique), (upper, list(reversed(unique)))):
        for p in ordered:
            while len(chain) >= 2 and _cross(chain[-2], chain[-1], p) <= 0:
                chain.pop()
            chain.append(p)
    return lower[:-1] + upper[:-1]


def _edges(polygon: Sequence[Flat]) -> list[tuple[Flat, Flat]]:
    if len(polygon) <= 2:
        return [(polygon[0], polygon[-1])]
    return [(polygon[i], polygon[(i + 1) % len(polygon)]) for i in range(len(polygon))]


def _inside_hull(p: Flat, hull: Sequence[Flat]) -> bool:
    return len(hull) >= 3 and all(_cross(a, b, p) >= 0 for a, b in _edges(hull))


def _flat_distance(a: tuple[Flat, Flat], b: tuple[Flat, Flat]) -> float:
    return segment_distance((*a[0], 0.0), (*a[1], 0.0), (*b[0], 0.0), (*b[1], 0.0))


def hull_distance(a: Sequence[Flat], b: Sequence[Flat]) -> float:
    """The horizontal distance between two convex hulls (``convex_hull``); 0 when they overlap."""
    if any(_inside_hull(p, b) for p in a) or any(_inside_hull(p, a) for p in b):
        return 0.0
    return min(_flat_distance(e, f) for e in _edges(a) for f in _edges(b))


def area(polygon: Sequence[Flat]) -> float:
    """The polygon's area (shoelace; either winding)."""
    return abs(sum(_cross((0.0, 0.0), p, q) for p, q in _edges(polygon))) / 2 if len(polygon) >= 3 else 0.0


def is_simple(polygon: Sequence[Flat]) -> bool:
    """Whether the polygon's edges meet only where neighbours share a corner (no crossing, no touching)."""
    edges = _edges(polygon)
    n = len(edges)
    for i in range(n):
        for j in range(i + 1, n):
            neighbours = j == i + 1 or (i == 0 and j == n - 1)
            if not neighbours and _flat_distance(edges[i], edges[j]) < 1e-9:
                return False
    return True


def crossings(polygon: Sequence[Flat], east: float) -> list[float]:
    """Where the line of constant ``east`` crosses the polygon's edges (norths, sorted): consecutive
    pairs are the spans inside it (each vertex counted once, on its upper edge)."""
    norths = []
    for (n0, e0), (n1, e1) in _edges(polygon):
        if (e0 <= east < e1) or (e1 <= east < e0):
            norths.append(n0 + (east - e0) * (n1 - n0) / (e1 - e0))
    return sorted(norths)
