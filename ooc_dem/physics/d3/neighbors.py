"""The 3D cell geometry of the neighbour build (numba, no I/O), and that build compiled
for spheres (``physics.neighbors``: the half pair list with its CSR index): the memory
order sorts spheres by cell along x, then y, then z (slabs run along x)."""

import sys

from numba import njit

from ..layout import AX_X, AX_Y, AX_Z
from ..neighbors import instantiate
from .layout import DIM  # noqa: F401  (the geometry's axes)

# a grid of n spheres has at most 8 n + 64 cells (spheres flying far away enlarge the cells)
GRID_CELLS = 8


@njit(inline="always", cache=True)
def vec(v):
    """(x, y, z) of a 3-vector."""
    return v[AX_X], v[AX_Y], v[AX_Z]


@njit(inline="always", cache=True)
def cell_of(pos, i, lo, cell, ncx, ncy, ncz):
    """Sphere i's cell (x, y, z indices), clipped to the grid."""
    cx = min(max(int((pos[i, AX_X] - lo[AX_X]) / cell), 0), ncx - 1)
    cy = min(max(int((pos[i, AX_Y] - lo[AX_Y]) / cell), 0), ncy - 1)
    cz = min(max(int((pos[i, AX_Z] - lo[AX_Z]) / cell), 0), ncz - 1)
    return cx, cy, cz


@njit(inline="always", cache=True)
def order_key(pos, i, lo, cell):
    """The memory-order key of sphere i's cell: x, then y, then z index (each below 10^6)."""
    cx = min(int((pos[i, AX_X] - lo[AX_X]) / cell), 999_999)
    cy = min(int((pos[i, AX_Y] - lo[AX_Y]) / cell), 999_999)
    cz = min(int((pos[i, AX_Z] - lo[AX_Z]) / cell), 999_999)
    return (cx * 1_000_000 + cy) * 1_000_000 + cz


_built = instantiate("d3", sys.modules[__name__])
build_pairs = _built.build_pairs
build_pairs_serial = _built.build_pairs_serial
spatial_order = _built.spatial_order
