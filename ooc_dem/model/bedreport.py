"""What a settled bed reports of itself: its surface, bulk density, porosity, mean
coordination number and the grading of the grains drawn (docs/reference/grading.md).

- Surface height (``surface_height``): the mean, over columns 4 r_max wide along x (and, 3D,
  across z), of the top (y + r) of the highest grain in each column; the end columns (the
  walls) left out. The wheel's sinkage is measured from it.
- The measuring plane (``top_layer_height``): the same mean of the highest grain *centre* in
  each column, the middle of the top layer. Bulk density and porosity are those of the box
  from the floor (y = 0) up to this plane over the bin's length (and width, 3D; 2D discs are
  cylinders of physics.thickness), every grain counted with its part inside (a disc's
  circular segment, a sphere's cap below the plane): the top layer's upper half, mostly the
  void between its peaks, is left out, its lower half stands for the layers below.
- Porosity: 1 - (grain volume in the box) / (box volume) (2D: 1 - the area fraction of the
  discs); bulk density: grain mass in the box / box volume (density (1 - porosity)).
- Coordination number: contacts between grains per grain, 2 C / N from the contact histories
  (a contact is in both grains' histories after a run); contacts with the walls (negative
  partner ids) are left out of it and counted apart (``wall_contacts``).
- Grading: d10, d50, d60 and cu = d60 / d10 of the grains' diameters by mass (mass as d^3,
  2D as d^2), as a sieve analysis of the bed would give them (model/grading.py).

A bed too large for memory is measured part by part (``BedMeasure.add``): each part below its
own plane over its own length, the sums merged.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..physics.layout import AX_X, AX_Y, AX_Z
from .grading import characteristic_diameters
from .state import Particles


def surface_height(
    p: Particles, length: float, r_max: float, x_origin: float = 0.0, across: tuple[float, float] | None = None
) -> float:
    """Mean height of the top of the bed: the max of y + r in cells of 4 r_max along x
    (from x_origin over length), the end cells (walls) excluded. ``across`` = (z_lo, z_hi),
    3D: only the spheres in that band (the wheel's footprint), split into cells of about
    4 r_max across it too, so the surface is the mean of the local tops under the wheel,
    not the highest sphere anywhere across the bin's width."""
    return _mean_column_top(p, p.pos[:, AX_Y] + p.r, length, r_max, x_origin, across)


def top_layer_height(
    p: Particles, length: float, r_max: float, x_origin: float = 0.0, across: tuple[float, float] | None = None
) -> float:
    """Mean height of the middle of the bed's top layer: ``surface_height`` of the grains'
    centres (the max of y in each cell), the plane below which the bed is measured."""
    return _mean_column_top(p, p.pos[:, AX_Y], length, r_max, x_origin, across)


def _mean_column_top(
    p: Particles,
    y_top: NDArray[np.float64],
    length: float,
    r_max: float,
    x_origin: float,
    across: tuple[float, float] | None,
) -> float:
    cell = 4 * r_max
    ncol = max(1, int(length / cell))
    x = p.pos[:, AX_X]
    col = np.clip(((x - x_origin) / cell).astype(np.int64), 0, ncol - 1)
    nrow, row = 1, np.zeros(len(p), np.int64)
    if across is not None:
        lo, hi = across
        z = p.pos[:, AX_Z]
        inside = (z >= lo) & (z < hi)
        col, y_top, z = col[inside], y_top[inside], z[inside]
        nrow = max(1, int((hi - lo) / cell))
        row = np.clip(((z - lo) * (nrow / (hi - lo))).astype(np.int64), 0, nrow - 1)
    top = np.full((ncol, nrow), -np.inf)
    np.maximum.at(top, (col, row), y_top)
    inner = top[1:-1] if ncol > 4 else top
    inner = inner[np.isfinite(inner)]
    return float(np.mean(inner)) if len(inner) else 0.0


def volume_below(y: NDArray[np.float64], r: NDArray[np.float64], h: float, dim: int) -> NDArray[np.float64]:
    """Each grain's volume below the plane at height h: 2D the area of a disc's circular
    segment (per unit thickness), 3D the volume of a sphere's cap."""
    t = np.clip(h - y, -r, r)  # the plane's height above the centre, within the grain
    if dim == 2:
        return r * r * np.arccos(-t / r) + t * np.sqrt(np.maximum(r * r - t * t, 0.0))
    b = r + t  # height of the cap below the plane
    return np.pi * b * b * (3.0 * r - b) / 3.0


class BedMeasure:
    """The sums a bed report is made of, over the parts of a bed (``add``), and the report.

    ``thickness``: 2D, the discs' length (physics.thickness); ``width``: 3D, the bin's width."""

    def __init__(self, dim: int, thickness: float, width: float) -> None:
        self.dim = dim
        self.depth = thickness if dim == 2 else width  # the box's extent across x-y
        self.n = 0
        self.box_volume = 0.0
        self.plane_area = 0.0  # sum of plane height x length (the mean plane's numerator)
        self.length = 0.0
        self.grain_volume = 0.0
        self.grain_mass = 0.0
        self.pair_entries = 0
        self.wall_entries = 0
        self.radii = np.zeros(0)  # the distinct radii seen, increasing
        self.counts = np.zeros(0, np.int64)  # grains of each

    def add(self, p: Particles, plane: float, length: float) -> None:
        """Part p of the bed, measured from the floor up to ``plane`` over ``length`` of the bin."""
        y, r = p.pos[:, AX_Y], p.r
        inside = volume_below(y, r, plane, self.dim) - volume_below(y, r, 0.0, self.dim)
        full = np.pi * r * r if self.dim == 2 else (4.0 / 3.0) * np.pi * r**3
        self.grain_volume += float(np.sum(inside)) * (self.depth if self.dim == 2 else 1.0)
        self.grain_mass += float(np.sum(p.mass * (inside / full)))
        self.box_volume += length * plane * self.depth
        self.plane_area += length * plane
        self.length += length
        self.n += len(p)
        used = np.arange(p.hist_id.shape[1])[None, :] < p.hist_n[:, None]
        self.pair_entries += int(np.count_nonzero(used & (p.hist_id >= 0)))
        self.wall_entries += int(np.count_nonzero(used & (p.hist_id < 0)))
        # the distinct radii with their counts: a tiled bed's parts repeat one tile's radii,
        # so these stay the size of a tile however large the bed
        values, inverse = np.unique(np.concatenate([self.radii, r]), return_inverse=True)
        weights = np.concatenate([self.counts, np.ones(len(r), np.int64)])
        self.radii = values
        self.counts = np.bincount(inverse.ravel(), weights=weights, minlength=len(values)).astype(np.int64)

    def report(self) -> dict[str, Any]:
        """The bed report (units in the keys' names); porosity and bulk density are None for
        a bed without height (no box to measure)."""
        if self.n == 0:
            raise ValueError("no grains")
        solid = self.grain_volume / self.box_volume if self.box_volume > 0 else math.nan
        ok = math.isfinite(solid)
        grading = characteristic_diameters(self.radii, self.dim, counts=self.counts)
        return {
            "measured_to_height_m": self.plane_area / self.length if self.length > 0 else 0.0,
            "bulk_density_kg_m3": self.grain_mass / self.box_volume if ok else None,
            "porosity": 1.0 - solid if ok else None,
            "coordination_number": self.pair_entries / self.n,
            "wall_contacts": self.wall_entries,
            "grading": {
                "d10_m": grading["d10"],
                "d50_m": grading["d50"],
                "d60_m": grading["d60"],
                "cu": grading["cu"],
            },
        }


def bed_report(
    p: Particles, length: float, r_max: float, thickness: float, width: float, plane: float | None = None
) -> dict[str, Any]:
    """The report of a whole bed in a bin of this length (and, 3D, width): measured below
    ``plane`` (None: its ``top_layer_height``, over the whole bin)."""
    if plane is None:
        plane = top_layer_height(p, length, r_max, across=(0.0, width) if p.dim == 3 else None)
    m = BedMeasure(p.dim, thickness, width)
    m.add(p, plane, length)
    return m.report()
