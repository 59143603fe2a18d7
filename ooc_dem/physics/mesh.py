"""A wheel surface given as triangles (3D; numba kernels and their numpy set-up, no I/O):
the uniform grid over the triangles in the wheel's body frame (``mesh_wheel``), the
closest point of a triangle to a point (``closest_on_triangle``) and a sphere's contacts
with the mesh, one per part (``mesh_contact``).

A part is a connected piece of the surface (``surface_parts``: triangles sharing a
vertex), as a CAD export gives a wheel's rim and each of its grousers. One contact per
(sphere, part): the closest point over the part's triangles within the sphere's reach,
ties to the lowest triangle index. Two coplanar triangles sharing an edge then give a
sphere sliding across that edge the same distance and normal on both sides (no jump, no
double contact), an edge or a vertex gives the rounded normal (from the closest point to
the centre), and the contact's history is the part's (one partner id a part), so it
survives a sphere's passage from one triangle to the next. A grain wedged between a
grouser and the rim touches two parts and feels both, as on the built-in wheel; a sphere
touching two non-coplanar faces of one part at once (a concave corner of one piece)
feels the nearer only.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .layout import MeshWheel

MAX_GRID_CELLS = 4_000_000  # the grid's cells at most (the cell grows beyond that)


def surface_parts(tri: np.ndarray) -> np.ndarray:
    """Each triangle's part (T,): the connected pieces of the surface, triangles joined by
    a shared vertex (vertices equal in all three coordinates), numbered 0, 1, ... in the
    order of their first triangle. Labels spread by minimum over each triangle's vertices
    and are shortcut (pointer jumping) until nothing changes."""
    tri = np.ascontiguousarray(tri, np.float64)
    if len(tri) == 0:
        return np.zeros(0, np.int64)
    _, vid = np.unique(tri.reshape(-1, 3), axis=0, return_inverse=True)
    vid = vid.reshape(-1, 3)
    label = np.arange(int(vid.max()) + 1)
    while True:
        new = label.copy()
        np.minimum.at(new, vid.ravel(), np.repeat(label[vid].min(axis=1), 3))
        while True:  # every vertex to its label's label, until each points at a root
            jumped = new[new]
            if np.array_equal(jumped, new):
                break
            new = jumped
        if np.array_equal(new, label):
            break
        label = new
    of_tri = label[vid[:, 0]]
    roots, first, inverse = np.unique(of_tri, return_index=True, return_inverse=True)
    rank = np.empty(len(roots), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(roots))
    return rank[inverse.ravel()]


def mesh_wheel(tri: np.ndarray, cell: float, part: np.ndarray | None = None) -> MeshWheel:
    """The kernel's mesh of triangles tri (T, 3, 3) in the body frame with a grid of
    cubic cells of side ``cell`` (about the largest sphere's diameter; larger when that
    would make more than MAX_GRID_CELLS cells), and each triangle's part (default
    ``surface_parts``). Each triangle is listed in every cell its bounding box overlaps,
    so a sphere whose box overlaps none of a triangle's cells cannot touch it."""
    tri = np.ascontiguousarray(tri, np.float64)
    part = surface_parts(tri) if part is None else np.ascontiguousarray(part, np.int64)
    lo = tri.reshape(-1, 3).min(axis=0)
    hi = tri.reshape(-1, 3).max(axis=0)
    ext = np.maximum(hi - lo, 0.0)
    h = float(cell)
    while np.prod(np.floor(ext / h) + 1.0) > MAX_GRID_CELLS:
        h *= 1.5
    dims = (np.floor(ext / h) + 1).astype(np.int64)
    tlo = np.clip(np.floor((tri.min(axis=1) - lo) / h).astype(np.int64), 0, dims - 1)
    thi = np.clip(np.floor((tri.max(axis=1) - lo) / h).astype(np.int64), 0, dims - 1)
    span = thi - tlo + 1  # (T, 3) cells along each axis
    per = span[:, 0] * span[:, 1] * span[:, 2]
    first = np.concatenate(([0], np.cumsum(per)[:-1]))
    owner = np.repeat(np.arange(len(tri), dtype=np.int64), per)
    k = np.arange(int(per.sum()), dtype=np.int64) - np.repeat(first, per)
    sx = span[owner, 0]
    sy = span[owner, 1]
    ix = tlo[owner, 0] + k % sx
    iy = tlo[owner, 1] + (k // sx) % sy
    iz = tlo[owner, 2] + k // (sx * sy)
    cell_of = (iz * dims[1] + iy) * dims[0] + ix
    order = np.argsort(cell_of, kind="stable")  # within a cell: ascending triangle index
    ncell = int(np.prod(dims))
    cell_start = np.zeros(ncell + 1, np.int64)
    cell_start[1:] = np.cumsum(np.bincount(cell_of, minlength=ncell))
    rho = np.sqrt(tri[:, :, 0] ** 2 + tri[:, :, 1] ** 2)
    bounds = np.array([rho.max(), lo[2], hi[2]])
    return MeshWheel(tri, np.array([lo[0], lo[1], lo[2], h]), dims, cell_start, owner[order].copy(), bounds, part)


@njit(inline="always", cache=True)
def closest_on_triangle(px, py, pz, t):
    """The point of triangle t ((3, 3) vertices a, b, c) closest to p, by the region of
    the triangle p projects into: a vertex, an edge or the face (Ericson, Real-Time
    Collision Detection, 5.1.5, ClosestPtPointTriangle; the face's point by projection)."""
    ax, ay, az = t[0, 0], t[0, 1], t[0, 2]
    bx, by, bz = t[1, 0], t[1, 1], t[1, 2]
    cx, cy, cz = t[2, 0], t[2, 1], t[2, 2]
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz)
    # the face: p moved onto the plane along its unit normal (rather than Ericson's
    # barycentric sum): a plane normal to an axis then gives q and the normal exactly, the
    # bits of an analytic wall there
    nx = aby * acz - abz * acy
    ny = abz * acx - abx * acz
    nz = abx * acy - aby * acx
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    if nn == 0.0:  # a degenerate triangle (a line or a point): its vertex a
        return ax, ay, az
    ux = nx / nn
    uy = ny / nn
    uz = nz / nn
    h = apx * ux + apy * uy + apz * uz
    return px - h * ux, py - h * uy, pz - h * uz


@njit(inline="always", cache=True)
def _cell_index(x, lo, h, n):
    """The grid cell along one axis holding coordinate x, clamped to the grid."""
    k = math.floor((x - lo) / h)
    if k < 0:
        return 0
    if k > n - 1:
        return n - 1
    return int(k)


@njit(cache=True)
def mesh_contact(mesh, px, py, pz, r, after):
    """A sphere's contact with the lowest part above ``after`` (-1: any) that has a
    triangle within r (centre p in the body frame, radius r): the closest point q over
    that part's triangles within r (ties: the lowest triangle index), as (found, part, qx,
    qy, qz, distance, more); found is False when no such part has a triangle within r or
    the centre lies on its surface (no normal); more: a higher part has a triangle within
    r too (call again with after = part). Only the triangles of the grid cells the
    sphere's box overlaps are tested."""
    g = mesh.grid
    lo_x, lo_y, lo_z, h = g[0], g[1], g[2], g[3]
    nx, ny, nz = mesh.dims[0], mesh.dims[1], mesh.dims[2]
    if px + r < lo_x or py + r < lo_y or pz + r < lo_z:
        return False, -1, 0.0, 0.0, 0.0, 0.0, False
    if px - r > lo_x + nx * h or py - r > lo_y + ny * h or pz - r > lo_z + nz * h:
        return False, -1, 0.0, 0.0, 0.0, 0.0, False
    i0 = _cell_index(px - r, lo_x, h, nx)
    i1 = _cell_index(px + r, lo_x, h, nx)
    j0 = _cell_index(py - r, lo_y, h, ny)
    j1 = _cell_index(py + r, lo_y, h, ny)
    k0 = _cell_index(pz - r, lo_z, h, nz)
    k1 = _cell_index(pz + r, lo_z, h, nz)
    reach = r * r
    best = reach
    best_t = -1
    best_part = -1
    more = False
    bqx = bqy = bqz = 0.0
    tri, start, cell_tri, part_of = mesh.tri, mesh.cell_start, mesh.cell_tri, mesh.part
    for k in range(k0, k1 + 1):
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                c = (k * ny + j) * nx + i
                for at in range(start[c], start[c + 1]):
                    t = cell_tri[at]
                    pt = part_of[t]
                    if pt <= after or (best_part >= 0 and pt > best_part and more):
                        continue
                    qx, qy, qz = closest_on_triangle(px, py, pz, tri[t])
                    ex = px - qx
                    ey = py - qy
                    ez = pz - qz
                    e2 = ex * ex + ey * ey + ez * ez
                    if e2 >= reach:
                        continue
                    if best_part < 0 or pt < best_part:  # a lower part: it is the one
                        if best_part >= 0:
                            more = True
                        best_part = pt
                        best = e2
                        best_t = t
                        bqx, bqy, bqz = qx, qy, qz
                    elif pt > best_part:
                        more = True
                    elif e2 < best or (e2 == best and t < best_t):
                        best = e2
                        best_t = t
                        bqx, bqy, bqz = qx, qy, qz
    if best_t < 0 or best == 0.0:
        return False, best_part, 0.0, 0.0, 0.0, 0.0, more
    return True, best_part, bqx, bqy, bqz, math.sqrt(best), more
