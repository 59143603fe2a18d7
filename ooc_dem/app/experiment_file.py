"""The experiment file of `ooc-dem experiment` (docs/reference/experiment.md): one TOML file
describing a single-wheel testbed experiment (the wheels, the slips, the conventions, the
soil's lab properties, the DEM choices and the measured points), read and checked into
frozen dataclasses. Every refusal is one line naming the file, the key and what is allowed.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import OocDemError
from ..model.schema import MAX_TEXT, NAME_ALLOWED, NAME_RE, show, show_key

MAX_EXPERIMENT_FILE = 1 << 20  # bytes
MAX_WHEELS = 16
MAX_POINTS = 200  # slips of one wheel (measured or run)
SLIP_RADII = ("rim", "lug_tip")
SINKAGE_REFERENCES = ("rim", "lug_tip")
MEASURED_QUANTITIES = ("drawbar_pull", "torque", "sinkage")


class ExperimentError(OocDemError, ValueError):
    """An experiment file, its values or its set-up is invalid (message is one line)."""


# ------------------------------------------------------------------- the file's parts


@dataclass(frozen=True)
class LabProperties:
    """[soil]: the soil's lab properties. friction_angle, cohesion and bulk_density are the
    calibration's targets; the Bekker and Janosi values are recorded in the report only."""

    friction_angle: float  # deg, Mohr-Coulomb (peak)
    cohesion: float = 0.0  # Pa
    bulk_density: float = 0.0  # kg/m^3 (0: not a target)
    bekker_n: float | None = None
    bekker_k_c: float | None = None  # N/m^(n+1)
    bekker_k_phi: float | None = None  # N/m^(n+2)
    janosi_k: float | None = None  # m, shear deformation modulus
    grading_sizes: tuple[float, ...] = ()  # m, sieve openings (the lab's grading, recorded)
    grading_passing: tuple[float, ...] = ()  # % by mass passing each


@dataclass(frozen=True)
class DemChoices:
    """[dem]: the DEM model the user chose for the experiment (docs/reference/experiment.md)."""

    base: str = "paper2008-3d"
    r_min: float = 0.0045  # m
    r_max: float = 0.0055  # m
    grading: tuple[tuple[str, Any], ...] = ()  # [dem.grading]: the scenario's soil.grading keys
    particle_density: float = 2650.0  # kg/m^3
    bin_length: float = 0.0  # m; 0: the rule (start_margin + travel + lug tip radius + end_margin)
    bin_width: float = 0.0  # m; 0: the widest wheel + 2 side_margin
    side_margin: float = 0.13  # m of soil beside each side of the wheel
    bed_depth: float = 0.10  # m
    start_margin: float = 0.03  # m of soil behind the lug tips at the start
    end_margin: float = 0.05  # m of soil ahead of the lug tips at the end of travel
    tile_size: float = 0.15  # m, the side of the settled tiles the bed is made of
    solid_fraction: float = 0.0  # of the settled bed; 0: bulk_density / particle_density, else 0.6
    dt: float = 0.0  # s; 0: the base scenario's
    omega: float = 1.0  # rad/s
    omega_note: str = ""
    settle_time: float = 0.5  # s, the wheel sinks in before travel (omega = 0)
    travel_time: float = 2.0  # s
    steady_start: float = 0.5  # s of travel
    steady_end: float = 0.0  # s of travel; 0: travel_time
    series_interval: float = 0.01  # s
    checkpoint_interval: float = 0.1  # s of simulated time between a run's committed epochs
    passages_per_block: int = 1  # lug passages per confidence-interval block
    block_time: float = 0.0  # s, a smooth wheel's block; 0: the lug period of the file's first lugged wheel
    overrides: tuple[str, ...] = ()
    calibrated: tuple[str, ...] | None = None  # the calibration's overrides, given (no calibration)
    calibrated_from: str = ""  # a calibration.json (or its directory) they were read from


@dataclass(frozen=True)
class CalibrationChoices:
    """[calibration]: the virtual tests the soil is calibrated with (app/calibrate.py's
    CalibrateOptions; its defaults where not given)."""

    grains: int = 2000  # grains in the shear box
    sigmas: tuple[float, ...] = (3.0e3, 6.0e3, 9.0e3, 12.0e3)  # Pa, the shear tests' normal stresses
    envelope: str = "peak"  # the Mohr-Coulomb line calibrated: "peak" or "residual"
    evaluations: int = 8  # shear tests at most
    vary: str = "friction"  # the soil-soil value searched for the friction angle (or "rolling_friction")


@dataclass(frozen=True)
class Conventions:
    slip_radius: str = "rim"  # s = 1 - v / (omega R), R the rim's or the lug tips' radius
    sinkage: str = "rim"  # the depth of the rim's or the lug tips' lowest point below the initial surface
    notes: str = ""


@dataclass(frozen=True)
class WheelSpec:
    name: str
    radius: float  # m, rim
    width: float  # m
    load: float  # N
    n_lugs: int = 0
    lug_height: float = 0.0  # m
    lug_thickness: float = 0.0  # m

    @property
    def tip_radius(self) -> float:
        return self.radius + (self.lug_height if self.n_lugs else 0.0)


@dataclass(frozen=True)
class Measured:
    """[measured.<wheel>]: the measured points (sinkage in mm, as papers give it)."""

    slip: tuple[float, ...]
    drawbar_pull: tuple[float, ...] | None = None  # N
    torque: tuple[float, ...] | None = None  # N m
    sinkage: tuple[float, ...] | None = None  # mm

    def at(self, quantity: str, slip: float) -> float | None:
        values = getattr(self, quantity)
        if values is None:
            return None
        for s, v in zip(self.slip, values):
            if abs(s - slip) < 1e-9:
                return float(v)
        return None


@dataclass(frozen=True)
class Experiment:
    name: str
    source: Path
    soil: LabProperties
    dem: DemChoices
    conventions: Conventions
    wheels: tuple[WheelSpec, ...]
    measured: tuple[tuple[str, Measured], ...]
    reference: str = ""
    notes: str = ""
    slips: tuple[float, ...] = ()  # run at these slips; empty: each wheel's measured slips
    calibration: CalibrationChoices = CalibrationChoices()

    def measured_of(self, wheel: str) -> Measured | None:
        return dict(self.measured).get(wheel)

    def slips_of(self, wheel: str) -> tuple[float, ...]:
        if self.slips:
            return self.slips
        m = self.measured_of(wheel)
        return m.slip if m is not None else ()


# ----------------------------------------------------------------------- checking

Check = Callable[[Any], bool]
_NUM = (float,)


def _num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


class _Table:
    """One table of the file, its keys taken one by one; unknown keys refused at the end."""

    def __init__(self, src: str, where: str, data: Any, allowed: tuple[str, ...]):
        if not isinstance(data, dict):
            raise ExperimentError(f"{src}: {where} = {show(data)}: must be a table")
        unknown = sorted(set(data) - set(allowed))
        if unknown:
            raise ExperimentError(f"{src}: {where}.{show_key(unknown[0])}: unknown key (allowed: {', '.join(allowed)})")
        self.src, self.where, self.data = src, where, data

    def fail(self, key: str, allowed: str) -> ExperimentError:
        return ExperimentError(f"{self.src}: {self.where}.{key} = {show(self.data[key])}: must be {allowed}")

    def number(self, key: str, default: float | None, check: Check = _num, allowed: str = "a number") -> float:
        if key not in self.data:
            if default is None:
                raise ExperimentError(f"{self.src}: {self.where}.{key}: missing (must be {allowed})")
            return default
        v = self.data[key]
        if not _num(v) or not check(v):
            raise self.fail(key, allowed)
        return float(v) + 0.0

    def optional(self, key: str, check: Check, allowed: str) -> float | None:
        return self.number(key, None, check, allowed) if key in self.data else None

    def integer(self, key: str, default: int, lo: int, hi: int) -> int:
        v = self.data.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise self.fail(key, f"an integer in [{lo}, {hi}]")
        return v

    def text(self, key: str, default: str, choices: tuple[str, ...] = ()) -> str:
        v = self.data.get(key, default)
        if not isinstance(v, str) or len(v) > MAX_TEXT or (choices and v not in choices):
            raise self.fail(key, f"one of {', '.join(map(repr, choices))}" if choices else "a string")
        return v

    def numbers(self, key: str, check: Check, allowed: str) -> tuple[float, ...] | None:
        if key not in self.data:
            return None
        v = self.data[key]
        if not isinstance(v, list) or not 1 <= len(v) <= MAX_POINTS or not all(_num(x) and check(x) for x in v):
            raise self.fail(key, f"an array of 1 to {MAX_POINTS} numbers, each {allowed}")
        return tuple(float(x) + 0.0 for x in v)

    def strings(self, key: str) -> tuple[str, ...]:
        v = self.data.get(key, [])
        if not isinstance(v, list) or len(v) > 1000 or not all(isinstance(x, str) and "=" in x for x in v):
            raise self.fail(key, 'an array of "section.key=value" strings')
        return tuple(v)


_POS = (lambda v: v > 0, "a number > 0")
_NONNEG = (lambda v: v >= 0, "a number >= 0")
_SLIP = (lambda v: 0 <= v < 1, "a slip in [0, 1)")

_TOP = ("experiment", "soil", "dem", "calibration", "conventions", "wheel", "measured")
_CALIBRATION = ("grains", "sigmas", "envelope", "evaluations", "vary")
_EXPERIMENT = ("name", "reference", "notes", "slips")
_SOIL = (
    "friction_angle",
    "cohesion",
    "bulk_density",
    "bekker_n",
    "bekker_k_c",
    "bekker_k_phi",
    "janosi_k",
    "grading",
)
_DEM = tuple(
    k for k in DemChoices.__dataclass_fields__ if k not in ("calibrated_from",)
)  # the keys of [dem] are DemChoices' fields
_CONVENTIONS = ("slip_radius", "sinkage", "notes")
_WHEEL = ("name", "radius", "width", "load", "n_lugs", "lug_height", "lug_thickness")
_MEASURED = ("slip", *MEASURED_QUANTITIES)


def load_experiment(path: str | Path) -> Experiment:
    """The experiment file at ``path``, read and checked (ExperimentError: one line)."""
    p = Path(path)
    src = show(str(p), 200)
    try:
        size = p.stat().st_size if p.is_file() else -1
    except (OSError, ValueError):
        size = -1
    if size < 0:
        raise ExperimentError(f"experiment file {src}: no such file")
    if size > MAX_EXPERIMENT_FILE:
        raise ExperimentError(f"experiment file {src}: {size} bytes; at most {MAX_EXPERIMENT_FILE}")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError, ValueError) as e:
        first = (str(e).splitlines() or [type(e).__name__])[0]
        raise ExperimentError(f"experiment file {src}: invalid TOML ({first})") from None
    return experiment_from_dict(data, p)


def experiment_from_dict(data: dict[str, Any], path: Path) -> Experiment:
    src = show(str(path), 200)
    unknown = sorted(set(data) - set(_TOP))
    if unknown:
        raise ExperimentError(f"{src}: [{show_key(unknown[0])}]: unknown section (allowed: {', '.join(_TOP)})")
    for sec in ("experiment", "soil", "wheel"):
        if sec not in data:
            raise ExperimentError(f"{src}: no [{sec}]{' entries ([[wheel]])' if sec == 'wheel' else ''}")

    e = _Table(src, "[experiment]", data["experiment"], _EXPERIMENT)
    name = e.text("name", "")
    if NAME_RE.fullmatch(name) is None:
        raise ExperimentError(f"{src}: [experiment].name = {show(name)}: must be {NAME_ALLOWED}")
    slips = e.numbers("slips", *_SLIP) or ()
    if len(set(slips)) != len(slips):
        raise ExperimentError(f"{src}: [experiment].slips: a slip is given twice")

    soil = _lab_soil(src, data["soil"])
    dem = _dem(src, data.get("dem", {}), path)
    k = _Table(src, "[calibration]", data.get("calibration", {}), _CALIBRATION)
    d0 = CalibrationChoices()
    sigmas = k.numbers("sigmas", *_POS) or d0.sigmas
    if len(sigmas) < 2 or len(set(sigmas)) != len(sigmas):
        raise ExperimentError(f"{src}: [calibration].sigmas: at least two distinct normal stresses (Pa)")
    calibration = CalibrationChoices(
        grains=k.integer("grains", d0.grains, 200, 1_000_000),
        sigmas=sigmas,
        envelope=k.text("envelope", d0.envelope, ("peak", "residual")),
        evaluations=k.integer("evaluations", d0.evaluations, 2, 50),
        vary=k.text("vary", d0.vary, ("friction", "rolling_friction")),
    )
    c = _Table(src, "[conventions]", data.get("conventions", {}), _CONVENTIONS)
    conventions = Conventions(
        slip_radius=c.text("slip_radius", "rim", SLIP_RADII),
        sinkage=c.text("sinkage", "rim", SINKAGE_REFERENCES),
        notes=c.text("notes", ""),
    )

    entries = data["wheel"]
    if not isinstance(entries, list) or not 1 <= len(entries) <= MAX_WHEELS:
        raise ExperimentError(f"{src}: [[wheel]]: must be 1 to {MAX_WHEELS} [[wheel]] tables")
    wheels = tuple(_wheel(src, k, w) for k, w in enumerate(entries))
    names = [w.name for w in wheels]
    if len(set(names)) != len(names):
        raise ExperimentError(f"{src}: [[wheel]]: two wheels are named {show(names[0])}; names must differ")
    if len(name) + 1 + max(map(len, names)) > 100:
        raise ExperimentError(f"{src}: [experiment].name and a wheel's name make a run name over 100 characters")

    measured_tab = data.get("measured", {})
    if not isinstance(measured_tab, dict):
        raise ExperimentError(f"{src}: [measured] = {show(measured_tab)}: must be a table of [measured.<wheel>]")
    measured = []
    for wname, table in measured_tab.items():
        if wname not in names:
            raise ExperimentError(
                f"{src}: [measured.{show_key(wname)}]: no [[wheel]] of that name (wheels: {', '.join(names)})"
            )
        measured.append((wname, _measured(src, wname, table)))
    exp = Experiment(
        name=name,
        source=path,
        soil=soil,
        dem=dem,
        conventions=conventions,
        wheels=wheels,
        measured=tuple(measured),
        reference=e.text("reference", ""),
        notes=e.text("notes", ""),
        slips=slips,
        calibration=calibration,
    )
    for w in wheels:
        if not exp.slips_of(w.name):
            raise ExperimentError(
                f"{src}: wheel {w.name!r}: no slips to run (give [experiment].slips or [measured.{w.name}].slip)"
            )
    if not any(w.n_lugs for w in wheels) and dem.block_time == 0.0:
        raise ExperimentError(
            f"{src}: [dem].block_time: no wheel has lugs, so the statistics' block must be given (s, > 0)"
        )
    return exp


def _lab_soil(src: str, data: Any) -> LabProperties:
    t = _Table(src, "[soil]", data, _SOIL)
    sizes: tuple[float, ...] = ()
    passing: tuple[float, ...] = ()
    if "grading" in t.data:
        g = _Table(src, "[soil.grading]", t.data["grading"], ("sizes", "passing"))
        sizes = g.numbers("sizes", *_POS) or ()
        passing = g.numbers("passing", lambda v: 0 <= v <= 100, "a percentage in [0, 100]") or ()
        if len(sizes) != len(passing) or any(b <= a for a, b in zip(sizes, sizes[1:])):
            raise ExperimentError(
                f"{src}: [soil.grading]: sizes (increasing, m) and passing (%) must be arrays of the same length"
            )
    return LabProperties(
        friction_angle=t.number("friction_angle", None, lambda v: 0 < v < 90, "an angle in (0, 90) degrees"),
        cohesion=t.number("cohesion", 0.0, *_NONNEG),
        bulk_density=t.number("bulk_density", 0.0, *_NONNEG),
        bekker_n=t.optional("bekker_n", *_POS),
        bekker_k_c=t.optional("bekker_k_c", _num, "a number"),
        bekker_k_phi=t.optional("bekker_k_phi", _num, "a number"),
        janosi_k=t.optional("janosi_k", *_POS),
        grading_sizes=sizes,
        grading_passing=passing,
    )


def _dem(src: str, data: Any, path: Path) -> DemChoices:
    t = _Table(src, "[dem]", data, _DEM)
    d = DemChoices()
    grading: tuple[tuple[str, Any], ...] = ()
    if "grading" in t.data:
        if not isinstance(t.data["grading"], dict):
            raise t.fail("grading", "a table of soil.grading keys (docs/reference/grading.md)")
        # checked with the scenario (model/scenario_check.py), which names soil.grading.<key>
        grading = tuple(sorted(t.data["grading"].items()))
    calibrated: tuple[str, ...] | None = None
    calibrated_from = ""
    if "calibrated" in t.data:
        v = t.data["calibrated"]
        if isinstance(v, str):
            calibrated_from = str((path.parent / v) if not Path(v).is_absolute() else Path(v))
            calibrated = read_calibrated_overrides(Path(calibrated_from), f"{src}: [dem].calibrated")
        else:
            calibrated = t.strings("calibrated")
    r_min = t.number("r_min", d.r_min, *_POS)
    r_max = t.number("r_max", d.r_max, *_POS)
    if r_max < r_min:
        raise ExperimentError(f"{src}: [dem].r_max = {r_max!r}: must be >= [dem].r_min ({r_min!r})")
    travel = t.number("travel_time", d.travel_time, *_POS)
    steady_start = t.number("steady_start", d.steady_start, *_NONNEG)
    steady_end = t.number("steady_end", 0.0, *_NONNEG) or travel
    if not steady_start < steady_end <= travel:
        raise ExperimentError(
            f"{src}: [dem].steady_start = {steady_start!r}, steady_end = {steady_end!r}: the steady window must "
            f"lie in the travel (0 <= steady_start < steady_end <= travel_time = {travel!r})"
        )
    return DemChoices(
        base=t.text("base", d.base),
        r_min=r_min,
        r_max=r_max,
        grading=grading,
        particle_density=t.number("particle_density", d.particle_density, *_POS),
        bin_length=t.number("bin_length", 0.0, *_NONNEG),
        bin_width=t.number("bin_width", 0.0, *_NONNEG),
        side_margin=t.number("side_margin", d.side_margin, *_NONNEG),
        bed_depth=t.number("bed_depth", d.bed_depth, *_POS),
        start_margin=t.number("start_margin", d.start_margin, *_NONNEG),
        end_margin=t.number("end_margin", d.end_margin, *_NONNEG),
        tile_size=t.number("tile_size", d.tile_size, *_POS),
        solid_fraction=t.number(
            "solid_fraction", 0.0, lambda v: v == 0 or 0.3 <= v <= 0.74, "0 (from the bulk density) or in [0.3, 0.74]"
        ),
        dt=t.number("dt", 0.0, *_NONNEG),
        omega=t.number("omega", d.omega, lambda v: 0 < v <= 1000, "a number in (0, 1000] rad/s"),
        omega_note=t.text("omega_note", ""),
        settle_time=t.number("settle_time", d.settle_time, *_NONNEG),
        travel_time=travel,
        steady_start=steady_start,
        steady_end=steady_end,
        series_interval=t.number("series_interval", d.series_interval, *_POS),
        checkpoint_interval=t.number("checkpoint_interval", d.checkpoint_interval, *_POS),
        passages_per_block=t.integer("passages_per_block", 1, 1, 1000),
        block_time=t.number("block_time", 0.0, *_NONNEG),
        overrides=t.strings("overrides"),
        calibrated=calibrated,
        calibrated_from=calibrated_from,
    )


def read_calibrated_overrides(path: Path, where: str) -> tuple[str, ...]:
    """The overrides of a finished calibration: its calibration.json (or the directory
    holding one), whose "overrides" is an array of "section.key=value" strings."""
    from .calibrate import CalibrationError, read_calibration_file

    f = path / "calibration.json" if path.is_dir() else path
    try:
        ov = read_calibration_file(f)["overrides"] if f.is_file() else None
    except CalibrationError:
        ov = None
    if ov is None:
        raise ExperimentError(
            f"{where} = {show(str(path), 200)}: not a calibration.json (or a directory holding one) with "
            f'"overrides": ["section.key=value", ...]'
        )
    return tuple(ov)


def _wheel(src: str, k: int, data: Any) -> WheelSpec:
    t = _Table(src, f"[[wheel]] {k + 1}", data, _WHEEL)
    name = t.text("name", "")
    if NAME_RE.fullmatch(name) is None:
        raise ExperimentError(f"{src}: [[wheel]] {k + 1}.name = {show(name)}: must be {NAME_ALLOWED}")
    t.where = f"[[wheel]] {name!r}"
    n_lugs = t.integer("n_lugs", 0, 0, 360)
    w = WheelSpec(
        name=name,
        radius=t.number("radius", None, *_POS),
        width=t.number("width", None, *_POS),
        load=t.number("load", None, *_POS),
        n_lugs=n_lugs,
        lug_height=t.number("lug_height", 0.0, *_NONNEG),
        lug_thickness=t.number("lug_thickness", 0.0, *_NONNEG),
    )
    if n_lugs and (w.lug_height <= 0 or w.lug_thickness <= 0):
        raise ExperimentError(
            f"{src}: {t.where}: n_lugs = {n_lugs} needs lug_height and lug_thickness > 0 (m; state the thickness "
            f"if the source does not)"
        )
    if not n_lugs and (w.lug_height or w.lug_thickness):
        raise ExperimentError(f"{src}: {t.where}: a smooth wheel (n_lugs = 0) has no lug_height or lug_thickness")
    return w


def _measured(src: str, wheel: str, data: Any) -> Measured:
    t = _Table(src, f"[measured.{wheel}]", data, _MEASURED)
    slip = t.numbers("slip", lambda v: -1 < v < 1, "a slip in (-1, 1)")
    if slip is None:
        raise ExperimentError(f"{src}: [measured.{wheel}].slip: missing (the slips of the measured points)")
    if len(set(slip)) != len(slip):
        raise ExperimentError(f"{src}: [measured.{wheel}].slip: a slip is given twice")
    values = {q: t.numbers(q, _num, "a number") for q in MEASURED_QUANTITIES}
    for q, v in values.items():
        if v is not None and len(v) != len(slip):
            raise ExperimentError(
                f"{src}: [measured.{wheel}].{q}: {len(v)} values for {len(slip)} slips (one per slip)"
            )
    return Measured(slip=slip, **values)
