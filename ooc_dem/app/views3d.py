"""The 3D wheel run's own views (``physics.dim = 3``), written beside the 2D figures:

- ``figures/deformation_midwidth.png``: the spheres of a vertical slice at the wheel's
  mid-width (final |z - z0| < 2 r_max; the initial panel adds those that started in it),
  initial and final, in their initial layer colours
  (the paper's Fig. 5-6 in 3D; the 2D figure code on the slice);
- ``figures/rut.png``: top view of the rut, the final minus the initial surface height
  on an x-z grid (the sinkage map), with the wheel's width marked;
- ``figures/lateral_flow.png``: the spheres' mean lateral displacement dz on the same
  grid (soil pushed out sideways from under the wheel, and its mean across the rut);
- ``wheel.vtk``: the wheel at its final pose as a surface mesh (legacy VTK polydata:
  rim cylinder with end caps and one box per lug), to load in ParaView next to the
  particles of ``ooc-dem checkpoint export RUN --format vtk|xdmf``.
"""

from __future__ import annotations

import math
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
RIM_SEGMENTS = 72


def wheel_mesh(
    sc: Scenario, ws: NDArray[np.float64], segments: int = RIM_SEGMENTS
) -> tuple[NDArray[np.float64], list[list[int]]]:
    """(points (P, 3), polygons as point-index lists) of the wheel at state ws: the rim
    cylinder (segments quads, two end-cap polygons) and each lug as a closed box from R to
    the lug tip, lug_thickness thick, across the wheel's width (the plates the kernels use,
    without their rounded edges)."""
    from ..engine.stepper import wheel_z0

    w = sc.wheel
    X, Y, th = float(ws[WS_X]), float(ws[WS_Y]), float(ws[WS_THETA])
    z0 = wheel_z0(sc)
    za, zb = z0 - 0.5 * w.width, z0 + 0.5 * w.width
    pts: list[tuple[float, float, float]] = []
    polys: list[list[int]] = []
    phi = th + 2.0 * math.pi * np.arange(segments) / segments
    for z in (za, zb):
        for a in phi:
            pts.append((X + w.radius * math.cos(a), Y + w.radius * math.sin(a), z))
    for k in range(segments):
        k1 = (k + 1) % segments
        polys.append([k, k1, segments + k1, segments + k])
    polys.append(list(range(segments - 1, -1, -1)))
    polys.append(list(range(segments, 2 * segments)))
    half = 0.5 * w.lug_thickness
    for lug in range(w.n_lugs):
        a = th + 2.0 * math.pi * lug / w.n_lugs
        ux, uy = math.cos(a), math.sin(a)
        vx, vy = -uy, ux
        base = len(pts)
        for z in (za, zb):
            for s, t in ((w.radius, -half), (w.lug_tip_radius, -half), (w.lug_tip_radius, half), (w.radius, half)):
                pts.append((X + s * ux + t * vx, Y + s * uy + t * vy, z))
        b = base
        polys += [
            [b, b + 1, b + 2, b + 3],
            [b + 4, b + 7, b + 6, b + 5],
            [b, b + 4, b + 5, b + 1],
            [b + 1, b + 5, b + 6, b + 2],
            [b + 2, b + 6, b + 7, b + 3],
            [b + 3, b + 7, b + 4, b],
        ]
    return np.array(pts, np.float64), polys


def write_wheel_vtk(path: str | os.PathLike[str], sc: Scenario, ws: NDArray[np.float64]) -> Path:
    """The wheel mesh (``wheel_mesh``) as a legacy ASCII VTK polydata file (atomic)."""
    from ..storage.atomic import write_replacing

    pts, polys = wheel_mesh(sc, ws)
    lines = [
        "# vtk DataFile Version 3.0",
        f"ooc-dem wheel of {sc.name}",
        "ASCII",
        "DATASET POLYDATA",
        f"POINTS {len(pts)} double",
    ]
    lines += [f"{float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in pts]
    lines.append(f"POLYGONS {len(polys)} {sum(len(p) + 1 for p in polys)}")
    lines += [" ".join(map(str, [len(p), *p])) for p in polys]
    text = "\n".join(lines) + "\n"
    path = Path(path)
    write_replacing(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
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
