"""A 2D wheel given as a closed polyline (numba, no I/O): its segment grid, built once,
and the nearest point of the outline to a disc's centre, in the wheel's body frame.

The outline (``layout.WheelOutline``) replaces the built-in rim and lugs for the contact:
a disc has at most one contact with it, at the outline's point nearest its centre (over
every segment: the projection onto the segment, clamped to its ends, so a vertex is the
common end of two segments; equal distances: the lower segment index). So a disc sliding
over the vertex between two collinear segments feels no jump: the nearest point and its
distance are continuous there. Whether the centre is inside the outline is the side of
that point: on a segment's interior, the side of that segment (counter-clockwise: inside
on its left); at a vertex, the vertex's turn (a point nearest a convex vertex is outside
it, one nearest a reflex vertex inside).

Only the segments of the grid's cells that the disc's box (centre +- radius) meets are
tested: a segment within the radius has its nearest point in that box, and every segment
is listed in each cell its bounding box meets. A centre inside the outline deeper than
its radius finds no segment within reach and gets no contact (an overlap of more than a
diameter: the run has failed by then).
"""

import math

import numpy as np
from numba import njit

from .detmath import det_cos, det_sin
from .layout import WheelOutline

MAX_GRID_CELLS = 1 << 20  # the grid's cells at most (a coarser cell beyond)


@njit(cache=True)
def _cell_range(lo, hi, x0, h, n):
    """The cells [a, b] along one axis that the interval [lo, hi] meets, clamped to the grid."""
    a = int(math.floor((lo - x0) / h))
    b = int(math.floor((hi - x0) / h))
    return max(a, 0), min(b, n - 1)


@njit(cache=True)
def _segment_cells(vert, x0, y0, h, nx, ny, cell_start, cell_seg, fill):
    """Count (fill False: into cell_start[c + 1]) or list (fill True: at cell_start's
    cursor) each segment in every cell its bounding box meets, in ascending segment order."""
    nv = vert.shape[0]
    cursor = cell_start[:-1].copy()
    for k in range(nv):
        j = k + 1 if k + 1 < nv else 0
        ax, ay, bx, by = vert[k, 0], vert[k, 1], vert[j, 0], vert[j, 1]
        ia, ib = _cell_range(min(ax, bx), max(ax, bx), x0, h, nx)
        ja, jb = _cell_range(min(ay, by), max(ay, by), y0, h, ny)
        for cy in range(ja, jb + 1):
            for cx in range(ia, ib + 1):
                c = cy * nx + cx
                if fill:
                    cell_seg[cursor[c]] = k
                    cursor[c] += 1
                else:
                    cell_start[c + 1] += 1


def wheel_outline(vert: np.ndarray, cell: float) -> WheelOutline:
    """The kernels' outline (``layout.WheelOutline``) of a closed counter-clockwise polyline
    vert (V, 2) in the wheel's body frame, its segments gridded in cells of side ``cell``
    (at least so coarse that the grid has MAX_GRID_CELLS cells)."""
    vert = np.ascontiguousarray(vert, np.float64)
    lo = vert.min(axis=0)
    hi = vert.max(axis=0)
    ext = hi - lo
    h = max(float(cell), float(max(ext[0], ext[1])) / 1024.0, 1e-12)
    while (int(ext[0] / h) + 1) * (int(ext[1] / h) + 1) > MAX_GRID_CELLS:
        h *= 2.0
    nx = int(ext[0] / h) + 1
    ny = int(ext[1] / h) + 1
    cell_start = np.zeros(nx * ny + 1, np.int64)
    empty = np.zeros(0, np.int64)
    _segment_cells(vert, lo[0], lo[1], h, nx, ny, cell_start, empty, False)
    cell_start = np.cumsum(cell_start)
    cell_seg = np.empty(int(cell_start[-1]), np.int64)
    _segment_cells(vert, lo[0], lo[1], h, nx, ny, cell_start, cell_seg, True)
    prev = np.roll(vert, 1, axis=0)
    nxt = np.roll(vert, -1, axis=0)
    e_in = vert - prev
    e_out = nxt - vert
    turn = np.sign(e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0])
    reach = float(np.sqrt((vert * vert).sum(axis=1)).max())
    return WheelOutline(
        vert,
        turn.astype(np.float64),
        np.array([lo[0], lo[1], h]),
        np.array([nx, ny], np.int64),
        cell_start,
        cell_seg,
        np.array([reach]),
    )


@njit(inline="always", cache=True)
def segment_point(vert, k, px, py):
    """The point of segment k nearest (px, py): (qx, qy, squared distance, t in [0, 1])."""
    nv = vert.shape[0]
    j = k + 1 if k + 1 < nv else 0
    ax = vert[k, 0]
    ay = vert[k, 1]
    ex = vert[j, 0] - ax
    ey = vert[j, 1] - ay
    ee = ex * ex + ey * ey
    t = 0.0
    if ee > 0.0:
        t = ((px - ax) * ex + (py - ay) * ey) / ee
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
    qx = ax + t * ex
    qy = ay + t * ey
    dx = px - qx
    dy = py - qy
    return qx, qy, dx * dx + dy * dy, t


@njit(cache=True)
def nearest_point(ol, px, py, reach):
    """The outline's point nearest (px, py) among the segments of the cells within reach of
    it (module doc), in the body frame: (segment, qx, qy, distance, inside); segment -1
    when no segment is within reach."""
    vert = ol.vert
    x0 = ol.grid[0]
    y0 = ol.grid[1]
    h = ol.grid[2]
    nx = ol.dims[0]
    ny = ol.dims[1]
    ia, ib = _cell_range(px - reach, px + reach, x0, h, nx)
    ja, jb = _cell_range(py - reach, py + reach, y0, h, ny)
    best = -1
    bq = (0.0, 0.0)
    bd2 = reach * reach
    bt = 0.0
    for cy in range(ja, jb + 1):
        for cx in range(ia, ib + 1):
            c = cy * nx + cx
            for at in range(ol.cell_start[c], ol.cell_start[c + 1]):
                k = ol.cell_seg[at]
                qx, qy, d2, t = segment_point(vert, k, px, py)
                if d2 < bd2 or (d2 == bd2 and best >= 0 and k < best):
                    best = k
                    bd2 = d2
                    bq = (qx, qy)
                    bt = t
    if best < 0:
        return -1, 0.0, 0.0, 0.0, False
    nv = vert.shape[0]
    if bt == 0.0 or bt == 1.0:  # a vertex: its turn (straight: the segment's side)
        v = best if bt == 0.0 else (best + 1 if best + 1 < nv else 0)
        tv = ol.turn[v]
        if tv != 0.0:
            return best, bq[0], bq[1], math.sqrt(bd2), tv < 0.0
    j = best + 1 if best + 1 < nv else 0
    ex = vert[j, 0] - vert[best, 0]
    ey = vert[j, 1] - vert[best, 1]
    side = ex * (py - vert[best, 1]) - ey * (px - vert[best, 0])
    return best, bq[0], bq[1], math.sqrt(bd2), side > 0.0


@njit(inline="always", cache=True)
def outline_scene(wg, ws, ol):
    """The outline wheel's part of a step's scene (body_rows' ``outline_rows``): whether
    there is one, its centre, velocity, spin, the cosine and sine of its angle, its mass."""
    g = wg[0]
    s = ws[0]
    on = g.enabled > 0.5 and ol.vert.shape[0] > 0
    # the turn into the body frame of the same bits on every machine (physics.detmath)
    return on, s.x, s.y, s.vx, s.vy, s.wz, det_cos(s.theta), det_sin(s.theta), g.mass


@njit(cache=True)
def no_outline_rows(i, d, cp, oscene, ol, body, bat, bend, dt):
    """A dimension without outline wheels (3D): no row."""
    return bat, False


@njit(cache=True)
def self_intersection(vert):
    """A pair of non-adjacent segments of the closed polyline vert that meet (touching
    counts), as (k, j), or (-1, -1); tests only the pairs that share a grid cell."""
    _, _, _, nx, ny, cell_start, cell_seg = segment_grid(vert)
    nv = vert.shape[0]
    for c in range(nx * ny):
        for p in range(cell_start[c], cell_start[c + 1]):
            k = cell_seg[p]
            for q in range(p + 1, cell_start[c + 1]):
                j = cell_seg[q]
                if abs(k - j) == 1 or abs(k - j) == nv - 1:
                    continue
                if _segments_meet(vert, k, j):
                    return min(k, j), max(k, j)
    return -1, -1


@njit(cache=True)
def segment_grid(vert):
    """A segment grid as ``wheel_outline``'s with a cell of twice the mean segment length
    (the self-intersection test's): (x0, y0, h, nx, ny, cell_start, cell_seg)."""
    nv = vert.shape[0]
    lx = vert[0, 0]
    hx = vert[0, 0]
    ly = vert[0, 1]
    hy = vert[0, 1]
    total = 0.0
    for k in range(nv):
        j = k + 1 if k + 1 < nv else 0
        lx = min(lx, vert[k, 0])
        hx = max(hx, vert[k, 0])
        ly = min(ly, vert[k, 1])
        hy = max(hy, vert[k, 1])
        total += math.hypot(vert[j, 0] - vert[k, 0], vert[j, 1] - vert[k, 1])
    h = max(2.0 * total / nv, max(hx - lx, hy - ly) / 4096.0, 1e-12)
    while (int((hx - lx) / h) + 1) * (int((hy - ly) / h) + 1) > MAX_GRID_CELLS:
        h *= 2.0
    nx = int((hx - lx) / h) + 1
    ny = int((hy - ly) / h) + 1
    cell_start = np.zeros(nx * ny + 1, np.int64)
    _segment_cells(vert, lx, ly, h, nx, ny, cell_start, cell_start[:0], False)
    for c in range(nx * ny):
        cell_start[c + 1] += cell_start[c]
    cell_seg = np.empty(cell_start[nx * ny], np.int64)
    _segment_cells(vert, lx, ly, h, nx, ny, cell_start, cell_seg, True)
    return lx, ly, h, nx, ny, cell_start, cell_seg


@njit(inline="always", cache=True)
def _orient(ax, ay, bx, by, cx, cy):
    v = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    return 1 if v > 0.0 else (-1 if v < 0.0 else 0)


@njit(inline="always", cache=True)
def _on_segment(ax, ay, bx, by, px, py):
    return min(ax, bx) <= px <= max(ax, bx) and min(ay, by) <= py <= max(ay, by)


@njit(cache=True)
def _segments_meet(vert, k, j):
    nv = vert.shape[0]
    k1 = k + 1 if k + 1 < nv else 0
    j1 = j + 1 if j + 1 < nv else 0
    ax, ay, bx, by = vert[k, 0], vert[k, 1], vert[k1, 0], vert[k1, 1]
    cx, cy, dx, dy = vert[j, 0], vert[j, 1], vert[j1, 0], vert[j1, 1]
    o1 = _orient(ax, ay, bx, by, cx, cy)
    o2 = _orient(ax, ay, bx, by, dx, dy)
    o3 = _orient(cx, cy, dx, dy, ax, ay)
    o4 = _orient(cx, cy, dx, dy, bx, by)
    if o1 != o2 and o3 != o4:
        return True
    if o1 == 0 and _on_segment(ax, ay, bx, by, cx, cy):
        return True
    if o2 == 0 and _on_segment(ax, ay, bx, by, dx, dy):
        return True
    if o3 == 0 and _on_segment(cx, cy, dx, dy, ax, ay):
        return True
    if o4 == 0 and _on_segment(cx, cy, dx, dy, bx, by):
        return True
    return False


@njit(cache=True)
def builtin_off(wg):
    """A copy of the wheel's geometry record with the built-in rim and lugs off (the wheel
    given as an outline: its body_rows then makes the walls' and plates' rows only)."""
    g = wg.copy()
    g[0].enabled = 0.0
    return g
