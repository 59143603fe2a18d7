"""The 3D wheel run's own views (``physics.dim = 3``), written beside the 2D figures:

- ``figures/deformation_midwidth.png``: the spheres of a vertical slice at the wheel's
  mid-width (final |z - z0| < 2 r_max; the initial panel adds those that started in it),
  initial and final, in their initial layer colours
  (the paper's Fig. 5-6 in 3D; the 2D figure code on the slice);
- ``figures/rut.png``: top view of the rut, the final minus the initial surface height
  on an x-z grid (the sinkage map), with the wheel's width marked;
- ``figures/lateral_flow.png``: the spheres' mean lateral displacement dz on the same
  grid (soil pushed out sideways from under the wheel, and its mean across the rut);
- ``wheel.vtk``: the wheel at its final pose as a surface mesh (legacy VTK, written by
  meshio: the triangles of ``wheel_surface.py``, rim cylinder with end caps and one box per
  lug), to load in ParaView next to the particles of ``ooc-dem checkpoint export RUN``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ..physics.layout import WS_THETA, WS_X, WS_Y

if TYPE_CHECKING:
    from ..model.scenario import Scenario

MIDWIDTH_FIGURE = "deformation_midwidth.png"
RUT_FIGURE = "rut.png"
LATERAL_FIGURE = "lateral_flow.png"
WHEEL_MESH = "wheel.vtk"


def write_wheel_vtk(path: str | os.PathLike[str], sc: Scenario, ws: NDArray[np.float64]) -> Path:
    """The wheel's surface (``wheel_surface.wheel_surface`` at state ws: the triangles of the
    rim cylinder and the lug boxes, as the trajectory export gives them) as a legacy
    VTK file written by meshio (binary, an unstructured grid of triangles; atomic)."""
    import meshio

    from ..storage.atomic import write_replacing
    from .wheel_surface import WheelGeometry, wheel_surface

    pts, tris = wheel_surface(WheelGeometry.of_scenario(sc), ws[WS_X], ws[WS_Y], ws[WS_THETA])
    mesh = meshio.Mesh(pts, [("triangle", tris)])
    path = Path(path)
    write_replacing(path, lambda tmp: meshio.write(tmp, mesh, file_format="vtk"))
    return path


def _grid(sc: Scenario) -> tuple[float, int, int]:
    cell = 2.0 * sc.soil.r_max
    nx = max(1, int(sc.bin.length / cell))
    nz = max(1, int(sc.bin.width / cell))
    return cell, nx, nz


def _cells(
    x: NDArray[np.float64], z: NDArray[np.float64], cell: float, nx: int, nz: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    return (np.clip((x / cell).astype(np.int64), 0, nx - 1), np.clip((z / cell).astype(np.int64), 0, nz - 1))


def surface_map(
    sc: Scenario, x: NDArray[np.float64], y: NDArray[np.float64], z: NDArray[np.float64], r: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Top of the bed (max y + r) per x-z cell of 2 r_max (nan where a cell is empty)."""
    cell, nx, nz = _grid(sc)
    ix, iz = _cells(x, z, cell, nx, nz)
    top = np.full((nx, nz), -np.inf)
    np.maximum.at(top, (ix, iz), y + r)
    top[~np.isfinite(top)] = np.nan
    return top


def lateral_map(
    sc: Scenario, x0: NDArray[np.float64], z0: NDArray[np.float64], dz: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Mean lateral displacement per x-z cell of the spheres' initial position (nan: empty)."""
    cell, nx, nz = _grid(sc)
    ix, iz = _cells(x0, z0, cell, nx, nz)
    s = np.zeros((nx, nz))
    c = np.zeros((nx, nz))
    np.add.at(s, (ix, iz), dz)
    np.add.at(c, (ix, iz), 1.0)
    with np.errstate(invalid="ignore"):
        return np.where(c > 0, s / np.maximum(c, 1.0), np.nan)


def _match(iid: NDArray[np.int64], fid: NDArray[np.int64]) -> NDArray[np.intp]:
    """Index into the initial arrays of each final id (all ids are in both)."""
    order = np.argsort(iid, kind="stable")
    return order[np.clip(np.searchsorted(iid[order], fid), 0, len(iid) - 1)]
