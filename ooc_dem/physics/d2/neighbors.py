"""The 2D cell geometry of the neighbour build (numba, no I/O), and that build compiled
for discs (``physics.neighbors``: the half pair list with its CSR index): the grid is
one cell deep in z; the memory order sorts discs by cell column, then row."""

import sys

from numba import njit

from ..layout import AX_X, AX_Y
from ..neighbors import instantiate
from .layout import DIM  # noqa: F401  (the geometry's axes)

# a grid of n discs has at most 4 n + 64 cells (discs flying far away enlarge the cells)
GRID_CELLS = 4


@njit(inline="always", cache=True)
def vec(v):
    """(x, y) of a 2-vector."""
    return v[AX_X], v[AX_Y]


@njit(inline="always", cache=True)
def cell_of(pos, i, lo, cell, ncx, ncy, ncz):
    """Disc i's cell (column, row, 0), clipped to the grid."""
    cx = int((pos[i, AX_X] - lo[AX_X]) / cell)
    cy = int((pos[i, AX_Y] - lo[AX_Y]) / cell)
    return min(max(cx, 0), ncx - 1), min(max(cy, 0), ncy - 1), 0


@njit(inline="always", cache=True)
def order_key(pos, i, lo, cell):
    """The memory-order key of disc i's cell: column, then row."""
    cx = int((pos[i, AX_X] - lo[AX_X]) / cell)
    cy = int((pos[i, AX_Y] - lo[AX_Y]) / cell)
    return cx * 1_000_000 + min(cy, 999_999)


_built = instantiate("d2", sys.modules[__name__])
build_pairs = _built.build_pairs
build_pairs_serial = _built.build_pairs_serial
spatial_order = _built.spatial_order
