"""Calibrating a DEM soil from its lab sheet (``ooc-dem calibrate``): the scenario's grains
(sizes, grain density, contact laws) given, find the soil-soil friction, the cohesion energy
density and the pour's friction that give the measured friction angle, cohesion and bulk
density (docs/calibration.md).

The search is small and stated, every value it reports measured:

1. **Bulk density** (when given): the shear box's sample (``shear.poured_sample``, the grains
   of the scenario poured into the box) is poured with ``bed.fill_friction`` f and measured
   (``model.bedreport``: the whole box below its top layer's middle). Denser with a smaller
   f; f = 0 is the densest pour. Regula falsi (Illinois) on f within [0, FILL_MAX] until the
   density is within ``density_tolerance``. Grain density is the scenario's ``soil.density``
   (a lab value, not a fitted one): the pour sets the solid fraction. Without a density
   target the pour keeps the scenario's friction, written as ``bed.fill_friction`` so that
   the calibrated scenario's bed is poured as the sample was.
2. **Friction angle and cohesion**: the direct shear test (``shear.run_shear``) of that one
   sample at ``sigmas`` (the stresses under the wheel by default), the Mohr-Coulomb fit of
   the peaks (or residuals: ``envelope``) giving phi and c. The soil-soil friction mu (or,
   ``vary``, its rolling friction) moves tan(phi), the cohesion energy density k moves c,
   nearly independently: the first test takes the scenario's value without cohesion, the
   second a proportional guess of the value and a Rumpf-type guess of k; then each test
   takes a bracketed step in the value (``friction_step``: phi is noisy and can be flat in
   it) and a secant step in k, until both are
   within tolerance or ``evaluations`` shear tests are spent. The chosen parameters are
   those of the evaluation nearest the targets; its measured phi, c and their standard
   errors are the result.

Honest limits, reported when met: a density above the frictionless pour's (or below that of
the loosest pour tried) cannot be reached by the pour; a friction angle above what
friction reaches with the scenario's rolling friction cannot be reached (raise
``rolling_friction``); a cohesion below the intercept the cohesionless sample already shows
over these stresses (the envelope's curvature) cannot be reached with k >= 0; and a target
within the fit's own standard error cannot be resolved better than that error.

Outputs in OUT/: ``calibration.json`` (targets, options, the sample, every evaluation, the
chosen parameters, the achieved properties and their errors, the notes), ``calibrated.toml``
(the scenario fragment: the keys to set, with the achieved values as comments) and, of the
chosen evaluation, ``shear/`` (its shear.json and figures).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from ..errors import OocDemError
from ..storage.atomic import write_replacing
from .shear import ShearOptions, box_scenario, poured_sample, run_shear, sample_report, shear_figures

if TYPE_CHECKING:
    from ..model.schema import Scenario
    from ..model.state import Particles

CALIBRATION_JSON = "calibration.json"
FRAGMENT_TOML = "calibrated.toml"
FILL_MAX = 2.0  # the loosest pour's friction tried
VARIED = {"friction": (0.01, 3.0), "rolling_friction": (0.0, 1.0)}  # what moves phi, and its range
COORDINATION = 6.0  # the guess of k's contacts per grain (Rumpf)


class CalibrationError(OocDemError, ValueError):
    """A calibration cannot be set up (message is one line)."""


@dataclass(frozen=True)
class LabSoil:
    """A soil's lab sheet: the targets."""

    friction_angle: float  # deg, Mohr-Coulomb friction angle (peak, unless envelope = residual)
    cohesion: float = 0.0  # Pa, Mohr-Coulomb cohesion
    bulk_density: float = 0.0  # kg/m^3 (0: not a target; the pour stays the scenario's)

    def check(self) -> None:
        if not (0.0 < self.friction_angle < 60.0):
            raise CalibrationError(f"friction angle {self.friction_angle!r} deg must be in (0, 60)")
        if not (self.cohesion >= 0.0 and math.isfinite(self.cohesion)):
            raise CalibrationError(f"cohesion {self.cohesion!r} Pa must be finite and >= 0")
        if not (self.bulk_density >= 0.0 and math.isfinite(self.bulk_density)):
            raise CalibrationError(f"bulk density {self.bulk_density!r} kg/m^3 must be finite and >= 0")


@dataclass(frozen=True)
class CalibrateOptions:
    sigmas: tuple[float, ...] = (3.0e3, 6.0e3, 9.0e3, 12.0e3)  # Pa, the shear tests' normal stresses
    grains: int = 2000  # grains in the shear box
    envelope: str = "peak"  # "peak" or "residual": the Mohr-Coulomb line calibrated
    vary: str = "friction"  # the soil-soil value that moves phi: "friction" or "rolling_friction"
    inertial: float = 1.0e-3  # the shear tests' inertial number at the smallest stress
    displacement: float = 0.10  # the shear displacement, a fraction of the box's length
    evaluations: int = 8  # shear tests at most
    pours: int = 6  # pours at most (density)
    angle_tolerance: float = 0.5  # deg
    cohesion_tolerance: float = 0.10  # relative
    density_tolerance: float = 0.01  # relative

    def check(self) -> None:
        if self.vary not in VARIED:
            raise CalibrationError(f"--vary {self.vary!r}: must be one of {', '.join(VARIED)}")
        if self.envelope not in ("peak", "residual"):
            raise CalibrationError(f"--envelope {self.envelope!r}: must be 'peak' or 'residual'")
        if self.grains < 200:
            raise CalibrationError(f"--grains {self.grains!r}: a shear box needs >= 200 grains")
        if self.evaluations < 2:
            raise CalibrationError(f"--evaluations {self.evaluations!r}: the search needs >= 2 shear tests")
        if self.pours < 2:
            raise CalibrationError(f"pours = {self.pours!r}: the density search needs >= 2 pours")
        ShearOptions(sigmas=self.sigmas, grains=self.grains).check()


def soil_key(sc: Scenario) -> str:
    """A digest of what a calibration of ``sc`` depends on (its physics, grains, pour and
    contact laws; not its bin, grain count, wheel or outputs): a calibration is reused only for a
    scenario of the same key."""
    import hashlib

    d = sc.to_dict()
    keep = {k: d[k] for k in ("physics", "soil", "contact")}
    keep["soil"] = {k: v for k, v in d["soil"].items() if k != "n"}  # the box holds its own count
    keep["bed"] = {k: d["bed"][k] for k in ("settle_speed", "max_settle_time", "fill_friction")}
    return hashlib.sha256(json.dumps(keep, sort_keys=True).encode()).hexdigest()[:16]


def with_values(sc: Scenario, fill: float | None = None, **pair_values: float) -> Scenario:
    """The scenario with the pour's friction and soil-soil values (friction, rolling_friction,
    cohesion) set."""
    bed = sc.bed if fill is None else dataclasses.replace(sc.bed, fill_friction=fill)
    values: dict[str, Any] = dict(pair_values)
    pair = dataclasses.replace(sc.contact.soil_soil, **values)
    return dataclasses.replace(sc, bed=bed, contact=dataclasses.replace(sc.contact, soil_soil=pair))


# ------------------------------------------------------------------- density
def _density_search(
    sc: Scenario, lab: LabSoil, opts: CalibrateOptions, say: Callable[[str], object]
) -> tuple[float, Particles, list[dict[str, Any]], list[str]]:
    """The pour's friction f for the target bulk density: (f, its sample, the pours, notes)."""
    pours: list[dict[str, Any]] = []
    samples: dict[float, Particles] = {}

    def pour(f: float) -> float:
        s = with_values(sc, fill=f)
        bed = poured_sample(s, opts.grains)
        rep = sample_report(box_scenario(s, opts.grains), bed)
        rho = float(rep["bulk_density_kg_m3"])
        samples[f] = bed
        pours.append({"fill_friction": f, "bulk_density": rho, "porosity": rep["porosity"]})
        say(f"pour {len(pours)}: fill friction {f:.4g} -> bulk density {rho:.1f} kg/m^3")
        return rho - lab.bulk_density

    notes: list[str] = []
    tol = opts.density_tolerance * lab.bulk_density
    lo, hi = 0.0, max(sc.contact.soil_soil.friction, 0.5)
    g_lo = pour(lo)
    if g_lo < -tol:
        notes.append(
            f"bulk density: {lab.bulk_density:g} kg/m^3 is above the densest pour's ({lab.bulk_density + g_lo:.1f}, "
            f"frictionless pour) with these grains (grain density {sc.soil.density:g} kg/m^3)"
        )
        return lo, samples[lo], pours, notes
    if abs(g_lo) <= tol:
        return lo, samples[lo], pours, notes
    g_hi = pour(hi)
    while g_hi > tol and hi < FILL_MAX and len(pours) < opts.pours:
        lo, g_lo = hi, g_hi
        hi = min(2.0 * hi, FILL_MAX)
        g_hi = pour(hi)
    if g_hi > tol:
        notes.append(
            f"bulk density: {lab.bulk_density:g} kg/m^3 is below the loosest pour tried ({lab.bulk_density + g_hi:.1f}, "
            f"fill friction {hi:g})"
        )
        return hi, samples[hi], pours, notes
    side = 0
    while abs(g_hi) > tol and len(pours) < opts.pours:
        # Illinois regula falsi: density falls as the pour's friction grows
        f = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
        g = pour(f)
        if g > 0:
            lo, g_lo = f, g
            if side == 1:
                g_hi *= 0.5
            side = 1
        else:
            hi, g_hi = f, g
            if side == -1:
                g_lo *= 0.5
            side = -1
        if abs(g) <= tol:
            return f, samples[f], pours, notes
    best = min(pours, key=lambda p: abs(p["bulk_density"] - lab.bulk_density))
    f = best["fill_friction"]
    return f, samples[f], pours, notes


# ------------------------------------------------------------ friction, cohesion
def cohesion_guess(sc: Scenario, sigma: float, friction_angle: float, cohesion: float, solid: float) -> float:
    """A first k (J/m^3) for cohesion c (Pa): Rumpf's tensile strength sigma_t = phi_s Z F /
    (pi d^2) of grains bonded by F (c = sigma_t tan(phi)), F = k A over the contact area A of
    the mean contact force at ``sigma`` (Hertz or linear overlap). An order of magnitude only:
    the search measures c and corrects k."""
    from ..model.contacts import contact_table_3d
    from ..physics.d3.layout import LAW_HERTZ
    from ..physics.layout import T_SOIL

    r = 0.5 * (sc.soil.r_min + sc.soil.r_max)
    d = 2.0 * r
    tan_phi = math.tan(math.radians(friction_angle))
    bond = cohesion * math.pi * d * d / (solid * COORDINATION * tan_phi)  # N, the bond per contact
    force = sigma * math.pi * d * d / (solid * COORDINATION)  # N, the mean contact force
    if sc.dim == 3:
        rec = contact_table_3d(sc)[T_SOIL, T_SOIL]
        if int(rec["law"]) == LAW_HERTZ:
            rstar = 0.5 * r
            delta = float((3.0 * force / (4.0 * float(rec["estar"]) * math.sqrt(rstar))) ** (2.0 / 3.0))
        else:
            delta = force / float(rec["kn"])
        return bond / (math.pi * r * delta)
    t = sc.physics.thickness
    delta = force * t / d / sc.contact.soil_soil.kn  # the discs' force per unit of thickness
    return bond / (2.0 * math.sqrt(r * delta) * t)


def _secant(x0: float, y0: float, x1: float, y1: float, target: float) -> float | None:
    """x where the line through (x0, y0), (x1, y1) reaches target; None when flat."""
    if x1 == x0 or y1 == y0:
        return None
    return x1 + (target - y1) * (x1 - x0) / (y1 - y0)


def friction_step(tested: list[tuple[float, float]], target: float, lowest: float = 0.0) -> float:
    """The next value of the varied parameter x for tan(phi) = target, from the (x, tan phi)
    tested so far, in order. phi rises with x, but flatly where the packing, not the
    friction, holds the sample, and a shear test's phi is noisy (its standard error, a
    fraction of a degree to two), so a plain secant can step the wrong way or barely move.
    Once tests lie on both sides of the target, the next x is regula falsi inside that
    bracket, or its midpoint when the last two tests fell on one side (so the bracket at
    least halves every other test), when regula falsi would land near an end, or when noise
    inverts the bracket. Before, x takes the farther of the ratio of the tangents (raised
    to 1, 2, 4, ... while the tests stay on one side) and a secant of positive slope
    through the last two, not below ``lowest``."""
    below = [t for t in tested if t[1] < target]
    above = [t for t in tested if t[1] >= target]
    if below and above:
        a = max(below)  # the highest x still below the target
        b = min(above)  # the lowest x already above it
        mid = 0.5 * (a[0] + b[0])
        if a[0] >= b[0] or (len(tested) >= 2 and (tested[-1][1] < target) == (tested[-2][1] < target)):
            return mid
        w = b[0] - a[0]
        x = a[0] + (target - a[1]) * w / (b[1] - a[1])
        return x if a[0] + 0.1 * w <= x <= b[0] - 0.1 * w else mid
    last_x, last_tan = tested[-1]
    run = 1  # the tests so far on the last one's side
    while run < len(tested) and (tested[-1 - run][1] < target) == (last_tan < target):
        run += 1
    ratio = target / last_tan
    if last_x <= 0.0:
        return 0.05 if ratio > 1.0 else 0.0
    x = last_x * float(ratio ** (2 ** min(run - 1, 6)))
    if len(tested) >= 2:
        step = _secant(*tested[-2], *tested[-1], target)
        px, ptan = tested[-2]
        if step is not None and (last_tan - ptan) * (last_x - px) > 0:  # phi rising with x
            x = max(x, step) if ratio > 1.0 else min(x, step)
    return max(x, lowest)


def _miss(ev: dict[str, Any], lab: LabSoil, opts: CalibrateOptions, cohesion: bool = True) -> float:
    """An evaluation's distance from the targets in units of the tolerances (``cohesion``
    False: the friction angle's only)."""
    m = abs(float(ev["phi_deg"]) - lab.friction_angle) / opts.angle_tolerance
    if cohesion and lab.cohesion > 0:
        m = max(m, abs(float(ev["c"]) - lab.cohesion) / (opts.cohesion_tolerance * lab.cohesion))
    return m


def run_calibrate(
    sc: Scenario,
    lab: LabSoil,
    out: Path,
    progress: Callable[[str], object] | None = None,
    opts: CalibrateOptions | None = None,
) -> dict[str, Any]:
    """Calibrate ``sc``'s soil to ``lab`` (module doc); writes OUT/ and returns the result,
    whose "overrides" are the scenario values to set ("section.key=value")."""
    opts = opts or CalibrateOptions()
    lab.check()
    opts.check()
    if out.exists() and any(out.iterdir()):
        raise CalibrationError(f"--out {out}: directory exists and is not empty")

    def say(text: str) -> None:
        if progress is not None:
            progress(text)

    notes: list[str] = []
    pours: list[dict[str, Any]] = []
    if lab.bulk_density > 0:
        fill, sample, pours, density_notes = _density_search(sc, lab, opts, say)
        notes += density_notes
    else:
        # the pour's friction fixed at the one the sample is poured with, so that the bed of
        # the calibrated scenario is poured as the sample was, whatever friction is chosen
        fill = sc.bed.fill_friction if sc.bed.fill_friction >= 0 else sc.contact.soil_soil.friction
        sample = poured_sample(with_values(sc, fill=fill), opts.grains)
    base = with_values(sc, fill=fill)
    measured = sample_report(box_scenario(base, opts.grains), sample)
    shear_opts = ShearOptions(
        sigmas=opts.sigmas, grains=opts.grains, inertial=opts.inertial, displacement=opts.displacement
    )
    evaluations: list[dict[str, Any]] = []
    results: list[dict[str, Any]] = []

    vary = opts.vary

    def evaluate(x: float, k: float) -> dict[str, Any]:
        tested = with_values(base, **{vary: x}, cohesion=k)
        res = run_shear(tested, shear_opts, out=None, figures=False, sample=sample)
        fit = res[f"{opts.envelope}_fit"]
        ev = {
            "friction": tested.contact.soil_soil.friction,
            "rolling_friction": tested.contact.soil_soil.rolling_friction,
            "cohesion_energy": k,
            "phi_deg": fit["phi_deg"],
            "phi_se_deg": fit["phi_se_deg"],
            "c": fit["c"],
            "c_se": fit["c_se"],
            "r2": fit["r2"],
        }
        evaluations.append(ev)
        results.append(res)
        cse = "" if fit["c_se"] is None else f" +- {fit['c_se']:.0f}"
        pse = "" if fit["phi_se_deg"] is None else f" +- {fit['phi_se_deg']:.2f}"
        say(
            f"shear test {len(evaluations)}: {vary.replace('_', ' ')} {x:.4g}, cohesion {k:.4g} J/m^3 -> "
            f"phi {fit['phi_deg']:.2f}{pse} deg, c {fit['c']:.0f}{cse} Pa"
        )
        return ev

    tan_t = math.tan(math.radians(lab.friction_angle))
    x0 = float(getattr(sc.contact.soil_soil, vary))
    lo_x, hi_x = VARIED[vary]
    a = evaluate(x0, 0.0)
    c_floor = a["c"]
    # a cohesion the cohesionless sample already exceeds is out of reach of k >= 0: the
    # search then keeps k = 0 and spends its tests on the friction angle (a note says so)
    reach_c = lab.cohesion > 0 and c_floor <= lab.cohesion * (1.0 + opts.cohesion_tolerance)
    b: dict[str, Any] | None = None
    while len(evaluations) < opts.evaluations and _miss(evaluations[-1], lab, opts, reach_c) > 1.0:
        last = evaluations[-1]
        ratio = tan_t / math.tan(math.radians(last["phi_deg"]))
        if b is None:  # the first step: a proportional value (a step of 0.05 from 0) and a Rumpf-type k
            x = last[vary] * ratio if last[vary] > 0 else (0.05 if ratio > 1 else 0.0)
            k = 0.0
            if reach_c:
                solid = 1.0 - float(measured["porosity"])
                k = cohesion_guess(
                    sc,
                    float(sum(opts.sigmas) / len(opts.sigmas)),
                    lab.friction_angle,
                    max(lab.cohesion - c_floor, 0.1 * lab.cohesion),
                    solid,
                )
        else:
            prev = evaluations[-2]
            x = friction_step([(e[vary], math.tan(math.radians(e["phi_deg"]))) for e in evaluations], tan_t, lo_x)
            k = last["cohesion_energy"]
            if reach_c:
                step_k = _secant(prev["cohesion_energy"], prev["c"], last["cohesion_energy"], last["c"], lab.cohesion)
                if step_k is not None:
                    k = step_k
        x = min(max(x, lo_x), hi_x)
        k = max(k, 0.0)
        if any(e[vary] == x and e["cohesion_energy"] == k for e in evaluations):
            break  # a range's end tested already: nothing new to learn
        b = evaluate(x, k)
    best_i = min(range(len(evaluations)), key=lambda i: _miss(evaluations[i], lab, opts, reach_c))
    best = evaluations[best_i]
    notes += _limits(lab, opts, evaluations, best, c_floor, reach_c)
    overrides = [f"contact.soil_soil.{vary}={best[vary]!r}"]
    if lab.cohesion > 0 or sc.contact.soil_soil.cohesion > 0:
        overrides.append(f"contact.soil_soil.cohesion={best['cohesion_energy']!r}")
    overrides.append(f"bed.fill_friction={fill!r}")
    achieved = {
        "friction_angle": best["phi_deg"],
        "friction_angle_se": best["phi_se_deg"],
        "cohesion": best["c"],
        "cohesion_se": best["c_se"],
        "bulk_density": measured["bulk_density_kg_m3"],
        "porosity": measured["porosity"],
    }
    result: dict[str, Any] = {
        "scenario": sc.name,
        "soil_key": soil_key(sc),
        "targets": asdict(lab),
        "options": asdict(opts),
        "grain_density": sc.soil.density,
        "sample": {"grains": opts.grains, **measured},
        "pours": pours,
        "evaluations": evaluations,
        "chosen": best_i,
        "overrides": overrides,
        "achieved": achieved,
        "errors": _errors(lab, achieved),
        "notes": notes,
    }
    out.mkdir(parents=True, exist_ok=True)
    shear_dir = out / "shear"
    shear_dir.mkdir()
    chosen = results[best_i]
    write_replacing(shear_dir / "shear.json", lambda tmp: Path(tmp).write_text(json.dumps(chosen, indent=1)))
    shear_figures(chosen, shear_dir / "figures")
    write_replacing(out / FRAGMENT_TOML, lambda tmp: Path(tmp).write_text(fragment_toml(result)))
    # written last: its presence says the calibration is complete (read_calibration)
    write_replacing(out / CALIBRATION_JSON, lambda tmp: Path(tmp).write_text(json.dumps(result, indent=1)))
    return result


def _errors(lab: LabSoil, achieved: dict[str, Any]) -> dict[str, Any]:
    """The achieved properties' distance from the targets: deg, relative, relative."""
    return {
        "friction_angle_deg": achieved["friction_angle"] - lab.friction_angle,
        "cohesion_relative": (achieved["cohesion"] - lab.cohesion) / lab.cohesion if lab.cohesion > 0 else None,
        "bulk_density_relative": (achieved["bulk_density"] - lab.bulk_density) / lab.bulk_density
        if lab.bulk_density > 0
        else None,
    }


def _limits(
    lab: LabSoil,
    opts: CalibrateOptions,
    evaluations: list[dict[str, Any]],
    best: dict[str, Any],
    c_floor: float,
    reach_c: bool,
) -> list[str]:
    """What the search met and could not get past (module doc)."""
    notes = []
    if lab.cohesion > 0 and not reach_c:
        se = evaluations[0]["c_se"]
        notes.append(
            f"cohesion: the cohesionless sample already shows c = {c_floor:.0f}"
            + ("" if se is None else f" +- {se:.0f}")
            + f" Pa over these stresses (> the target {lab.cohesion:g} Pa): k >= 0 cannot lower it; "
            "cohesion left at 0, only the friction angle searched"
        )
    if best["c_se"] is not None and lab.cohesion > 0 and best["c_se"] > opts.cohesion_tolerance * lab.cohesion:
        notes.append(
            f"cohesion: the fit's standard error {best['c_se']:.0f} Pa exceeds the tolerance "
            f"({opts.cohesion_tolerance:.0%} of {lab.cohesion:g} Pa): c is not resolved better than that"
        )
    vary = opts.vary
    lo_x, hi_x = VARIED[vary]
    other = "rolling_friction" if vary == "friction" else "friction"
    top = max(evaluations, key=lambda e: e[vary])
    if top[vary] >= hi_x and top["phi_deg"] < lab.friction_angle - opts.angle_tolerance:
        notes.append(
            f"friction angle: {vary} {hi_x:g} reaches only {top['phi_deg']:.1f} deg; raise "
            f"contact.soil_soil.{other} or calibrate with --vary {other}"
        )
    bottom = min(evaluations, key=lambda e: e[vary])
    if bottom[vary] <= lo_x and bottom["phi_deg"] > lab.friction_angle + opts.angle_tolerance:
        notes.append(
            f"friction angle: {vary} {lo_x:g} still gives {bottom['phi_deg']:.1f} deg on this sample; lower "
            f"contact.soil_soil.{other} or calibrate with --vary {other} (a looser sample, e.g. a larger grain "
            "density for the same bulk density, has a lower peak)"
        )
    if _miss(best, lab, opts, reach_c) > 1.0:
        notes.append(f"not within tolerance after {len(evaluations)} shear tests (the nearest is reported)")
    return notes


def fragment_toml(result: dict[str, Any]) -> str:
    """The scenario fragment of a calibration: its overrides as TOML, the achieved values as
    comments."""
    a, t = result["achieved"], result["targets"]
    lines = [
        f"# calibrated by `ooc-dem calibrate` from the scenario {result['scenario']!r}:",
        f"#   friction angle {a['friction_angle']:.2f} deg (target {t['friction_angle']:g}),"
        f" cohesion {a['cohesion']:.0f} Pa (target {t['cohesion']:g}),"
        f" bulk density {a['bulk_density']:.1f} kg/m^3 (target {t['bulk_density']:g})",
        f"#   {result['options']['envelope']} envelope over sigma = "
        + ", ".join(f"{s:g}" for s in result["options"]["sigmas"])
        + " Pa; calibration.json has every test",
    ]
    sections: dict[str, list[str]] = {}
    for item in result["overrides"]:
        key, value = item.split("=", 1)
        section, name = key.rsplit(".", 1)
        sections.setdefault(section, []).append(f"{name} = {float(value)!r}")
    for section, keys in sections.items():
        lines += ["", f"[{section}]", *keys]
    return "\n".join(lines) + "\n"


def calibration_lines(result: dict[str, Any]) -> list[str]:
    """The calibration's table as printed: every test, the chosen values, the achieved
    properties against the targets, the notes."""
    lines = [f"{'test':>4} {'friction':>9} {'rolling':>8} {'k (J/m3)':>10} {'phi (deg)':>14} {'c (Pa)':>14}"]
    for i, ev in enumerate(result["evaluations"]):
        pse = "" if ev["phi_se_deg"] is None else f" +- {ev['phi_se_deg']:.2f}"
        cse = "" if ev["c_se"] is None else f" +- {ev['c_se']:.0f}"
        mark = " <- chosen" if i == result["chosen"] else ""
        lines.append(
            f"{i + 1:>4} {ev['friction']:>9.4f} {ev['rolling_friction']:>8.4f} {ev['cohesion_energy']:>10.4g} {ev['phi_deg']:>6.2f}{pse:>8} "
            f"{ev['c']:>6.0f}{cse:>8}{mark}"
        )
    a, t, e = result["achieved"], result["targets"], result["errors"]
    lines.append(
        f"friction angle {a['friction_angle']:.2f} deg (target {t['friction_angle']:g}, "
        f"{e['friction_angle_deg']:+.2f} deg)"
    )
    if e["cohesion_relative"] is not None:
        lines.append(f"cohesion {a['cohesion']:.0f} Pa (target {t['cohesion']:g}, {e['cohesion_relative']:+.0%})")
    if e["bulk_density_relative"] is not None:
        lines.append(
            f"bulk density {a['bulk_density']:.1f} kg/m^3 (target {t['bulk_density']:g}, "
            f"{e['bulk_density_relative']:+.1%})"
        )
    lines.append("set: " + " ".join(result["overrides"]))
    lines += [f"note: {n}" for n in result["notes"]]
    return lines


MAX_CALIBRATION_BYTES = 1 << 20  # a calibration.json is a few kB; it is read as untrusted input


def read_calibration(out: Path) -> dict[str, Any] | None:
    """The finished calibration in OUT (its calibration.json), or None."""
    from .runfiles import run_file

    path = run_file(out, CALIBRATION_JSON)  # a regular file inside OUT, never a link out of it
    return None if path is None else read_calibration_file(path)


def read_calibration_file(path: Path) -> dict[str, Any]:
    """A calibration.json, checked: an object whose "overrides" is an array of
    "section.key=value" strings (CalibrationError: one line)."""
    try:
        if path.stat().st_size > MAX_CALIBRATION_BYTES:
            raise CalibrationError(f"{path}: too large for a calibration (at most {MAX_CALIBRATION_BYTES} bytes)")
        result: dict[str, Any] = json.loads(path.read_bytes())
    except (OSError, ValueError, RecursionError) as e:
        raise CalibrationError(f"{path}: not a calibration ({type(e).__name__})") from None
    ov = result.get("overrides") if isinstance(result, dict) else None
    if not isinstance(ov, list) or not all(isinstance(x, str) and "=" in x for x in ov):
        raise CalibrationError(f"{path}: not a calibration (no list of overrides)")
    return result
