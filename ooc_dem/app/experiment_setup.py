"""The model of an experiment (`ooc-dem experiment`, docs/reference/experiment.md): the bin,
the bed and the wheel's start from the DEM choices and their rules (``geometry``), and each
run's scenario: the base scenario + the DEM choices + the user's overrides + the calibrated
overrides + the wheel, slip-controlled, its slip converted to the engine's convention."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

from ..model.scenario import Scenario, ScenarioError, load_scenario
from .experiment_file import Experiment, ExperimentError, WheelSpec

FALLBACK_SOLID_FRACTION = 0.6  # of a poured bed, when the file gives no bulk density


def engine_slip(exp: Experiment, wheel: WheelSpec, slip: float) -> float:
    """The slip the engine prescribes (v = (1 - s_engine) R_rim omega) for the file's slip
    ``slip`` in its convention (v = (1 - s) R omega, R the rim's or the lug tips' radius)."""
    if exp.conventions.slip_radius == "lug_tip" and wheel.tip_radius != wheel.radius:
        return 1.0 - (1.0 - slip) * wheel.tip_radius / wheel.radius
    return slip


def run_dir_name(slip: float) -> str:
    return f"slip_{slip:.3f}"


@dataclass(frozen=True)
class Geometry:
    """The bin, the bed and the wheel's start, the same for every wheel (one settled bed)."""

    length: float
    width: float
    height: float
    x0: float
    n: int
    tile: int
    tiles_across: int
    solid_fraction: float
    travel: float  # m, the longest travel of any run

    def overrides(self) -> list[str]:
        return [
            f"bin.length={self.length!r}",
            f"bin.width={self.width!r}",
            f"bin.height={self.height!r}",
            f"soil.n={self.n}",
            f"bed.tile={self.tile}",
            f"bed.tiles_across={self.tiles_across}",
            f"wheel.x0={self.x0!r}",
        ]


def _mean_sphere_volume(base: Scenario) -> float:
    """The mean volume of the soil's spheres (its grading drawn, a fixed seed)."""
    from ..model.grading import draw_radii, grading_of_soil

    r = draw_radii(grading_of_soil(base.soil), 200_000, np.random.default_rng(0), base.dim)
    return float(np.mean(4.0 / 3.0 * math.pi * r**3))


def geometry(exp: Experiment, base: Scenario) -> Geometry:
    """The bin and bed from the DEM choices' lengths and rules (docs/reference/experiment.md)."""
    d, src = exp.dem, exp.source
    tip = max(w.tip_radius for w in exp.wheels)
    travel = max(
        (1.0 - engine_slip(exp, w, s)) * w.radius * d.omega * d.travel_time
        for w in exp.wheels
        for s in exp.slips_of(w.name)
    )
    x0 = d.start_margin + tip
    need = x0 + travel + tip + d.end_margin
    length = d.bin_length or need
    if length < need - 1e-12:
        raise ExperimentError(
            f"{src}: [dem].bin_length = {d.bin_length!r}: the wheel starts at x0 = {x0:.4f} m and travels up to "
            f"{travel:.4f} m; with its lug tips and end_margin the bin must be >= {need:.4f} m long"
        )
    width = d.bin_width or max(w.width for w in exp.wheels) + 2.0 * d.side_margin
    if width < max(w.width for w in exp.wheels) + 4.0 * d.r_max:
        raise ExperimentError(f"{src}: [dem].bin_width = {width!r}: narrower than the widest wheel + 2 particles")
    phi = d.solid_fraction or (
        min(0.74, exp.soil.bulk_density / d.particle_density) if exp.soil.bulk_density > 0 else FALLBACK_SOLID_FRACTION
    )
    n_est = phi * length * width * d.bed_depth / _mean_sphere_volume(base)
    nx = max(1, round(length / d.tile_size))
    nz = max(1, round(width / d.tile_size))
    if nx * nz > 1:
        tile = math.ceil(n_est / (nx * nz))
        n = tile * nx * nz  # whole tiles: tile_grid gives nx along, nz across
    else:
        tile, n, nz = 0, max(1, round(n_est)), 1
    # the loose fill a tile (or the bed) is poured from: initial_fill_3d's grid of pitch 2.2 r_max
    pitch = 2.2 * d.r_max
    tl, tw = length / nx, width / nz
    per_layer = max(1, int((tl - 2 * d.r_max) / pitch)) * max(1, int((tw - 2 * d.r_max) / pitch))
    fill_top = 2 * d.r_max + (math.ceil((tile or n) / per_layer) - 1) * pitch
    height = max(1.05 * fill_top, d.bed_depth + 2.0 * tip + 0.05)
    return Geometry(
        length=round(length, 4),
        width=round(width, 4),
        height=math.ceil(height * 100.0) / 100.0,
        x0=round(x0, 4),
        n=n,
        tile=tile,
        tiles_across=nz,
        solid_fraction=phi,
        travel=travel,
    )


def dem_overrides(exp: Experiment) -> list[str]:
    """The DEM choices as scenario overrides (before the geometry's, the user's own and the
    calibration's)."""
    d = exp.dem
    ov = [
        "scenario.description=" + json.dumps(f"{exp.name}: {exp.reference}"[:200]),
        f"soil.r_min={d.r_min!r}",
        f"soil.r_max={d.r_max!r}",
        f"soil.density={d.particle_density!r}",
        f"wheel.omega={d.omega!r}",
        f"wheel.settle_time={d.settle_time!r}",
        f"wheel.travel_time={d.travel_time!r}",
        "wheel.control=slip",
        "wheel.z0=0.0",
        f"output.steady_start={d.steady_start!r}",
        f"output.steady_end={d.steady_end!r}",
        f"output.series_interval={d.series_interval!r}",
        "output.snapshot_interval=0.0",  # no trajectory: the runs' series are what is compared
    ]
    if d.dt:
        ov.append(f"physics.dt={d.dt!r}")
    for key, value in d.grading:
        ov.append(f"soil.grading.{key}={json.dumps(value)}")
    return ov


def wheel_overrides(w: WheelSpec) -> list[str]:
    ov = [
        f"wheel.radius={w.radius!r}",
        f"wheel.width={w.width!r}",
        f"wheel.load={w.load!r}",
        f"wheel.n_lugs={w.n_lugs}",
        f"wheel.lug_tip_radius={w.tip_radius!r}",
    ]
    if w.n_lugs:
        ov.append(f"wheel.lug_thickness={w.lug_thickness!r}")
    return ov


def _scenario(exp: Experiment, overrides: list[str], what: str) -> Scenario:
    try:
        return load_scenario(exp.dem.base, overrides)
    except ScenarioError as e:
        raise ExperimentError(f"{exp.source}: {what}: {e}") from None


def base_scenario(exp: Experiment) -> Scenario:
    """The base scenario with the DEM choices and the user's overrides (no calibration, the
    first wheel): what the calibration starts from, and what the geometry is sized on."""
    sc = _scenario(exp, [*dem_overrides(exp), *exp.dem.overrides], "[dem] on the base scenario")
    if sc.dim != 3:
        raise ExperimentError(f"{exp.source}: [dem].base = {exp.dem.base!r}: a 2D scenario; the experiment is 3D")
    geo = geometry(exp, sc)
    return _scenario(
        exp,
        [*dem_overrides(exp), *geo.overrides(), *exp.dem.overrides, *wheel_overrides(exp.wheels[0])],
        "[dem] on the base scenario",
    )


def run_scenario(exp: Experiment, geo: Geometry, calibrated: list[str], w: WheelSpec, slip: float) -> Scenario:
    """One run's scenario: base + DEM choices + the user's overrides + calibrated + the wheel."""
    ov = [
        *dem_overrides(exp),
        *geo.overrides(),
        *exp.dem.overrides,
        *calibrated,
        *wheel_overrides(w),
        f"scenario.name={exp.name}-{w.name}",
        f"wheel.slip={engine_slip(exp, w, slip)!r}",
    ]
    return _scenario(exp, ov, f"wheel {w.name!r} at slip {slip:g}")
