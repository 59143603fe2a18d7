"""Cell lists and Verlet neighbour lists (numba, no I/O).

A neighbour list holds, for each disc, every disc within r_i + r_j + skin,
sorted by global id. It is a superset of the contacts until some disc has moved
more than skin/2, so *when* it is rebuilt never changes a result: forces only see
real overlaps, summed in partner-id order.
"""
import math

import numpy as np
from numba import njit, prange


@njit(cache=True)
def spatial_order(x, y, n, cell):
    """Permutation that sorts discs by (cell column, cell row): keeps neighbours close in memory."""
    if n == 0:
        return np.empty(0, np.int64)
    xmin = x[:n].min()
    ymin = y[:n].min()
    keys = np.empty(n, np.int64)
    for i in range(n):
        cx = int((x[i] - xmin) / cell)
        cy = int((y[i] - ymin) / cell)
        keys[i] = cx * 1_000_000 + min(cy, 999_999)
    return np.argsort(keys, kind="mergesort")


@njit(cache=True)
def _bin(x, y, n, x0, y0, cell, ncx, ncy, cell_start, cell_list, cell_of):
    counts = cell_start
    counts[:] = 0
    for i in range(n):
        cx = int((x[i] - x0) / cell)
        cy = int((y[i] - y0) / cell)
        cx = min(max(cx, 0), ncx - 1)
        cy = min(max(cy, 0), ncy - 1)
        c = cy * ncx + cx
        cell_of[i] = c
        counts[c + 1] += 1
    for c in range(ncx * ncy):
        counts[c + 1] += counts[c]
    fill = counts[:-1].copy()
    for i in range(n):
        c = cell_of[i]
        cell_list[fill[c]] = i
        fill[c] += 1


@njit(parallel=True, cache=True)
def _gather(x, y, r, gid, n, ncx, ncy, cell_start, cell_list, cell_of, skin, nbr, nbr_n, err):
    cap = nbr.shape[1]
    for i in prange(n):
        c = cell_of[i]
        cx = c % ncx
        cy = c // ncx
        k = 0
        xi = x[i]
        yi = y[i]
        ri = r[i]
        for oy in range(-1, 2):
            yy = cy + oy
            if yy < 0 or yy >= ncy:
                continue
            for ox in range(-1, 2):
                xx = cx + ox
                if xx < 0 or xx >= ncx:
                    continue
                cc = yy * ncx + xx
                for q in range(cell_start[cc], cell_start[cc + 1]):
                    j = cell_list[q]
                    if j == i:
                        continue
                    dx = x[j] - xi
                    dy = y[j] - yi
                    cut = ri + r[j] + skin
                    if dx * dx + dy * dy < cut * cut:
                        if k >= cap:
                            err[1] = 1
                            break
                        nbr[i, k] = np.int32(j)
                        k += 1
        # insertion sort by global id (lists are short)
        for a in range(1, k):
            v = nbr[i, a]
            gv = gid[v]
            b = a - 1
            while b >= 0 and gid[nbr[i, b]] > gv:
                nbr[i, b + 1] = nbr[i, b]
                b -= 1
            nbr[i, b + 1] = v
        nbr_n[i] = k


@njit(cache=True)
def build_neighbors(x, y, r, gid, n, skin, nbr, nbr_n, xref, yref, err):
    """Rebuild the Verlet lists of discs 0..n-1 and remember the build positions."""
    if n == 0:
        return
    rmax = r[:n].max()
    cell = 2.0 * rmax + skin
    x0 = x[:n].min()
    y0 = y[:n].min()
    ncx = int((x[:n].max() - x0) / cell) + 1
    ncy = int((y[:n].max() - y0) / cell) + 1
    # keep the grid bounded for discs that fly far away: the last row/column
    # collects them, which is still exact (distances are checked)
    if ncx * ncy > 4 * n + 64:
        ncy = max(1, (4 * n + 64) // ncx)
    cell_start = np.zeros(ncx * ncy + 1, np.int64)
    cell_list = np.empty(n, np.int64)
    cell_of = np.empty(n, np.int64)
    _bin(x, y, n, x0, y0, cell, ncx, ncy, cell_start, cell_list, cell_of)
    _gather(x, y, r, gid, n, ncx, ncy, cell_start, cell_list, cell_of, skin, nbr, nbr_n, err)
    for i in range(n):
        xref[i] = x[i]
        yref[i] = y[i]


@njit(parallel=True, cache=True)
def max_displacement2(x, y, xref, yref, n):
    """Largest squared displacement since the last build (max is order-free, so exact)."""
    nch = 64
    part = np.zeros(nch)
    size = (n + nch - 1) // nch
    for c in prange(nch):
        m = 0.0
        for i in range(c * size, min(n, (c + 1) * size)):
            dx = x[i] - xref[i]
            dy = y[i] - yref[i]
            d = dx * dx + dy * dy
            if d > m:
                m = d
        part[c] = m
    return part.max()
