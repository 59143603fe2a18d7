"""A 2D wheel given as an outline (``wheel.outline``): its points read from the scenario
(an inline array of [x, y] or a text file of "x y" lines) and checked, and the outline of
the built-in wheel (rim and lugs) as such a polyline.

The points are metres in the wheel's body frame (axle at the origin, the wheel's angle 0),
counter-clockwise, the last joined back to the first. An outline is refused (one line,
``ScenarioError``) unless it has 3 to MAX_OUTLINE_VERTICES finite points, its segments
do not cross or touch (except neighbours at their common vertex), it runs
counter-clockwise around the axle (which it encloses, not on it), and no point of it is
farther from the axle than max(wheel.radius, wheel.lug_tip_radius), the reach that the
wheel's placement and the slabs of the decomposition are sized by.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from .schema import ScenarioError, show

MAX_OUTLINE_VERTICES = 100_000
MAX_OUTLINE_FILE = 8 << 20  # bytes of an outline file (10^5 lines of two numbers fit)


def _points_of_file(path: str) -> np.ndarray:
    what = f"wheel.outline = {show(path, 200)}"
    p = Path(path)
    try:
        size = p.stat().st_size if p.is_file() else -1
    except (OSError, ValueError):
        size = -1
    if size < 0:
        raise ScenarioError(f"{what}: no such file")
    if size > MAX_OUTLINE_FILE:
        raise ScenarioError(f"{what}: {size} bytes; an outline file is at most {MAX_OUTLINE_FILE} bytes")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file: refused below as too few points
            pts = np.loadtxt(p, dtype=np.float64, ndmin=2)
    except (OSError, ValueError, UnicodeDecodeError) as e:
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ScenarioError(f"{what}: cannot read it as lines of 'x y' ({first[:120]})") from None
    if pts.size == 0:
        pts = np.zeros((0, 2))
    if pts.shape[1] != 2:
        raise ScenarioError(f"{what}: {pts.shape[1]} numbers a line; an outline file has lines of 'x y'")
    return pts


def outline_points(sc) -> np.ndarray:
    """The checked points (V, 2) of the scenario's wheel.outline (module doc)."""
    w = sc.wheel
    value = w.outline
    if isinstance(value, str):
        pts = _points_of_file(value)
        what = f"wheel.outline = {show(value, 200)}"
    else:
        pts = np.array(value, np.float64).reshape(-1, 2)
        what = "wheel.outline"
    check_outline(pts, max(w.radius, w.lug_tip_radius), what)
    return np.ascontiguousarray(pts)


def check_outline(pts: np.ndarray, reach: float, what: str = "wheel.outline") -> None:
    """Refuse (ScenarioError, one line) an outline that is not a simple counter-clockwise
    polyline of 3..MAX_OUTLINE_VERTICES finite points around the axle within ``reach``."""
    n = len(pts)
    if n > MAX_OUTLINE_VERTICES:
        raise ScenarioError(f"{what}: {n} points; an outline has at most {MAX_OUTLINE_VERTICES}")
    if n < 3:
        raise ScenarioError(f"{what}: {n} points; an outline needs at least 3")
    if not np.isfinite(pts).all():
        raise ScenarioError(f"{what}: a point that is not a finite number")
    far = float(np.sqrt((pts * pts).sum(axis=1)).max())
    if not far <= reach:
        raise ScenarioError(
            f"{what}: a point {far!r} m from the axle, beyond max(wheel.radius, wheel.lug_tip_radius) = {reach!r} m "
            f"(the reach the wheel is placed and the slabs are sized by)"
        )
    from ..physics.outline import self_intersection

    k, j = self_intersection(pts)
    if k >= 0:
        raise ScenarioError(f"{what}: segments {k} and {j} cross or touch (an outline is a simple polygon)")
    x, y = pts[:, 0], pts[:, 1]
    area = 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    if not area > 0.0:
        raise ScenarioError(f"{what}: runs clockwise (or encloses nothing); an outline runs counter-clockwise")
    if not _encloses_origin(pts):
        raise ScenarioError(f"{what}: does not enclose the axle (the origin of its points) strictly")


def _encloses_origin(pts: np.ndarray) -> bool:
    """Whether the origin lies strictly inside the simple polygon pts (ray casting along +x;
    a point on the outline is not inside)."""
    a = pts
    b = np.roll(pts, -1, axis=0)
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    dot = a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]
    if np.any((cross == 0.0) & (dot <= 0.0)):
        return False  # the origin on a segment
    up = (a[:, 1] > 0.0) != (b[:, 1] > 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = a[:, 0] + (0.0 - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return bool(np.count_nonzero(up & (xs > 0.0)) % 2 == 1)


def builtin_outline(
    radius: float, n_lugs: int, lug_tip_radius: float, lug_thickness: float, deviation: float = 1e-4
) -> np.ndarray:
    """The built-in wheel (rim of ``radius``, ``n_lugs`` lugs of ``lug_thickness`` reaching
    ``lug_tip_radius``, lug k along angle 2 pi k / n_lugs) as a counter-clockwise outline:
    the rim a polygon whose chords leave the circle by less than ``deviation`` (m), its
    vertices on it, each lug its two straight sides and a tip rounded as the built-in
    capsule's (a polygon within ``deviation`` of its half circle; a square tip when the
    lug is shorter than its half thickness)."""
    half = 0.5 * lug_thickness
    step = 2.0 * math.acos(max(-1.0, 1.0 - deviation / radius))  # rim chord's angle
    pts: list[tuple[float, float]] = []

    def arc(r: float, a0: float, a1: float, cx: float = 0.0, cy: float = 0.0) -> None:
        """Points on a circle from angle a0 to a1 (a0 < a1; both ends included)."""
        m = max(1, math.ceil((a1 - a0) / (2.0 * math.acos(max(-1.0, 1.0 - deviation / r)))))
        for s in range(m + 1):
            a = a0 + (a1 - a0) * s / m
            pts.append((cx + r * math.cos(a), cy + r * math.sin(a)))

    if n_lugs <= 0 or lug_tip_radius <= radius:
        m = max(3, math.ceil(2.0 * math.pi / step))
        return np.array(
            [(radius * math.cos(2 * math.pi * s / m), radius * math.sin(2 * math.pi * s / m)) for s in range(m)]
        )
    root = math.asin(min(1.0, half / radius))  # the lug's side meets the rim this far from its axis
    centre_out = max(radius, lug_tip_radius - half)  # the capsule's outer centre
    for k in range(n_lugs):
        phi = 2.0 * math.pi * k / n_lugs
        ux, uy = math.cos(phi), math.sin(phi)
        vx, vy = -uy, ux  # the lug's left (counter-clockwise) side
        # up the lug's right side (-v), round the tip, down its left side (+v)
        x_root = radius * math.cos(root)
        pts.append((x_root * ux - half * vx, x_root * uy - half * vy))
        cx, cy = centre_out * ux, centre_out * uy
        if lug_tip_radius - half > radius:
            arc(half, phi - 0.5 * math.pi, phi + 0.5 * math.pi, cx, cy)
        else:  # a lug shorter than its half thickness: a square tip at the tip radius
            pts.append((lug_tip_radius * ux - half * vx, lug_tip_radius * uy - half * vy))
            pts.append((lug_tip_radius * ux + half * vx, lug_tip_radius * uy + half * vy))
        pts.append((x_root * ux + half * vx, x_root * uy + half * vy))
        # the rim to the next lug's right side, its own ends left out (the lugs' root points)
        a0 = phi + root
        a1 = phi + 2.0 * math.pi / n_lugs - root
        if a1 > a0:
            mark = len(pts)
            arc(radius, a0, a1)
            del pts[mark]
            pts.pop()
    return np.array(pts)
