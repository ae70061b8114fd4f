"""Pure geometry in the fleet's shared local frame (m north, m east, m depth): the distance between two
segments and between the convex hulls of two sets of points in 3D (where two vehicles may be), convex
hulls and simple polygons in the horizontal plane. No state and no I/O: the separation check and the team
missions' lanes build on it.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

Point = tuple[float, float, float]  # north, east, depth
Flat = tuple[float, float]  # north, east
EPS = 1e-12
GJK_ROUNDS = 64  # GJK converges in a few rounds on hulls of a few points; a bound, never reached in tests
GJK_TOLERANCE = 1e-9  # relative: a support point no nearer than this stops it


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


def box_gap(a: Sequence[Point], b: Sequence[Point]) -> float:
    """The distance between the axis-aligned boxes around two point sets: never more than ``hull_gap``."""
    square = 0.0
    for i in range(3):
        gap = max(min(p[i] for p in b) - max(p[i] for p in a), min(p[i] for p in a) - max(p[i] for p in b))
        square += max(0.0, gap) ** 2
    return math.sqrt(square)


def hull_gap(a: Sequence[Point], b: Sequence[Point]) -> float:
    """The distance between the convex hulls of two point sets in 3D (0 when they meet): GJK (Gilbert,
    Johnson and Keerthi, 1988) on their Minkowski difference, whose point nearest the origin is the gap."""

    def support(d: Point) -> Point:  # the point of the difference a - b farthest along d
        return _sub(max(a, key=lambda p: _dot(p, d)), min(b, key=lambda q: _dot(q, d)))

    simplex = [_sub(a[0], b[0])]
    v = simplex[0]
    for _ in range(GJK_ROUNDS):
        vv = _dot(v, v)
        if vv <= EPS:
            return 0.0
        w = support((-v[0], -v[1], -v[2]))
        if w in simplex or vv - _dot(v, w) <= GJK_TOLERANCE * vv:  # no point of the difference is nearer
            break
        simplex, v = _nearest([*simplex, w])
    return math.sqrt(_dot(v, v))


def _nearest(points: list[Point]) -> tuple[list[Point], Point]:
    """The point of the hull of ``points`` (at most four) nearest the origin, and the fewest of them whose
    hull holds it: the nearest of the faces' nearest points that lie inside their face."""
    best: tuple[float, list[Point], Point] | None = None
    for size in range(1, len(points) + 1):
        for face in itertools.combinations(points, size):
            found = _face_nearest(face)
            if found is not None and (best is None or _dot(found, found) < best[0] - EPS):
                best = (_dot(found, found), list(face), found)
    assert best is not None  # a single point always has one
    return best[1], best[2]


def _face_nearest(face: Sequence[Point]) -> Point | None:
    """The point of the face's affine span nearest the origin, if it lies inside the face (None if not,
    or if the face is degenerate: a smaller face then holds it)."""
    base, rest = face[0], [_sub(p, face[0]) for p in face[1:]]
    if not rest:
        return base
    gram = [[_dot(e, f) for f in rest] for e in rest]
    weights = _solve(gram, [-_dot(base, e) for e in rest])
    if weights is None or min(weights) <= 0 or sum(weights) >= 1:
        return None
    point = base
    for k, e in zip(weights, rest, strict=True):
        point = _along(point, e, k)
    return point


def _solve(matrix: list[list[float]], rhs: list[float]) -> list[float] | None:
    """``matrix`` x = ``rhs`` (at most 3 x 3) by elimination with partial pivoting; None if singular."""
    n = len(rhs)
    rows = [[*row, r] for row, r in zip(matrix, rhs, strict=True)]
    scale = max(abs(x) for row in matrix for x in row) or 1.0
    for col in range(n):
        pivot = max(range(col, n), key=lambda r: abs(rows[r][col]))
        if abs(rows[pivot][col]) <= 1e-12 * scale:
            return None
        rows[col], rows[pivot] = rows[pivot], rows[col]
        for r in range(col + 1, n):
            f = rows[r][col] / rows[col][col]
            rows[r] = [x - f * y for x, y in zip(rows[r], rows[col], strict=True)]
    out = [0.0] * n
    for r in reversed(range(n)):
        out[r] = (rows[r][n] - sum(rows[r][c] * out[c] for c in range(r + 1, n))) / rows[r][r]
    return out


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


def _flat_distance(a: tuple[Flat, Flat], b: tuple[Flat, Flat]) -> float:
    return segment_distance((*a[0], 0.0), (*a[1], 0.0), (*b[0], 0.0), (*b[1], 0.0))


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
