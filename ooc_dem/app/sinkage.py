"""Plate sinkage: the pressure-sinkage test of terramechanics (``ooc-dem sinkage``) and the
Bekker fit p = (k_c / b + k_phi) z^n.

The scenario's settled bed (``bed.settled_bed``, the same bed its runs start from) is
pressed by a rigid footing of width b (2D: a strip across the discs' thickness; 3D: a
square b x b at the bin's mid-width) at the bin's mid-length, moving down at a constant
speed: its bottom face and its side faces (so that the grains pushed aside cannot pass
over it) are plates (``physics.plates``) of the walls' law, prescribed in velocity. The
sinkage z is the depth of the bottom face below the bed's mean surface
(``bedreport.surface_height``), the pressure p the bottom face's normal force over its area
(2D: b times the thickness). Each width starts from the same bed.

The fit (``bekker``): log p = n log z + log k_j for each width b_j, least squares with one
n for all widths (the points with z above ``fit_from`` of the depth, p > 0), then
k_j = k_c / b_j + k_phi solved for k_c and k_phi (two widths: exactly; more: least
squares).

Outputs in OUT/: ``sinkage.json`` (the options, each width's series, the fit) and
``figures/sinkage.png`` (p against z, the fitted curves).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..engine.stepper import DomainStepper, Model
from ..errors import OocDemError
from ..physics.layout import AX_X, AX_Y, AX_Z, PLATE_RECORD
from ..physics.plates import plate
from ..storage.atomic import write_replacing

if TYPE_CHECKING:
    from ..model.schema import Scenario
    from ..model.state import Particles

SINKAGE_JSON = "sinkage.json"
FIG = "sinkage.png"
ROWS = 200  # rows of a series (each the mean over its window of steps)


class SinkageError(OocDemError, ValueError):
    """A sinkage test cannot be set up (message is one line)."""


@dataclass(frozen=True)
class SinkageOptions:
    widths: tuple[float, ...] = ()  # m, the footings' widths (empty: 1/4 and 1/2 of the bed's depth)
    depth: float = 0.0  # m, the final sinkage (0: 1/5 of the bed's depth)
    speed: float = 0.01  # m/s, the footing's speed
    fit_from: float = 0.1  # the fit takes the sinkages above this fraction of the depth

    def check(self) -> None:
        if self.widths and len(self.widths) < 2:
            raise SinkageError(f"--widths: {len(self.widths)} width given; the Bekker fit needs >= 2")
        for b in self.widths:
            if not (b > 0 and math.isfinite(b)):
                raise SinkageError(f"--widths: {b!r} m must be a finite width > 0")
        if len(set(self.widths)) != len(self.widths):
            raise SinkageError("--widths: the widths must be distinct")
        if not (self.depth >= 0 and math.isfinite(self.depth)):
            raise SinkageError(f"--depth: {self.depth!r} m must be >= 0")
        if not (self.speed > 0 and math.isfinite(self.speed)):
            raise SinkageError(f"--speed: {self.speed!r} m/s must be > 0")
        if not (0 <= self.fit_from < 1):
            raise SinkageError(f"fit_from = {self.fit_from!r} must be in [0, 1)")


def footing(sc: Scenario, b: float, bottom: float, top: float, speed: float) -> np.ndarray:
    """The footing's plates, its bottom face first: at the bin's mid-length (3D: and
    mid-width), moving down at ``speed``."""
    xc = 0.5 * sc.bin.length
    zc = 0.5 * sc.bin.width
    h = 0.5 * b
    v = (0.0, -speed, 0.0)
    rows = [plate(AX_Y, -1, bottom, (xc - h, xc + h), (zc - h, zc + h), velocity=v)]
    rows += [
        plate(AX_X, -1, xc - h, (bottom, top), (zc - h, zc + h), velocity=v),
        plate(AX_X, 1, xc + h, (bottom, top), (zc - h, zc + h), velocity=v),
    ]
    if sc.dim == 3:
        rows += [
            plate(AX_Z, -1, zc - h, (xc - h, xc + h), (bottom, top), velocity=v),
            plate(AX_Z, 1, zc + h, (xc - h, xc + h), (bottom, top), velocity=v),
        ]
    return np.concatenate(rows)


def press(
    sc: Scenario, model: Model, bed: Particles, surface: float, b: float, opts: SinkageOptions, depth: float
) -> dict[str, Any]:
    """One width: the footing let down from just above the surface to ``depth`` below it;
    the series of sinkage and pressure."""
    dt = sc.physics.dt
    start = float(np.max(bed.pos[:, AX_Y] + bed.r)) + 0.1 * sc.soil.r_max  # above every grain
    top = start + 4.0 * b
    table = footing(sc, b, start, top, opts.speed)
    st = DomainStepper(bed.take(np.arange(len(bed))), model, plates=table)
    nsteps = int(math.ceil((start - surface + depth) / (opts.speed * dt)))
    rows = min(ROWS, nsteps)
    nsteps = (nsteps // rows) * rows
    rec = np.zeros((nsteps, len(table)), PLATE_RECORD)
    per = max(1, nsteps // 20)
    done = 0
    while done < nsteps:
        k = min(per, nsteps - done)
        st.advance(done, k)
        rec[done : done + k] = st.plate_records
        done += k
    area = b * (b if sc.dim == 3 else sc.physics.thickness)
    k = nsteps // rows
    z = surface - rec["pos"][k - 1 :: k, 0]
    p = rec["load"][:, 0].reshape(rows, k).mean(axis=1) / area
    return {"width": b, "area": area, "series": {"sinkage": z.tolist(), "pressure": p.tolist()}}


def bekker(tests: list[dict[str, Any]], depth: float, fit_from: float) -> dict[str, Any]:
    """The Bekker fit p = (k_c / b + k_phi) z^n (module doc): n, k_c, k_phi and each width's
    k = k_c / b + k_phi, with the fit's points and R^2 of log p."""
    cols, rhs, zs = [], [], []
    for j, t in enumerate(tests):
        z = np.asarray(t["series"]["sinkage"])
        p = np.asarray(t["series"]["pressure"])
        sel = (z > fit_from * depth) & (p > 0)
        if sel.sum() < 2:
            raise SinkageError(f"width {t['width']:g} m: fewer than 2 points with z > {fit_from:g} depth and p > 0")
        for zz, pp in zip(z[sel], p[sel]):
            row = [math.log(zz)] + [1.0 if i == j else 0.0 for i in range(len(tests))]
            cols.append(row)
            rhs.append(math.log(pp))
            zs.append(zz)
    a = np.asarray(cols)
    y = np.asarray(rhs)
    sol, *_ = np.linalg.lstsq(a, y, rcond=None)
    resid = y - a @ sol
    r2 = 1.0 - float(resid @ resid) / float(((y - y.mean()) ** 2).sum())
    n = float(sol[0])
    ks = np.exp(sol[1:])
    inv_b = np.array([1.0 / t["width"] for t in tests])
    # k_j = k_c / b_j + k_phi: least squares (exact for two widths)
    m = np.column_stack([inv_b, np.ones_like(inv_b)])
    (k_c, k_phi), *_ = np.linalg.lstsq(m, ks, rcond=None)
    return {
        "n": n,
        "k_c": float(k_c),
        "k_phi": float(k_phi),
        "k_per_width": [{"width": t["width"], "k": float(k)} for t, k in zip(tests, ks)],
        "r2_log_p": r2,
        "points": len(y),
        "units": "p in Pa, z and b in m: k_c in N/m^(n+1), k_phi in N/m^(n+2)",
    }


def run_sinkage(
    sc: Scenario,
    opts: SinkageOptions,
    out: Path | None = None,
    figures: bool = True,
    use_cache: bool = True,
    progress: Callable[[str], object] | None = None,
) -> dict[str, Any]:
    """The pressure-sinkage test of a scenario's bed at each width (module doc): the result
    (also written to OUT/sinkage.json, with the figure, when ``out`` is given)."""
    from ..model.bedreport import surface_height
    from .bed import settled_bed

    opts.check()
    if out is not None and out.exists() and any(out.iterdir()):
        raise SinkageError(f"--out {out}: directory exists and is not empty")
    if sc.bed.tile > 0:
        raise SinkageError(f"bed.tile = {sc.bed.tile}: the sinkage test takes an untiled bed (bed.tile = 0)")
    bed = settled_bed(sc, use_cache=use_cache)
    surface = surface_height(bed, sc.bin.length, sc.soil.r_max)
    widths = opts.widths or (0.25 * surface, 0.5 * surface)
    depth = opts.depth or 0.2 * surface
    across = sc.bin.width if sc.dim == 3 else sc.bin.length
    if max(widths) > 0.5 * min(sc.bin.length, across):
        raise SinkageError(f"--widths: {max(widths):g} m is more than half the bin ({sc.bin.length:g} m)")
    if depth >= 0.5 * surface:
        raise SinkageError(f"--depth: {depth:g} m is half the bed's depth ({surface:.4g} m) or more")
    model = Model.from_scenario(sc).without_wheel()
    tests = []
    for b in widths:
        if progress is not None:
            progress(f"pressing a {b:g} m plate {depth:g} m into the bed at {opts.speed:g} m/s")
        tests.append(press(sc, model, bed, surface, b, opts, depth))
    result: dict[str, Any] = {
        "scenario": sc.name,
        "dim": sc.dim,
        "options": asdict(opts),
        "surface": surface,
        "depth": depth,
        "widths": list(widths),
        "tests": tests,
        "bekker": bekker(tests, depth, opts.fit_from),
    }
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        text = json.dumps(result, indent=1)
        write_replacing(out / SINKAGE_JSON, lambda tmp: Path(tmp).write_text(text))
        if figures:
            sinkage_figure(result, out / "figures")
    return result


def sinkage_figure(result: dict[str, Any], folder: Path) -> Path:
    """Pressure against sinkage for each width, with the Bekker curves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(folder, exist_ok=True)
    fit = result["bekker"]
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for t, kw in zip(result["tests"], fit["k_per_width"]):
        z = np.asarray(t["series"]["sinkage"])
        line = ax.plot(z * 1e3, np.asarray(t["series"]["pressure"]) / 1e3, label=f"b = {t['width'] * 1e3:.0f} mm")[0]
        zz = np.linspace(max(z.min(), 1e-6), z.max(), 60)
        zz = zz[zz > 0]
        ax.plot(zz * 1e3, kw["k"] * zz ** fit["n"] / 1e3, "--", color=line.get_color())
    ax.set_xlabel("sinkage z (mm)")
    ax.set_ylabel("pressure p (kPa)")
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=0)
    ax.set_title(
        f"pressure-sinkage, {result['scenario']}: n = {fit['n']:.2f}, "
        f"k_c = {fit['k_c']:.3g}, k_phi = {fit['k_phi']:.3g}",
        fontsize=9,
    )
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    path = folder / FIG
    write_replacing(path, lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    plt.close(fig)
    return path
