"""3D cell lists and the half Verlet pair list with its per-sphere CSR index
(numba, no I/O); the 3D twin of ``ooc_dem.physics.neighbors``.

The pair list holds every pair of spheres within r_i + r_j + skin ONCE, stored with
its lower global id ``a``: sphere a's pairs are ``pair_b[half_off[a]:half_off[a + 1]]``
sorted by global id (a pair's row slot is its position; ``pair_a`` the lower sphere of
each slot). ``inc_k[inc_off[b]:inc_off[b + 1]]`` lists, for each sphere b, the slots of
its pairs with lower-id partners, sorted by the partner's id. Both are sized by
counting (count, prefix sum, fill), never by a fixed cap; the scans run in parallel
over spheres and each sphere writes only its own range, so the result does not
depend on the thread count or on the memory order of the spheres (partners are
sorted by global id, the set of pairs is exact: distances are checked).
"""
import numpy as np
from numba import njit, prange
from ..layout import AX_X, AX_Y, AX_Z
from ..neighbors import SCAN_CHUNK, _put_partners, _slots, fullest_cell  # the same in 2D and 3D


@njit(cache=True)
def spatial_order(pos, n, cell):
    """Permutation sorting spheres by cell (x column, then y, then z): keeps neighbours
    close in memory (slabs run along x)."""
    if n == 0:
        return np.empty(0, np.int64)
    x0 = pos[:n, 0].min()
    y0 = pos[:n, 1].min()
    z0 = pos[:n, 2].min()
    keys = np.empty(n, np.int64)
    for i in range(n):
        cx = min(int((pos[i, 0] - x0) / cell), 999_999)
        cy = min(int((pos[i, 1] - y0) / cell), 999_999)
        cz = min(int((pos[i, 2] - z0) / cell), 999_999)
        keys[i] = (cx * 1_000_000 + cy) * 1_000_000 + cz
    return np.argsort(keys, kind="mergesort")


@njit(cache=True)
def _grid(pos, n, cutoff):
    """Cell size >= cutoff and cell counts, enlarged so the grid has at most ~8 n + 64
    cells (spheres flying far away; still exact, distances are checked)."""
    lo = np.empty(3)
    ext = np.empty(3)
    for k in range(3):
        lo[k] = pos[:n, k].min()
        ext[k] = pos[:n, k].max() - lo[k]
    cell = cutoff
    limit = 8 * n + 64
    while True:
        ncx = int(ext[0] / cell) + 1
        ncy = int(ext[1] / cell) + 1
        ncz = int(ext[2] / cell) + 1
        if ncx * ncy * ncz <= limit:
            return lo, cell, ncx, ncy, ncz
        cell *= 1.25


@njit(inline="always", cache=True)
def _cell_xyz(pos, i, lo, cell, ncx, ncy, ncz):
    """Sphere i's cell (x, y, z indices), clipped to the grid."""
    cx = min(max(int((pos[i, AX_X] - lo[AX_X]) / cell), 0), ncx - 1)
    cy = min(max(int((pos[i, AX_Y] - lo[AX_Y]) / cell), 0), ncy - 1)
    cz = min(max(int((pos[i, AX_Z] - lo[AX_Z]) / cell), 0), ncz - 1)
    return cx, cy, cz


@njit(cache=True)
def _bin(pos, n, lo, cell, ncx, ncy, ncz, cell_start, cell_list):
    """Counting sort of the spheres by cell, ascending index within a cell; cell_start
    serves as counts, fill cursors, then starts (as the 2D _bin: no second grid-sized
    array)."""
    cell_start[:] = 0
    for i in range(n):
        cx, cy, cz = _cell_xyz(pos, i, lo, cell, ncx, ncy, ncz)
        cell_start[(cz * ncy + cy) * ncx + cx + 1] += 1
    ncell = ncx * ncy * ncz
    for c in range(ncell):
        cell_start[c + 1] += cell_start[c]
    for i in range(n):
        cx, cy, cz = _cell_xyz(pos, i, lo, cell, ncx, ncy, ncz)
        c = (cz * ncy + cy) * ncx + cx
        cell_list[cell_start[c]] = i
        cell_start[c] += 1
    for c in range(ncell, 0, -1):   # each cursor ends at the next cell's start
        cell_start[c] = cell_start[c - 1]
    cell_start[0] = 0


@njit(parallel=True, cache=True)
def _scan(pos, r, gid, n, lo, cell, ncx, ncy, ncz, cell_start, cell_list, skin,
          half_off, pair_b, inc_off, inc, fill, room):
    """fill False: count each sphere's partners with higher / lower ids into
    half_off[i + 1] / inc_off[i + 1]. fill True: write them at the offsets, sorted by id.
    Branch-free over the candidates, one run of spheres per row of three cells (as the 2D
    scan, physics.neighbors._scan, says why). room: the candidate buffers' length, 27 times
    the fullest cell (a sphere's candidates are the spheres of 27 cells)."""
    for ch in prange((n + SCAN_CHUNK - 1) // SCAN_CHUNK):
        higher = np.empty(room, np.int32)
        lower = np.empty(room, np.int32)
        for i in range(ch * SCAN_CHUNK, min(n, (ch + 1) * SCAN_CHUNK)):
            cx, cy, cz = _cell_xyz(pos, i, lo, cell, ncx, ncy, ncz)
            nu = 0
            nl = 0
            xi = pos[i, 0]
            yi = pos[i, 1]
            zi = pos[i, 2]
            ri = r[i]
            gi = gid[i]
            xlo = max(cx - 1, 0)
            xhi = min(cx + 1, ncx - 1)
            for zz in range(max(cz - 1, 0), min(cz + 2, ncz)):
                for yy in range(max(cy - 1, 0), min(cy + 2, ncy)):
                    row = (zz * ncy + yy) * ncx
                    for q in range(cell_start[row + xlo], cell_start[row + xhi + 1]):
                        j = cell_list[q]
                        dx = pos[j, 0] - xi
                        dy = pos[j, 1] - yi
                        dz = pos[j, 2] - zi
                        cut = ri + r[j] + skin
                        # i itself is near but neither higher nor lower (ids are unique)
                        near = dx * dx + dy * dy + dz * dz < cut * cut
                        higher[nu] = j
                        lower[nl] = j
                        nu += near & (gid[j] > gi)
                        nl += near & (gid[j] < gi)
            _put_partners(i, nu, nl, higher, lower, half_off, pair_b, inc_off, inc, gid, fill)


@njit(cache=True)
def build_pairs(pos, r, gid, n, skin, half_off, pair_b, pair_a, inc_off, inc_k, pref):
    """Rebuild the half pair list and CSR index of spheres 0..n-1 and remember the build
    positions in pref. Returns the number of pairs P; when P exceeds the capacity of
    pair_b / pair_a / inc_k nothing is filled (grow them to at least P, call again)."""
    half_off[0] = 0
    inc_off[0] = 0
    if n == 0:
        return 0
    lo, cell, ncx, ncy, ncz = _grid(pos, n, 2.0 * r[:n].max() + skin)
    # int32: a domain's sphere count (RAM bounds it far below 2**31)
    cell_start = np.zeros(ncx * ncy * ncz + 1, np.int32)
    cell_list = np.empty(n, np.int32)
    _bin(pos, n, lo, cell, ncx, ncy, ncz, cell_start, cell_list)
    room = 27 * fullest_cell(cell_start, ncx * ncy * ncz)   # both passes' candidate buffers
    _scan(pos, r, gid, n, lo, cell, ncx, ncy, ncz, cell_start, cell_list, skin,
          half_off, pair_b, inc_off, inc_k, False, room)
    for i in range(n):
        half_off[i + 1] += half_off[i]
        inc_off[i + 1] += inc_off[i]
    npairs = half_off[n]
    if npairs > pair_b.shape[0] or npairs > inc_k.shape[0] or npairs > pair_a.shape[0]:
        return npairs
    _scan(pos, r, gid, n, lo, cell, ncx, ncy, ncz, cell_start, cell_list, skin,
          half_off, pair_b, inc_off, inc_k, True, room)
    _slots(n, half_off, pair_b, pair_a, inc_off, inc_k)
    for i in range(n):
        pref[i, 0] = pos[i, 0]
        pref[i, 1] = pos[i, 1]
        pref[i, 2] = pos[i, 2]
    return npairs


# the one-thread twin (physics.twins): serial DDM runs its sub-domains side by side
from ..neighbors import _slots_serial  # noqa: E402
from ..twins import serial_twin  # noqa: E402

_scan_serial = serial_twin(_scan, "_scan_serial")
build_pairs_serial = serial_twin(build_pairs, "build_pairs_serial", _scan=_scan_serial,
                                 _slots=_slots_serial)
