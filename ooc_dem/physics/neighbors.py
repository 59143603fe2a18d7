"""Cell lists and the half Verlet pair list with its per-disc CSR index (numba, no I/O).

The pair list holds every pair of discs within r_i + r_j + skin ONCE, stored with
its lower global id ``a``: disc a's pairs are ``pair_b[half_off[a]:half_off[a + 1]]``
sorted by global id (the pair's row slot is its position; ``pair_a`` the lower disc
of each slot). The CSR index ``inc_k[inc_off[b]:inc_off[b + 1]]`` lists, for each
disc b, the slots of its pairs with lower-id partners, sorted by the partner's id
(Nishiura & Sakaguchi 2011's per-particle pair-index table).
Both are sized from the bed (counted, then filled), never by a fixed cap.

The list is a superset of the contacts until some disc has moved more than skin/2,
so *when* it is rebuilt never changes a result: forces only see real overlaps,
summed in partner-id order.
"""
import numpy as np
from numba import njit, prange

from .layout import AX_X, AX_Y


@njit(inline="always", cache=True)
def _sort_by_gid(idx, lo, hi, gid):
    """Insertion sort of idx[lo:hi] by global id (a disc's lists are short): partners in
    ascending id are the sum order of the determinism contract."""
    for a in range(lo + 1, hi):
        v = idx[a]
        gv = gid[v]
        b = a - 1
        while b >= lo and gid[idx[b]] > gv:
            idx[b + 1] = idx[b]
            b -= 1
        idx[b + 1] = v


@njit(cache=True)
def spatial_order(pos, n, cell):
    """Permutation that sorts discs by (cell column, cell row): keeps neighbours close in memory.
    pos: (N, 2) positions."""
    if n == 0:
        return np.empty(0, np.int64)
    xmin = pos[:n, AX_X].min()
    ymin = pos[:n, AX_Y].min()
    keys = np.empty(n, np.int64)
    for i in range(n):
        cx = int((pos[i, AX_X] - xmin) / cell)
        cy = int((pos[i, AX_Y] - ymin) / cell)
        keys[i] = cx * 1_000_000 + min(cy, 999_999)
    return np.argsort(keys, kind="mergesort")


@njit(inline="always", cache=True)
def _cell_xy(pos, i, x0, y0, cell, ncx, ncy):
    """Disc i's cell (column, row), clipped to the grid."""
    cx = int((pos[i, AX_X] - x0) / cell)
    cy = int((pos[i, AX_Y] - y0) / cell)
    return min(max(cx, 0), ncx - 1), min(max(cy, 0), ncy - 1)


@njit(cache=True)
def _bin(pos, n, x0, y0, cell, ncx, ncy, cell_start, cell_list):
    """Counting sort of the discs by cell, ascending index within a cell. cell_start
    serves as the counts, then as each cell's fill cursor, then is shifted back to the
    cells' starts (no second array of the grid's size: a neighbour build's temporaries
    are the peak of a large monolithic run's memory)."""
    cell_start[:] = 0
    for i in range(n):
        cx, cy = _cell_xy(pos, i, x0, y0, cell, ncx, ncy)
        cell_start[cy * ncx + cx + 1] += 1
    for c in range(ncx * ncy):
        cell_start[c + 1] += cell_start[c]
    for i in range(n):
        cx, cy = _cell_xy(pos, i, x0, y0, cell, ncx, ncy)
        c = cy * ncx + cx
        cell_list[cell_start[c]] = i
        cell_start[c] += 1
    # cell_start[c] is now the end of cell c, i.e. the start of cell c + 1
    for c in range(ncx * ncy, 0, -1):
        cell_start[c] = cell_start[c - 1]
    cell_start[0] = 0


# discs a chunk of the scan runs through with one pair of candidate buffers
SCAN_CHUNK = 256


@njit(inline="always", cache=True)
def fullest_cell(cell_start, ncells):
    """The most particles any one cell holds (2D and 3D scans size their buffers by it)."""
    fullest = 0
    for c in range(ncells):
        fullest = max(fullest, cell_start[c + 1] - cell_start[c])
    return fullest


@njit(inline="always", cache=True)
def _put_partners(i, nu, nl, higher, lower, half_off, pair_b, inc_off, inc, gid, fill):
    """A scan's result for particle i (2D and 3D): its partner counts (fill False), or its
    nu higher-id and nl lower-id partners from the candidate buffers at its offsets,
    sorted by id (fill True)."""
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
def _scan(pos, r, gid, n, x0, y0, cell, ncx, ncy, cell_start, cell_list, skin,
          half_off, pair_b, inc_off, inc, fill, room):
    """fill False: count each disc's partners with higher / lower ids into
    half_off[i + 1] / inc_off[i + 1]. fill True: write them at the offsets, sorted by id.

    Branch-free: every disc of the 3 x 3 cells is written to both candidate buffers
    and each buffer's length grows by one only for a partner of its kind (within the
    cut-off; higher / lower id). Whether a candidate is a partner is a
    coin toss for the branch predictor (about 4 in 11 are, half of them of each kind),
    and the branchy scan spent most of its time on mispredictions (paper2008: 386 us
    a counting pass on 2 threads). room: the candidate buffers' length, 9 times the
    fullest cell (a disc's candidates are the discs of 9 cells)."""
    for ch in prange((n + SCAN_CHUNK - 1) // SCAN_CHUNK):
        higher = np.empty(room, np.int32)
        lower = np.empty(room, np.int32)
        for i in range(ch * SCAN_CHUNK, min(n, (ch + 1) * SCAN_CHUNK)):
            cx, cy = _cell_xy(pos, i, x0, y0, cell, ncx, ncy)
            nu = 0
            nl = 0
            xi = pos[i, AX_X]
            yi = pos[i, AX_Y]
            ri = r[i]
            gi = gid[i]
            xlo = max(cx - 1, 0)
            xhi = min(cx + 1, ncx - 1)
            for yy in range(max(cy - 1, 0), min(cy + 2, ncy)):
                # a row's three cells are adjacent in the cell order: one run of discs
                for q in range(cell_start[yy * ncx + xlo], cell_start[yy * ncx + xhi + 1]):
                    j = cell_list[q]
                    dx = pos[j, AX_X] - xi
                    dy = pos[j, AX_Y] - yi
                    cut = ri + r[j] + skin
                    # i itself is near but neither higher nor lower (ids are unique)
                    near = dx * dx + dy * dy < cut * cut
                    higher[nu] = j
                    lower[nl] = j
                    nu += near & (gid[j] > gi)
                    nl += near & (gid[j] < gi)
            _put_partners(i, nu, nl, higher, lower, half_off, pair_b, inc_off, inc, gid, fill)


@njit(parallel=True, cache=True)
def _slots(n, half_off, pair_b, pair_a, inc_off, inc_k):
    """pair_a[k] = the lower disc of slot k; inc_k: each lower partner a of disc b
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


@njit(cache=True)
def build_pairs(pos, r, gid, n, skin, half_off, pair_b, pair_a, inc_off, inc_k, ref):
    """Rebuild the half pair list and CSR index of discs 0..n-1 (positions pos (N, 2)) and
    remember the build positions in ref (N, 2). Returns the number of pairs P; when P exceeds the capacity of
    pair_b / pair_a / inc_k nothing is filled (grow them to at least P and call again)."""
    half_off[0] = 0
    inc_off[0] = 0
    if n == 0:
        return 0
    rmax = r[:n].max()
    cell = 2.0 * rmax + skin
    x0 = pos[:n, AX_X].min()
    y0 = pos[:n, AX_Y].min()
    ncx = int((pos[:n, AX_X].max() - x0) / cell) + 1
    ncy = int((pos[:n, AX_Y].max() - y0) / cell) + 1
    # keep the grid bounded for discs that fly far away: the last row/column
    # collects them, which is still exact (distances are checked)
    if ncx * ncy > 4 * n + 64:
        ncy = max(1, (4 * n + 64) // ncx)
    # int32: a domain's disc count (RAM bounds it far below 2**31)
    cell_start = np.zeros(ncx * ncy + 1, np.int32)
    cell_list = np.empty(n, np.int32)
    _bin(pos, n, x0, y0, cell, ncx, ncy, cell_start, cell_list)
    room = 9 * fullest_cell(cell_start, ncx * ncy)   # both passes' candidate buffers
    _scan(pos, r, gid, n, x0, y0, cell, ncx, ncy, cell_start, cell_list, skin,
          half_off, pair_b, inc_off, inc_k, False, room)
    for i in range(n):
        half_off[i + 1] += half_off[i]
        inc_off[i + 1] += inc_off[i]
    npairs = half_off[n]
    if npairs > pair_b.shape[0] or npairs > inc_k.shape[0]:
        return npairs
    _scan(pos, r, gid, n, x0, y0, cell, ncx, ncy, cell_start, cell_list, skin,
          half_off, pair_b, inc_off, inc_k, True, room)
    _slots(n, half_off, pair_b, pair_a, inc_off, inc_k)
    for i in range(n):
        ref[i, AX_X] = pos[i, AX_X]
        ref[i, AX_Y] = pos[i, AX_Y]
    return npairs


# serial twins (physics.twins): the pair-list build of one sub-domain on one thread
from .twins import serial_twin  # noqa: E402

_scan_serial = serial_twin(_scan, "_scan_serial")
_slots_serial = serial_twin(_slots, "_slots_serial")
build_pairs_serial = serial_twin(build_pairs, "build_pairs_serial", _scan=_scan_serial,
                                 _slots=_slots_serial)
