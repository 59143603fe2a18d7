"""Cell lists and the half Verlet pair list with its per-particle CSR index (numba, no I/O;
written once, compiled per dimension by ``instantiate``).

The pair list holds every pair of particles within r_i + r_j + skin ONCE, stored with
its lower global id ``a``: particle a's pairs are ``pair_b[half_off[a]:half_off[a + 1]]``
sorted by global id (the pair's row slot is its position; ``pair_a`` the lower particle
of each slot). The CSR index ``inc_k[inc_off[b]:inc_off[b + 1]]`` lists, for each
particle b, the slots of its pairs with lower-id partners, sorted by the partner's id
(Nishiura & Sakaguchi 2011's per-particle pair-index table). Both are sized by counting
(count, prefix sum, fill), never by a fixed cap; the scans run in parallel over
particles and each particle writes only its own range, so the result does not depend on
the thread count, on the memory order of the particles or on the grid (partners are
sorted by global id, the set of pairs is exact: distances are checked).

The list is a superset of the contacts until some particle has moved more than skin/2,
so *when* it is rebuilt never changes a result: forces only see real overlaps, summed
in partner-id order.

The grid has three axes in every dimension (a 2D grid is one cell deep in z); a
dimension gives its cell of a particle and its memory-order key (``Slot``s below).
"""

import sys
from types import SimpleNamespace

import numpy as np
from numba import njit, prange

from .axes import DIM, vec
from .layout import AX_X
from .twins import slot, bindings, no_parfors, serial_twin, slots_of, specialise

# ----------------------------------------------- what each dimension binds (its geometry)
cell_of = slot(
    "cell_of(pos, i, lo, cell, ncx, ncy, ncz): particle i's cell (cx, cy, cz), clipped to the grid (cz = 0 in 2D)"
)
order_key = slot(
    "order_key(pos, i, lo, cell): the int64 key of particle i's cell in the "
    "memory order (lo: the lowest coordinate of each axis)"
)
GRID_CELLS = slot("GRID_CELLS: a grid of n particles has at most GRID_CELLS n + 64 cells")

# particles a chunk of the scan runs through with one pair of candidate buffers
SCAN_CHUNK = 256


@njit(inline="always", cache=True)
def _sort_by_gid(idx, lo, hi, gid):
    """Insertion sort of idx[lo:hi] by global id (a particle's lists are short): partners
    in ascending id are the sum order of the determinism contract."""
    for a in range(lo + 1, hi):
        v = idx[a]
        gv = gid[v]
        b = a - 1
        while b >= lo and gid[idx[b]] > gv:
            idx[b + 1] = idx[b]
            b -= 1
        idx[b + 1] = v


@njit(inline="always", cache=True)
def fullest_cell(cell_start, ncells):
    """The most particles any one cell holds (the scans size their buffers by it)."""
    fullest = 0
    for c in range(ncells):
        fullest = max(fullest, cell_start[c + 1] - cell_start[c])
    return fullest


@njit(inline="always", cache=True)
def _put_partners(i, nu, nl, higher, lower, half_off, pair_b, inc_off, inc, gid, fill):
    """A scan's result for particle i: its partner counts (fill False), or its nu
    higher-id and nl lower-id partners from the candidate buffers at its offsets, sorted
    by id (fill True)."""
    if not fill:
        half_off[i + 1] = nu
        inc_off[i + 1] = nl
        return
    u0 = half_off[i]
    l0 = inc_off[i]
    for k in range(nu):
        pair_b[u0 + k] = higher[k]
    for k in range(nl):
        inc[l0 + k] = lower[k]
    _sort_by_gid(pair_b, u0, u0 + nu, gid)
    _sort_by_gid(inc, l0, l0 + nl, gid)


@njit(parallel=True, cache=True)
def pair_slots(n, half_off, pair_b, pair_a, inc_off, inc_k):
    """pair_a[k] = the lower particle of slot k; inc_k: each lower partner a of particle b
    replaced by the slot of the pair (a, b) in a's half list."""
    for i in prange(n):
        for q in range(half_off[i], half_off[i + 1]):
            pair_a[q] = i
        for e in range(inc_off[i], inc_off[i + 1]):
            a = inc_k[e]
            q = half_off[a]
            while pair_b[q] != i:
                q += 1
            inc_k[e] = q


pair_slots_serial = serial_twin(pair_slots, "pair_slots_serial")


# ------------------------------------------------------------------ templates
def spatial_order(pos, n, cell):
    """Permutation that sorts particles by cell (the dimension's ``order_key``: x column
    first, slabs run along x): keeps neighbours close in memory."""
    if n == 0:
        return np.empty(0, np.int64)
    lo = np.empty(DIM)
    for a in range(DIM):
        lo[a] = pos[:n, a].min()
    keys = np.empty(n, np.int64)
    for i in range(n):
        keys[i] = order_key(pos, i, lo, cell)
    return np.argsort(keys, kind="mergesort")


def grid(pos, n, cutoff):
    """(lo, cell, ncx, ncy, ncz): the lowest coordinates, a cell size >= cutoff and the
    cell counts, the cell enlarged so that the grid has at most GRID_CELLS n + 64 cells
    (particles flying far away; still exact, distances are checked). Axes past DIM have
    one cell."""
    lo = np.zeros(3)
    ext = np.zeros(3)
    for a in range(DIM):
        lo[a] = pos[:n, a].min()
        ext[a] = pos[:n, a].max() - lo[a]
    cell = cutoff
    limit = GRID_CELLS * n + 64
    while True:
        ncx = int(ext[0] / cell) + 1
        ncy = int(ext[1] / cell) + 1
        ncz = int(ext[2] / cell) + 1
        if ncx * ncy * ncz <= limit:
            return lo, cell, ncx, ncy, ncz
        cell *= 1.25


def bin_cells(pos, n, lo, cell, ncx, ncy, ncz, cell_start, cell_list):
    """Counting sort of the particles by cell, ascending index within a cell. cell_start
    serves as the counts, then as each cell's fill cursor, then is shifted back to the
    cells' starts (no second array of the grid's size: a neighbour build's temporaries
    are the peak of a large monolithic run's memory)."""
    cell_start[:] = 0
    for i in range(n):
        cx, cy, cz = cell_of(pos, i, lo, cell, ncx, ncy, ncz)
        cell_start[(cz * ncy + cy) * ncx + cx + 1] += 1
    ncell = ncx * ncy * ncz
    for c in range(ncell):
        cell_start[c + 1] += cell_start[c]
    for i in range(n):
        cx, cy, cz = cell_of(pos, i, lo, cell, ncx, ncy, ncz)
        c = (cz * ncy + cy) * ncx + cx
        cell_list[cell_start[c]] = i
        cell_start[c] += 1
    # cell_start[c] is now the end of cell c, i.e. the start of cell c + 1
    for c in range(ncell, 0, -1):
        cell_start[c] = cell_start[c - 1]
    cell_start[0] = 0


def scan(
    pos, r, gid, n, lo, cell, ncx, ncy, ncz, cell_start, cell_list, skin, half_off, pair_b, inc_off, inc, fill, room
):
    """fill False: count each particle's partners with higher / lower ids into
    half_off[i + 1] / inc_off[i + 1]. fill True: write them at the offsets, sorted by id.

    Branch-free: every particle of the neighbouring cells is written to both candidate
    buffers and each buffer's length grows by one only for a partner of its kind (within
    the cut-off; higher / lower id). Whether a candidate is a partner is a coin toss for
    the branch predictor (about 4 in 11 are in 2D, half of them of each kind), and the
    branchy scan spent most of its time on mispredictions (paper2008: 386 us a counting
    pass on 2 threads). A row of three cells along x is one run of particles in the cell
    order. room: the candidate buffers' length, 3^D times the fullest cell."""
    for ch in prange((n + SCAN_CHUNK - 1) // SCAN_CHUNK):
        higher = np.empty(room, np.int32)
        lower = np.empty(room, np.int32)
        for i in range(ch * SCAN_CHUNK, min(n, (ch + 1) * SCAN_CHUNK)):
            cx, cy, cz = cell_of(pos, i, lo, cell, ncx, ncy, ncz)
            nu = 0
            nl = 0
            p = vec(pos[i])
            ri = r[i]
            gi = gid[i]
            xlo = max(cx - 1, 0)
            xhi = min(cx + 1, ncx - 1)
            for zz in range(max(cz - 1, 0), min(cz + 2, ncz)):
                for yy in range(max(cy - 1, 0), min(cy + 2, ncy)):
                    row = (zz * ncy + yy) * ncx
                    for q in range(cell_start[row + xlo], cell_start[row + xhi + 1]):
                        j = cell_list[q]
                        e = pos[j, AX_X] - p[AX_X]
                        d2 = e * e
                        for a in range(AX_X + 1, DIM):
                            e = pos[j, a] - p[a]
                            d2 += e * e
                        cut = ri + r[j] + skin
                        # i itself is near but neither higher nor lower (ids are unique)
                        near = d2 < cut * cut
                        higher[nu] = j
                        lower[nl] = j
                        nu += near & (gid[j] > gi)
                        nl += near & (gid[j] < gi)
            _put_partners(i, nu, nl, higher, lower, half_off, pair_b, inc_off, inc, gid, fill)


def build_pairs(pos, r, gid, n, skin, half_off, pair_b, pair_a, inc_off, inc_k, ref):
    """Rebuild the half pair list and CSR index of particles 0..n-1 (positions pos (N, D))
    and remember the build positions in ref (N, D). Returns the number of pairs P; when P
    exceeds the capacity of pair_b / pair_a / inc_k nothing is filled (grow them to at
    least P and call again)."""
    half_off[0] = 0
    inc_off[0] = 0
    if n == 0:
        return 0
    lo, cell, ncx, ncy, ncz = grid(pos, n, 2.0 * r[:n].max() + skin)
    # int32: a domain's particle count (RAM bounds it far below 2**31)
    cell_start = np.zeros(ncx * ncy * ncz + 1, np.int32)
    cell_list = np.empty(n, np.int32)
    bin_cells(pos, n, lo, cell, ncx, ncy, ncz, cell_start, cell_list)
    room = 3**DIM * fullest_cell(cell_start, ncx * ncy * ncz)  # both passes' buffers
    scan(
        pos,
        r,
        gid,
        n,
        lo,
        cell,
        ncx,
        ncy,
        ncz,
        cell_start,
        cell_list,
        skin,
        half_off,
        pair_b,
        inc_off,
        inc_k,
        False,
        room,
    )
    for i in range(n):
        half_off[i + 1] += half_off[i]
        inc_off[i + 1] += inc_off[i]
    npairs = half_off[n]
    if npairs > pair_b.shape[0] or npairs > inc_k.shape[0] or npairs > pair_a.shape[0]:
        return npairs
    scan(
        pos,
        r,
        gid,
        n,
        lo,
        cell,
        ncx,
        ncy,
        ncz,
        cell_start,
        cell_list,
        skin,
        half_off,
        pair_b,
        inc_off,
        inc_k,
        True,
        room,
    )
    pair_slots(n, half_off, pair_b, pair_a, inc_off, inc_k)
    for i in range(n):
        for a in range(DIM):
            ref[i, a] = pos[i, a]
    return npairs


def instantiate(name: str, *modules) -> SimpleNamespace:
    """The neighbour build of one dimension (``name``: 'd2', 'd3'), its geometry bound
    (every Slot of this module, from ``modules``): ``build_pairs``, its one-thread twin
    ``build_pairs_serial`` (serial DDM) and ``spatial_order``."""
    bind = bindings(slots_of(sys.modules[__name__]), *modules)
    # one cell's and one sort's compiled code serves both the parallel and the serial build
    bind["grid"] = specialise(grid, f"grid_{name}", bind)
    bind["bin_cells"] = specialise(bin_cells, f"bin_cells_{name}", bind)
    serial = dict(
        bind, scan=specialise(scan, f"scan_{name}_serial", bind, parallel=no_parfors()), pair_slots=pair_slots_serial
    )
    bind["scan"] = specialise(scan, f"scan_{name}", bind, parallel=True)
    return SimpleNamespace(
        build_pairs=specialise(build_pairs, f"build_pairs_{name}", bind),
        build_pairs_serial=specialise(build_pairs, f"build_pairs_{name}_serial", serial, parallel=no_parfors()),
        spatial_order=specialise(spatial_order, f"spatial_order_{name}", bind),
    )
