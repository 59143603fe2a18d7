"""Rigid plates, the same in both dimensions (numba, no I/O; ``plates_step`` is a template
compiled per dimension by ``physics.step.instantiate``): the plates' bounding box, the
particles' force on each plate summed canonically, the plates' records and motion.

A plate is one ``layout.PLATE`` record of a table (at most ``layout.MAX_PLATES``): a finite,
axis-aligned rigid rectangle (2D: a segment) with one active face, the body of partner id
``layout.ID_PLATE0 + k`` (k its row in the table), material type T_WALL. A particle touches
it when its centre lies in front of the face, closer than its radius (0 < h < r, h the
centre's distance from the plane along the normal), and the centre's projection lies
within the plate's extent (lo <= c <= hi on each other axis, edges included). The edges are
sharp and have no contact of their own: a particle whose centre is beyond an edge feels
nothing from that plate, so plates that make a box must meet or overlap at its corners
(a particle then overlaps a convex edge by at most its radius without a force). The
contact geometry is each dimension's (``d2.bodies``, ``d3.bodies``); the law is the
walls' (the plate moves: the particle's velocity is taken relative to the plate's).

Motion, as the wheel's (``physics.wheel``): at step n the particles see the plates at
x_n; after the gather each plate moves x_(n+1) = x_n + v_(n+1/2) dt (its position along
the normal and its extents along the other axes). A prescribed plate keeps the velocity
the table gives. A force-controlled one (PLATE_FORCE) is along its normal a rigid body of
mass M pushed onto the particles by a constant load F, as the wheel's vertical motion is
under its weight: v_(n+1/2) = v_(n-1/2) + (F - N_n) / M dt along the normal (N_n the
normal force the particles press on it with at step n, no gravity of its own), its normal
speed clamped to vmax when vmax > 0 (a lid let down onto a sample). A rigid body rather
than a servo v = gain (F - N): a servo needs an error F - N = v / gain to move at a
steady speed v, so a dilating sample would be sheared under a force below the target
(the contacts' damping, which the servo reads as part of N, keeps its gain small: the
loop is stable only for gain < 1 / (c + k dt), c and k the damping and stiffness summed
over the plate's contacts); a rigid body moving at a steady speed holds N = F exactly.
Its mass sets how it oscillates on the contacts' springs: about M = n c^2 / (4 k) (n
contacts of stiffness k and damping c) is critically damped, the choice of
``app.shear``.
"""

import numpy as np
from numba import njit

from .chunks import N_CHUNKS
from .layout import ID_PLATE0, PLATE, PLATE_FORCE
from .twins import slot

body_force = slot("body_force(row): a body row's force on its particle as (fx, fy, fz) (2D: fz = 0)")


@njit(inline="always", cache=True)
def other_axes(axis):
    """The two axes of a plate's extent (lo1..hi1, lo2..hi2), in ascending order, for its
    normal axis (2D: the second is z, unused)."""
    if axis == 0:
        return 1, 2
    if axis == 1:
        return 0, 2
    return 0, 1


@njit(inline="always", cache=True)
def axis_velocity(p, axis):
    """A plate's velocity component along an axis."""
    if axis == 0:
        return p.vx
    if axis == 1:
        return p.vy
    return p.vz


@njit(cache=True)
def plates_box(table):
    """The box around every plate of the table, as (x_lo, x_hi, y_lo, y_hi, z_lo, z_hi)
    (none: every lo = +inf > hi = -inf): a particle farther than its radius outside it
    touches no plate. (Scalars: a parallel loop cannot take a tuple of arrays.)"""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for k in range(table.shape[0]):
        p = table[k]
        a = int(p.axis)
        o1, o2 = other_axes(a)
        lo[a] = min(lo[a], p.pos)
        hi[a] = max(hi[a], p.pos)
        lo[o1] = min(lo[o1], p.lo1)
        hi[o1] = max(hi[o1], p.hi1)
        lo[o2] = min(lo[o2], p.lo2)
        hi[o2] = max(hi[o2], p.hi2)
    return lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]


@njit(inline="always", cache=True)
def plate_scene(table):
    """The plates' part of a step's scene (the dimensions' body_rows): the table and the box
    around its plates (``plates_box``)."""
    x_lo, x_hi, y_lo, y_hi, z_lo, z_hi = plates_box(table)
    return table, x_lo, x_hi, y_lo, y_hi, z_lo, z_hi


def plates_step(s, t, gid, bd, pt, dt):
    """Step s's plate records (``layout.PLATE_RECORD`` rows s P .. s P + P - 1: each plate at
    the step's start and the particles' force on it), then the plates' motion (module doc).
    Each plate's force is the sum of its rows' reactions in ascending particle id, whatever
    the particles' memory order (canonical, as the wheel's)."""
    table = pt.table
    n_plates = table.shape[0]
    body, bcount = bd.rows, bd.count
    bcap = body.shape[0] // N_CHUNKS
    total = 0
    for ch in range(N_CHUNKS):
        total += bcount[ch]
    keys = np.empty(total, np.int64)
    which = np.empty(total, np.int64)
    fx = np.empty(total)
    fy = np.empty(total)
    fz = np.empty(total)
    cnt = 0
    for ch in range(N_CHUNKS):
        for at in range(ch * bcap, ch * bcap + bcount[ch]):
            k = body[at].pid - ID_PLATE0
            if k >= 0 and k < n_plates:
                keys[cnt] = gid[body[at].disc]
                which[cnt] = k
                bx, by, bz = body_force(body[at])
                fx[cnt] = bx
                fy[cnt] = by
                fz[cnt] = bz
                cnt += 1
    order = np.argsort(keys[:cnt], kind="mergesort")
    f = np.zeros((n_plates, 3))
    contacts = np.zeros(n_plates, np.int64)
    for o in range(cnt):
        j = order[o]
        k = which[j]
        f[k, 0] -= fx[j]
        f[k, 1] -= fy[j]
        f[k, 2] -= fz[j]
        contacts[k] += 1
    for k in range(n_plates):
        p = table[k]
        a = int(p.axis)
        o1, o2 = other_axes(a)
        normal_load = -f[k, a] * p.side  # how hard the particles press on the face
        if p.mode == PLATE_FORCE:
            vn = axis_velocity(p, a) * p.side + (p.load - normal_load) / p.mass * dt
            if p.vmax > 0.0:
                if vn > p.vmax:
                    vn = p.vmax
                elif vn < -p.vmax:
                    vn = -p.vmax
            if a == 0:
                p.vx = vn * p.side
            elif a == 1:
                p.vy = vn * p.side
            else:
                p.vz = vn * p.side
        r = pt.rec[s * n_plates + k]
        r.t = t
        r.pos = p.pos
        r.lo1 = p.lo1
        r.lo2 = p.lo2
        r.vx = p.vx
        r.vy = p.vy
        r.vz = p.vz
        r.fx = f[k, 0]
        r.fy = f[k, 1]
        r.fz = f[k, 2]
        r.load = normal_load
        r.contacts = contacts[k]
        p.pos += axis_velocity(p, a) * dt
        v1 = axis_velocity(p, o1) * dt
        p.lo1 += v1
        p.hi1 += v1
        v2 = axis_velocity(p, o2) * dt
        p.lo2 += v2
        p.hi2 += v2


def plate(
    axis: int,
    side: float,
    pos: float,
    extent: tuple[float, float],
    extent2: tuple[float, float] = (0.0, 0.0),
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0),
    load: float | None = None,
    mass: float = 0.0,
    vmax: float = 0.0,
) -> np.ndarray:
    """One ``layout.PLATE`` record (a (1,) array): normal axis (AX_X, AX_Y, AX_Z) and side
    (+1: the particles are at larger coordinates than pos), its position along the axis,
    its extent (lo, hi) along the first other axis and extent2 along the second (3D), its
    velocity (vx, vy, vz). load: a constant normal force (N) pushing it onto the particles:
    along its normal the plate is then a rigid body of that mass (kg), its normal speed
    limited to vmax (m/s; 0: none)."""
    if int(axis) not in (0, 1, 2) or side not in (1, -1, 1.0, -1.0):
        raise ValueError(f"plate: axis {axis!r} must be 0, 1 or 2 and side {side!r} +1 or -1")
    (lo1, hi1), (lo2, hi2) = extent, extent2
    if not (lo1 <= hi1 and lo2 <= hi2):
        raise ValueError(f"plate: extents {extent!r}, {extent2!r} must run from low to high")
    p = np.zeros(1, PLATE)
    vx, vy, vz = velocity
    p[0] = (axis, side, pos, lo1, hi1, lo2, hi2, vx, vy, vz, 0.0, 0.0, mass, vmax)
    if load is not None:
        if not (mass > 0.0 and vmax >= 0.0):
            raise ValueError("plate: a force-controlled plate needs a mass > 0 (and vmax >= 0)")
        p[0]["mode"] = PLATE_FORCE
        p[0]["load"] = load
    return p
