"""The direct shear box: a virtual soil test for calibrating a DEM soil (``ooc-dem shear``).

A split box is filled with the scenario's soil (its grading, density and contact laws) by
pouring: the box's scenario (``box_scenario``: the bin cut to the box, soil.n grains, no
wheel) is settled as any bed is (``bed.settled_bed``), without cohesion
(``pour_scenario``: the bonds act from the consolidation on). The fixed end walls (and in 3D the
side walls) are then switched off and the box is built of plates (``physics.plates``),
split at half the sample's height:

- lower half (fixed): the end faces x = 0 and x = L up to the split, the floor (the fixed
  wall y = 0), the top face of the right wall beyond x = L (the grains of the upper half
  that pass over it rest on it), in 3D the side faces z = 0 and z = W up to the split;
- upper half (moving at the shear speed v along +x): the end faces x = u and x = L + u
  above the split, the bottom face of its left wall (x < u: the grains of the lower half
  under it are held down), in 3D its side faces, and the lid, force-controlled: a rigid
  body under the load N = sigma A (A = L b, 2D: b the discs' thickness, or L W in 3D),
  its mass critically damped on its contacts (``lid_mass``).

The box's faces are frictionless (the soil_wall pair's friction and rolling friction are
set to 0 in the box's scenario): the shear force is then the soil's own resistance across
the shear plane, with no friction of the box's rims on the grains.

Each normal stress sigma starts from the same poured sample: the lid comes down and
consolidates it until its force holds N to 1 % (the upper half at rest), then the upper
half moves by ``displacement`` L. The shear force T is the x force the grains push back on
the upper half's plates with; tau = T / A_c and
sigma_n = N / A_c on the corrected area A_c = (L - u) b (3D (L - u) W), u the displacement
(one area for both, so the friction angle does not depend on the choice). The peak is the
largest tau of the series (means over ``ROWS`` windows), the residual the mean over the
last ``1 - residual_from`` of the displacement. The Mohr-Coulomb line tau = c + sigma_n
tan(phi) is fitted by least squares to the peaks and to the residuals (standard errors
from the residuals of the fit; they need three or more stresses).

Quasi-static: the inertial number I = gamma_dot d sqrt(rho / p), gamma_dot = v / (10 d) (a
shear band ten mean diameters thick), d the mean diameter and p = sigma, is reported for
each stress; by default v is set so that I = ``inertial`` at the smallest stress.

Outputs in OUT/: ``shear.json`` (the options, the box, every stress's series, peak and
residual, the fits) and ``figures/shear_tau_displacement.png``,
``figures/shear_mohr_coulomb.png``.
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
    from numpy.typing import ArrayLike

    from ..model.schema import Scenario
    from ..model.state import Particles

SHEAR_JSON = "shear.json"
FIG_TAU = "shear_tau_displacement.png"
FIG_MC = "shear_mohr_coulomb.png"
ROWS = 200  # rows of a shear series (each the mean over its window of steps)
PACKING = {2: 0.82, 3: 0.60}  # solid fraction of a poured sample, for the box's size
HEIGHT_OVER_LENGTH = 0.5  # the sample's aimed height over the box's length
BAND_DIAMETERS = 10.0  # shear band thickness in mean diameters (the inertial number's rate)
CONSOLIDATED = 0.01  # the lid's force within this fraction of its target
CHECK_EVERY = 0.005  # s between the consolidation's checks
MIN_CONSOLIDATION = 0.02  # s


class ShearError(OocDemError, ValueError):
    """A shear test cannot be set up or did not consolidate (message is one line)."""


@dataclass(frozen=True)
class ShearOptions:
    sigmas: tuple[float, ...] = (5.0e3, 10.0e3, 20.0e3)  # Pa, the normal stresses
    grains: int = 0  # grains in the box (0: the scenario's soil.n)
    inertial: float = 1.0e-3  # the inertial number aimed at the smallest stress (sets the speed)
    speed: float = 0.0  # m/s, the shear speed (> 0: given, not from inertial)
    displacement: float = 0.10  # the shear displacement, a fraction of the box's length
    residual_from: float = 0.75  # the residual window starts at this fraction of the displacement
    max_consolidation: float = 1.0  # s, refuse a sample whose lid does not settle within this
    lid_speed: float = 0.05  # m/s, the lid's speed limit (it is let down onto the sample)

    def check(self) -> None:
        if len(self.sigmas) < 2:
            raise ShearError(
                f"--sigma: {len(self.sigmas)} normal stress given; a Mohr-Coulomb fit needs >= 2 (3 for its errors)"
            )
        for s in self.sigmas:
            if not (s > 0 and math.isfinite(s)):
                raise ShearError(f"--sigma: {s!r} Pa must be a finite stress > 0")
        if len(set(self.sigmas)) != len(self.sigmas):
            raise ShearError("--sigma: the normal stresses must be distinct")
        if self.grains < 0:
            raise ShearError(f"--grains: {self.grains!r} must be >= 0")
        if not (0 < self.displacement <= 0.5):
            raise ShearError(f"--displacement: {self.displacement!r} must be in (0, 0.5] of the box's length")
        if not (0 <= self.residual_from < 1):
            raise ShearError(f"residual_from = {self.residual_from!r} must be in [0, 1)")
        if not (self.speed > 0 or self.inertial > 0):
            raise ShearError("--speed or --inertial must be > 0")


@dataclass(frozen=True)
class Box:
    """The box's geometry (m): length L, width W (3D; 2D: the discs' thickness), the split
    height, the lid's start, the grains' mean diameter."""

    dim: int
    length: float
    width: float
    split: float
    lid: float
    top: float
    d_mean: float
    r_max: float

    @property
    def area(self) -> float:
        return self.length * self.width


# ----------------------------------------------------------------------- the box
def box_length(sc: Scenario, grains: int) -> float:
    """The box's length for ``grains`` grains poured to a height of HEIGHT_OVER_LENGTH of it
    (3D: a square box, W = L)."""
    r = 0.5 * (sc.soil.r_min + sc.soil.r_max)
    if sc.dim == 2:
        area = grains * math.pi * r * r / PACKING[2]
        return math.sqrt(area / HEIGHT_OVER_LENGTH)
    volume = grains * 4.0 / 3.0 * math.pi * r**3 / PACKING[3]
    return float((volume / HEIGHT_OVER_LENGTH) ** (1.0 / 3.0))


def box_scenario(sc: Scenario, grains: int) -> Scenario:
    """The scenario the box's sample is poured in: the bin cut to the box (3D: L x L), tall
    enough for the loose fill, ``grains`` grains, no wheel, no tiling, frictionless walls."""
    from ..model.scenario_check import scenario_from_dict

    length = box_length(sc, grains)
    pitch = 2.2 * sc.soil.r_max
    across = max(1, int((length - 2 * sc.soil.r_max) / pitch))
    per_layer = across * (across if sc.dim == 3 else 1)
    fill_top = (math.ceil(grains / per_layer) + 1) * pitch
    d = sc.to_dict()
    d["scenario"]["name"] = f"{sc.name}-shear-box"
    d["bin"]["length"] = length
    if sc.dim == 3:
        d["bin"]["width"] = length
    d["bin"]["height"] = max(2.0 * fill_top, 2.0 * length)
    d["soil"]["n"] = grains
    d["bed"]["tile"] = 0
    d["wheel"]["enabled"] = False
    d["repose"]["enabled"] = False
    # the box is no part of the soil: frictionless, so that the force on the upper half is
    # the soil's resistance across the shear plane (a rim sliding over the other half's
    # grains would add its friction, about mu_wall (2 u / L) sigma A)
    d["contact"]["soil_wall"]["friction"] = 0.0
    d["contact"]["soil_wall"]["rolling_friction"] = 0.0
    return scenario_from_dict(d)


def pour_scenario(box_sc: Scenario) -> Scenario:
    """The box's scenario without cohesion: the sample is poured cohesionless (cohesive
    grains poured loose clump and may never come to rest), its bonds act from the
    consolidation on; so every cohesion is tested on the same poured sample."""
    from ..model.scenario_check import scenario_from_dict

    d = box_sc.to_dict()
    for pair in d["contact"].values():
        pair["cohesion"] = 0.0
    return scenario_from_dict(d)


def contact_scales(sc: Scenario, force: float) -> tuple[float, float]:
    """(k, c): the normal stiffness (N/m) and damping coefficient (N s/m) of one grain's
    contact with a plate (the soil_wall pair) carrying ``force``: the linear law's kn and
    2 zeta sqrt(m kn); Hertz's tangent stiffness 2 E* sqrt(R delta) at that force and its
    Tsuji damping 2 sqrt(5/6) |beta| sqrt(m k). m: the mean grain's mass."""
    from ..model.contacts import contact_table_3d

    r = 0.5 * (sc.soil.r_min + sc.soil.r_max)
    if sc.dim == 2:
        mass = math.pi * r * r * sc.physics.thickness * sc.soil.density
        pair = sc.contact.soil_wall
        return pair.kn, 2.0 * pair.damping_n * math.sqrt(mass * pair.kn)
    mass = 4.0 / 3.0 * math.pi * r**3 * sc.soil.density
    from ..physics.d3.layout import LAW_HERTZ
    from ..physics.layout import T_SOIL, T_WALL

    rec = contact_table_3d(sc)[T_WALL, T_SOIL]
    if int(rec["law"]) == LAW_HERTZ:
        estar = float(rec["estar"])
        delta = (3.0 * force / (4.0 * estar * math.sqrt(r))) ** (2.0 / 3.0)
        k = 2.0 * estar * math.sqrt(r * delta)
        return k, 2.0 * math.sqrt(5.0 / 6.0) * abs(float(rec["beta"])) * math.sqrt(mass * k)
    return float(rec["kn"]), 2.0 * float(rec["zn"]) * math.sqrt(mass * float(rec["kn"]))


def lid_mass(sc: Scenario, box: Box, load: float) -> float:
    """The lid's mass (kg): critically damped on its contacts, M = n c^2 / (4 k)
    (physics.plates), n the grains of one layer under it (k, c: ``contact_scales`` at
    load / n); at least 4 n k dt^2 (its oscillation far slower than a step)."""
    across = box.length / box.d_mean
    n = across if sc.dim == 2 else across * (box.width / box.d_mean)
    k, c = contact_scales(sc, load / n)
    return max(n * c * c / (4.0 * k), 4.0 * n * k * sc.physics.dt**2)


@dataclass(frozen=True)
class Plates:
    """The box's plate table, the rows of the upper half (they move at the shear speed) and
    the lid's row."""

    table: np.ndarray
    upper: tuple[int, ...]
    lid: int


def box_plates(box: Box, travel: float, load: float, mass: float, vmax: float) -> Plates:
    """The plates of the split box (module doc), the upper half at rest; ``travel``: the
    shear displacement the corner faces must cover."""
    L, W, ys, top = box.length, box.width, box.split, box.top
    m = 2.0 * box.r_max  # the faces overlap at the corners by this
    w = travel + 4.0 * box.r_max  # the walls' thickness under / over the shear plane
    z = (-m, W + m)
    rows: list[tuple[str, np.ndarray]] = [
        ("lower_left", plate(AX_X, 1, 0.0, (-m, ys), z)),
        ("lower_right", plate(AX_X, -1, L, (-m, ys), z)),
        ("lower_right_top", plate(AX_Y, 1, ys, (L, L + w), z)),
        ("upper_left", plate(AX_X, 1, 0.0, (ys, top), z)),
        ("upper_right", plate(AX_X, -1, L, (ys, top), z)),
        ("upper_left_bottom", plate(AX_Y, -1, ys, (-w, 0.0), z)),
        ("lid", plate(AX_Y, -1, box.lid, (-m, L + m), z, load=load, mass=mass, vmax=vmax)),
    ]
    if box.dim == 3:
        rows += [
            ("lower_front", plate(AX_Z, 1, 0.0, (-m, L + m), (-m, ys))),
            ("lower_back", plate(AX_Z, -1, W, (-m, L + m), (-m, ys))),
            ("upper_front", plate(AX_Z, 1, 0.0, (-m, L + m), (ys, top))),
            ("upper_back", plate(AX_Z, -1, W, (-m, L + m), (ys, top))),
        ]
    names = [n for n, _ in rows]
    table = np.concatenate([p for _, p in rows])
    upper = tuple(k for k, n in enumerate(names) if n.startswith("upper") or n == "lid")
    return Plates(table, upper, names.index("lid"))


def box_of(sc: Scenario, bed: Particles) -> Box:
    from ..model.bedreport import surface_height

    length = sc.bin.length
    width = sc.bin.length if sc.dim == 3 else sc.physics.thickness
    surface = surface_height(bed, length, sc.soil.r_max)
    top_grain = float(np.max(bed.pos[:, AX_Y] + bed.r))
    return Box(
        dim=sc.dim,
        length=length,
        width=width,
        split=0.5 * surface,
        lid=top_grain + 0.1 * sc.soil.r_max,
        top=top_grain + 2.0 * surface,
        d_mean=sc.soil.r_min + sc.soil.r_max,
        r_max=sc.soil.r_max,
    )


def poured_sample(
    sc: Scenario, grains: int, use_cache: bool = True, progress: Callable[[str], object] | None = None
) -> Particles:
    """The box's sample of ``grains`` grains poured (and cached) as ``run_shear`` pours it."""
    from .bed import settled_bed

    bsc = box_scenario(sc, grains)
    if progress is not None:
        progress(f"pouring {grains} grains into a {bsc.bin.length:.4g} m box")
    return settled_bed(pour_scenario(bsc), use_cache=use_cache)


def sample_report(box_sc: Scenario, bed: Particles) -> dict[str, Any]:
    """The poured sample's bed report (model/bedreport.py: bulk density, porosity,
    coordination number, grading), measured over the whole box as poured."""
    from ..model.bedreport import bed_report

    return bed_report(bed, box_sc.bin.length, box_sc.soil.r_max, box_sc.physics.thickness, box_sc.bin.width)


# ------------------------------------------------------------------- the test
def shear_speed(sc: Scenario, box: Box, opts: ShearOptions) -> float:
    """The shear speed: --speed, else the one giving I = opts.inertial at the smallest stress."""
    if opts.speed > 0:
        return opts.speed
    p = min(opts.sigmas)
    return opts.inertial * BAND_DIAMETERS * math.sqrt(p / sc.soil.density)


def inertial_number(sc: Scenario, box: Box, speed: float, sigma: float) -> float:
    """I = gamma_dot d sqrt(rho / p), gamma_dot = v / (BAND_DIAMETERS d), p = sigma."""
    return speed / BAND_DIAMETERS * math.sqrt(sc.soil.density / sigma)


def _window_means(rec: np.ndarray, plates: Plates, rows: int) -> dict[str, np.ndarray]:
    """Per window of steps (rows of ``rec``, (steps, P) PLATE_RECORD): the mean shear force T
    on the upper half, the lid's mean force N and position, the displacement at the end."""
    up = list(plates.upper)
    t_force = -rec["fx"][:, up].sum(axis=1)
    n_force = rec["load"][:, plates.lid]
    lid_y = rec["pos"][:, plates.lid]
    u = rec["pos"][:, up[0]]  # the upper left face's x: the displacement
    k = len(rec) // rows
    cut = k * rows

    def mean(a: np.ndarray) -> np.ndarray:
        return np.asarray(a[:cut].reshape(rows, k).mean(axis=1))

    return {"T": mean(t_force), "N": mean(n_force), "lid": mean(lid_y), "u": u[k - 1 : cut : k] + 0.0}


def shear_one(
    sc: Scenario,
    model: Model,
    bed: Particles,
    box: Box,
    sigma: float,
    speed: float,
    opts: ShearOptions,
    progress: Callable[[str], object] | None = None,
) -> dict[str, Any]:
    """One normal stress: consolidate, shear, and the series, peak and residual (module doc)."""
    dt = sc.physics.dt
    load = sigma * box.area
    mass = lid_mass(sc, box, load)
    travel = opts.displacement * box.length
    plates = box_plates(box, travel, load, mass, max(opts.lid_speed, 2.0 * speed))
    st = DomainStepper(bed.take(np.arange(len(bed))), model, plates=plates.table)
    # consolidation: the upper half at rest, until the lid's force holds its target
    chunk = max(1, int(round(CHECK_EVERY / dt)))
    step = 0
    while True:
        st.advance(step, chunk)
        step += chunk
        n_mean = float(st.plate_records["load"][:, plates.lid].mean())
        if step * dt >= MIN_CONSOLIDATION and abs(n_mean - load) < CONSOLIDATED * load:
            break
        if step * dt > opts.max_consolidation:
            raise ShearError(
                f"sigma = {sigma:g} Pa: the lid did not hold its load within {opts.max_consolidation:g} s "
                f"(mean {n_mean:.4g} N against {load:.4g} N); lower the stress or raise the contact stiffness"
            )
    consolidation_steps = step
    lid0 = float(st.plates[plates.lid]["pos"])
    if progress is not None:
        progress(f"sigma = {sigma:g} Pa: consolidated in {step * dt:.3f} s, shearing")
    # shearing: the upper half at the shear speed
    for k in plates.upper:
        st.plates[k]["vx"] = speed
    nsteps = int(math.ceil(travel / (speed * dt)))
    rows = min(ROWS, nsteps)
    nsteps = (nsteps // rows) * rows
    rec = np.zeros((nsteps, len(plates.table)), PLATE_RECORD)
    per = max(1, nsteps // 20)  # advances of at most 1/20 of the shear (bounded records)
    done = 0
    while done < nsteps:
        k = min(per, nsteps - done)
        st.advance(step + done, k)
        rec[done : done + k] = st.plate_records
        done += k
    w = _window_means(rec, plates, rows)
    area = (box.length - w["u"]) * box.width
    tau = w["T"] / area
    sig = w["N"] / area
    peak = int(np.argmax(tau))
    res = w["u"] >= opts.residual_from * w["u"][-1]
    return {
        "sigma": sigma,
        "load": load,
        "lid_mass": mass,
        "consolidation_time": consolidation_steps * dt,
        "inertial_number": inertial_number(sc, box, speed, sigma),
        "peak": {"tau": float(tau[peak]), "sigma": float(sig[peak]), "displacement": float(w["u"][peak])},
        "residual": {"tau": float(tau[res].mean()), "sigma": float(sig[res].mean())},
        "series": {
            "displacement": w["u"].tolist(),
            "tau": tau.tolist(),
            "sigma": sig.tolist(),
            "dilation": (w["lid"] - lid0).tolist(),
        },
    }


def mohr_coulomb(sigma: ArrayLike, tau: ArrayLike) -> dict[str, Any]:
    """Least-squares line tau = c + sigma tan(phi): c (Pa), phi (degrees), tan(phi), with
    their standard errors (from the fit's residuals, n - 2 degrees of freedom; None with
    two points) and R^2."""
    x = np.asarray(sigma, np.float64)
    y = np.asarray(tau, np.float64)
    n = len(x)
    if n < 2 or len(y) != n:
        raise ShearError(f"a Mohr-Coulomb fit needs >= 2 (sigma, tau) points, got {n}")
    xm, ym = x.mean(), y.mean()
    sxx = float(((x - xm) ** 2).sum())
    if sxx == 0.0:
        raise ShearError("a Mohr-Coulomb fit needs distinct normal stresses")
    slope = float(((x - xm) * (y - ym)).sum()) / sxx
    c = float(ym - slope * xm)
    resid = y - (c + slope * x)
    syy = float(((y - ym) ** 2).sum())
    r2 = 1.0 - float((resid**2).sum()) / syy if syy > 0 else 1.0
    se_slope = se_c = None
    if n > 2:
        s2 = float((resid**2).sum()) / (n - 2)
        se_slope = math.sqrt(s2 / sxx)
        se_c = math.sqrt(s2 * (1.0 / n + xm * xm / sxx))
    deg = 180.0 / math.pi
    return {
        "c": c,
        "c_se": se_c,
        "phi_deg": math.atan(slope) * deg,
        "phi_se_deg": None if se_slope is None else se_slope / (1.0 + slope * slope) * deg,
        "tan_phi": slope,
        "tan_phi_se": se_slope,
        "r2": r2,
        "points": n,
    }


def mohr_coulomb_line(label: str, fit: dict[str, Any]) -> str:
    """One line of a fit: c and phi with their standard errors."""
    cse = "" if fit["c_se"] is None else f" +- {fit['c_se']:.3g}"
    pse = "" if fit["phi_se_deg"] is None else f" +- {fit['phi_se_deg']:.2f}"
    return f"{label}: c = {fit['c']:.4g}{cse} Pa, phi = {fit['phi_deg']:.2f}{pse} deg (R^2 {fit['r2']:.3f})"


def run_shear(
    sc: Scenario,
    opts: ShearOptions,
    out: Path | None = None,
    figures: bool = True,
    use_cache: bool = True,
    progress: Callable[[str], object] | None = None,
    sample: Particles | None = None,
) -> dict[str, Any]:
    """The direct shear test of a scenario's soil at each of opts.sigmas (module doc): the
    result (also written to OUT/shear.json, with the figures, when ``out`` is given).
    ``sample``: a sample poured before (``poured_sample``) to test instead of pouring one,
    e.g. the same sample with other contact parameters."""
    opts.check()
    if out is not None and out.exists() and any(out.iterdir()):
        raise ShearError(f"--out {out}: directory exists and is not empty")
    grains = opts.grains or sc.soil.n
    bsc = box_scenario(sc, grains)
    if sample is None:
        sample = poured_sample(sc, grains, use_cache, progress)
    elif len(sample) != grains:
        raise ShearError(f"a sample of {len(sample)} grains given for a box of {grains}")
    bed = sample
    box = box_of(bsc, bed)
    walls_off = {"left": False, "right": False} | ({"front": False, "back": False} if sc.dim == 3 else {})
    model = Model.from_scenario(bsc).without_wheel().with_walls(**walls_off)
    speed = shear_speed(sc, box, opts)
    tests = [shear_one(bsc, model, bed, box, s, speed, opts, progress) for s in opts.sigmas]
    result: dict[str, Any] = {
        "scenario": sc.name,
        "dim": sc.dim,
        "grains": grains,
        "options": asdict(opts),
        "box": asdict(box),
        "sample": sample_report(bsc, bed),
        "shear_speed": speed,
        "dt": sc.physics.dt,
        "area": "corrected: (L - u) times the width (2D: the discs' thickness); tau and sigma alike",
        "tests": tests,
        "peak_fit": mohr_coulomb([t["peak"]["sigma"] for t in tests], [t["peak"]["tau"] for t in tests]),
        "residual_fit": mohr_coulomb([t["residual"]["sigma"] for t in tests], [t["residual"]["tau"] for t in tests]),
    }
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        text = json.dumps(result, indent=1)
        write_replacing(out / SHEAR_JSON, lambda tmp: Path(tmp).write_text(text))
        if figures:
            shear_figures(result, out / "figures")
    return result


# ------------------------------------------------------------------- figures
def shear_figures(result: dict[str, Any], folder: Path) -> list[Path]:
    """tau against displacement (one curve a stress) and tau against sigma (peaks, residuals,
    the fitted lines)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(folder, exist_ok=True)
    paths = []
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for t in result["tests"]:
        s = t["series"]
        ax.plot(
            np.asarray(s["displacement"]) * 1e3, np.asarray(s["tau"]) / 1e3, label=f"sigma = {t['sigma'] / 1e3:g} kPa"
        )
        ax.plot(t["peak"]["displacement"] * 1e3, t["peak"]["tau"] / 1e3, "k^", ms=5)
    ax.set_xlabel("shear displacement (mm)")
    ax.set_ylabel("shear stress tau (kPa)")
    ax.set_title(f"direct shear, {result['scenario']} ({result['grains']} grains, {result['dim']}D)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    paths.append(folder / FIG_TAU)
    write_replacing(paths[-1], lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    smax = max(max(t["peak"]["sigma"], t["residual"]["sigma"]) for t in result["tests"]) * 1.1
    xs = np.linspace(0.0, smax, 50)
    for key, marker, label in (("peak", "o", "peak"), ("residual", "s", "residual")):
        fit = result[f"{key}_fit"]
        pts = [(t[key]["sigma"], t[key]["tau"]) for t in result["tests"]]
        line = ax.plot([p[0] / 1e3 for p in pts], [p[1] / 1e3 for p in pts], marker, label=label)[0]
        se = "" if fit["phi_se_deg"] is None else f" +- {fit['phi_se_deg']:.1f}"
        cse = "" if fit["c_se"] is None else f" +- {fit['c_se'] / 1e3:.2f}"
        ax.plot(
            xs / 1e3,
            (fit["c"] + xs * fit["tan_phi"]) / 1e3,
            "-",
            color=line.get_color(),
            label=f"{label}: c = {fit['c'] / 1e3:.2f}{cse} kPa, phi = {fit['phi_deg']:.1f}{se} deg",
        )
    ax.set_xlabel("normal stress sigma (kPa)")
    ax.set_ylabel("shear stress tau (kPa)")
    ax.set_xlim(0, smax / 1e3)
    ax.set_ylim(bottom=0)
    ax.set_title("Mohr-Coulomb envelope")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    paths.append(folder / FIG_MC)
    write_replacing(paths[-1], lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    plt.close(fig)
    return paths
