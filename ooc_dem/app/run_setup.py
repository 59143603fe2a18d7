"""What a run's start needs besides its engine: the wheel placed above the bed
(``place_wheel``), the scenario's tiled bed streamed in parts to an out-of-core engine
(``StreamedBed``), and whether a run directory holds only what a run stopped before its
first commit left (``stopped_before_first_commit``: `run --out` may start afresh there)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..model.scenario import Scenario
from ..model.state import Particles
from ..physics.layout import AX_X, AX_Y, AX_Z, WS_SIZE, WS_X, WS_Y
from .bed import TiledBedMeasure, surface_height, wheel_footprint


def place_wheel(sc: Scenario, bed: Particles) -> np.ndarray:
    """Wheel centre above the bed under x0, lug tips drop_gap above the highest disc (3D:
    the highest sphere under the wheel's footprint, across its width too)."""
    w = sc.wheel
    ws = np.zeros(WS_SIZE)
    x, y = bed.pos[:, AX_X], bed.pos[:, AX_Y]
    under = np.abs(x - w.x0) < w.lug_tip_radius + sc.soil.r_max
    if sc.dim == 3:
        from ..engine.stepper import wheel_z0

        under &= np.abs(bed.pos[:, AX_Z] - wheel_z0(sc)) < 0.5 * w.width + sc.soil.r_max
    top = float((y[under] + bed.r[under]).max()) if under.any() else float((y + bed.r).max())
    ws[WS_X] = w.x0
    ws[WS_Y] = top + w.lug_tip_radius + w.drop_gap
    return ws


# what `run` puts into its output directory before the first commit
_RUN_SETUP_FILES = ("initial.npz", "scenario.toml", "bed.json")


def stopped_before_first_commit(out: Path) -> bool:
    """Whether `out` is a run that was stopped (killed, disk full) before its first commit.

    Such a directory holds nothing to lose: a store with no committed epoch and the run's own
    set-up files. `run --out` may start afresh there (create_store replaces the store and
    refuses if a live writer holds it); anything else in the directory makes it a user's.
    """
    from ooc_dem.storage import StoreError, open_store, store_owns

    try:
        store = open_store(out, repair=False)
    except StoreError:
        return False
    try:
        if store.current() is not None or store.meta.get("engine") != "ooc-dem":
            return False
    finally:
        store.close()
    own = set(_RUN_SETUP_FILES) | {n + ".tmp" for n in _RUN_SETUP_FILES}
    return all(n in own or store_owns(out, n) for n in os.listdir(out))


class StreamedBed:
    """The scenario's tiled bare bed as x-ordered parts for an out-of-core engine's
    ``create_streamed``: generated again on each pass over it, never whole in RAM. The
    first pass measures each part's surface height (its own columns, its own x origin)."""

    def __init__(self, sc: Scenario):
        self.sc = sc
        self.surfaces: list[float] | None = None
        self.measure = TiledBedMeasure(sc)  # the bed report, measured on the first pass

    def __iter__(self) -> Iterator[Particles]:
        from .bed import tiled_bed_parts

        # the first pass measures: its list is filled as the parts go by
        measured: list[float] | None = [] if self.surfaces is None else None
        if measured is not None:
            self.surfaces = measured
        band = wheel_footprint(self.sc)
        for p in tiled_bed_parts(self.sc, tiles_per_part=8):
            if measured is not None:
                x0 = p.pos[:, AX_X].min()
                measured.append(
                    surface_height(p, p.pos[:, AX_X].max() - x0, self.sc.soil.r_max, x_origin=x0, across=band)
                )
                self.measure.add(p)
            yield p
