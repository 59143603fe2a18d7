"""Soil deformation and displacement fields (the paper's Figs. 5-6), pure numpy.

The paper shows the deformation under the wheel by colouring the initial bed in
horizontal layers and drawing every disc at its final position in the colour of
its initial layer. These functions compute what such figures need:

* ``layer_index``: the layer of each disc from its initial height;
* ``displacements``: final minus initial position, matched by global disc id
  (the final state may come back in any order, e.g. grouped by sub-domain);
* ``gridded_displacement``: the mean displacement vector per cell of a coarse
  grid over the initial positions (Lagrangian: a cell holds the discs that
  *started* in it), for quiver plots.

No plotting here; see ``ooc_dem.app.plots``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


def layer_index(y0, surface: float, n_layers: int, bottom: float = 0.0) -> np.ndarray:
    """Horizontal layer of each disc from its initial height ``y0``.

    The bed between ``bottom`` (the bin floor, y = 0) and ``surface`` is cut into
    ``n_layers`` layers of equal thickness, numbered 0 at the bottom to
    ``n_layers - 1`` at the surface. Discs below ``bottom`` fall in layer 0 and
    discs above ``surface`` in the top layer. Returns int64 array like ``y0``.
    """
    if n_layers < 1:
        raise ValueError(f"n_layers must be >= 1, got {n_layers}")
    if not surface > bottom:
        raise ValueError(f"surface ({surface}) must lie above bottom ({bottom})")
    y0 = np.asarray(y0, dtype=np.float64)
    thickness = (surface - bottom) / n_layers
    k = np.floor((y0 - bottom) / thickness)
    return np.clip(k, 0, n_layers - 1).astype(np.int64)


def displacements(
    initial_id: ArrayLike,
    initial_x: ArrayLike,
    initial_y: ArrayLike,
    final_id: ArrayLike,
    final_x: ArrayLike,
    final_y: ArrayLike,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Displacement ``(dx, dy)`` of every initial disc, matched by global id.

    The result is aligned with the *initial* arrays. Discs missing from the final
    state get NaN; final discs that were not in the initial state are ignored.
    Raises ``ValueError`` on duplicate ids in either set.
    """
    iid = np.asarray(initial_id, dtype=np.int64)
    ix = np.asarray(initial_x, dtype=np.float64)
    iy = np.asarray(initial_y, dtype=np.float64)
    fid = np.asarray(final_id, dtype=np.int64)
    fx = np.asarray(final_x, dtype=np.float64)
    fy = np.asarray(final_y, dtype=np.float64)
    if not (len(iid) == len(ix) == len(iy)):
        raise ValueError("initial id, x and y must have the same length")
    if not (len(fid) == len(fx) == len(fy)):
        raise ValueError("final id, x and y must have the same length")
    order = np.argsort(fid, kind="stable")
    fid_s = fid[order]
    if len(fid_s) > 1 and np.any(fid_s[1:] == fid_s[:-1]):
        raise ValueError("duplicate ids in the final state")
    if len(iid) > 1 and len(np.unique(iid)) != len(iid):
        raise ValueError("duplicate ids in the initial state")
    dx = np.full(len(iid), np.nan)
    dy = np.full(len(iid), np.nan)
    if len(fid_s) == 0 or len(iid) == 0:
        return dx, dy
    pos = np.searchsorted(fid_s, iid)
    pos_c = np.minimum(pos, len(fid_s) - 1)
    found = fid_s[pos_c] == iid
    j = order[pos_c[found]]
    dx[found] = fx[j] - ix[found]
    dy[found] = fy[j] - iy[found]
    return dx, dy


@dataclass(frozen=True)
class DisplacementGrid:
    """Mean displacement per grid cell; 2D arrays of shape (ny, nx).

    ``x``, ``y``: cell centres; ``u``, ``v``: mean displacement of the discs that
    started in the cell (NaN where ``count`` is below the threshold);
    ``count``: number of discs per cell.
    """

    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    count: np.ndarray


def gridded_displacement(x0, y0, dx, dy, cell: float, extent=None, min_count: int = 1) -> DisplacementGrid:
    """Average the displacements ``(dx, dy)`` of discs on a square grid of size ``cell``.

    Discs are binned by their *initial* position ``(x0, y0)``. ``extent`` =
    (xmin, xmax, ymin, ymax) fixes the gridded region (discs outside are
    dropped); by default it is the bounding box of the initial positions, with
    the grid anchored at multiples of ``cell``. Discs with a NaN displacement are
    skipped. Cells with fewer than ``min_count`` discs get NaN vectors.
    """
    if not cell > 0:
        raise ValueError(f"cell must be > 0, got {cell}")
    x0 = np.asarray(x0, dtype=np.float64)
    y0 = np.asarray(y0, dtype=np.float64)
    dx = np.asarray(dx, dtype=np.float64)
    dy = np.asarray(dy, dtype=np.float64)
    ok = np.isfinite(x0) & np.isfinite(y0) & np.isfinite(dx) & np.isfinite(dy)
    if extent is None:
        if not ok.any():
            raise ValueError("no finite displacement to grid")
        xmin = np.floor(x0[ok].min() / cell) * cell
        ymin = np.floor(y0[ok].min() / cell) * cell
        xmax = x0[ok].max()
        ymax = y0[ok].max()
    else:
        xmin, xmax, ymin, ymax = (float(v) for v in extent)
    nx = max(1, int(np.ceil((xmax - xmin) / cell - 1e-9)))
    ny = max(1, int(np.ceil((ymax - ymin) / cell - 1e-9)))
    # a point exactly on the upper edge belongs to the last cell
    ix = np.floor((x0 - xmin) / cell).astype(np.int64, copy=False) if len(x0) else np.zeros(0, np.int64)
    iy = np.floor((y0 - ymin) / cell).astype(np.int64, copy=False) if len(y0) else np.zeros(0, np.int64)
    ix = np.where((ix == nx) & (x0 <= xmax), nx - 1, ix)
    iy = np.where((iy == ny) & (y0 <= ymax), ny - 1, iy)
    inside = ok & (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    flat = iy[inside] * nx + ix[inside]
    count = np.bincount(flat, minlength=nx * ny).reshape(ny, nx)
    su = np.bincount(flat, weights=dx[inside], minlength=nx * ny).reshape(ny, nx)
    sv = np.bincount(flat, weights=dy[inside], minlength=nx * ny).reshape(ny, nx)
    keep = count >= max(1, min_count)
    u = np.full((ny, nx), np.nan)
    v = np.full((ny, nx), np.nan)
    u[keep] = su[keep] / count[keep]
    v[keep] = sv[keep] / count[keep]
    xc = xmin + (np.arange(nx) + 0.5) * cell
    yc = ymin + (np.arange(ny) + 0.5) * cell
    X, Y = np.meshgrid(xc, yc)
    return DisplacementGrid(X, Y, u, v, count)
