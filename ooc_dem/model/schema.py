"""The scenario's schema: its sections as frozen dataclasses with their defaults, the
Scenario with its hashes, the limits every value is checked against, ScenarioError and the
helpers of its one-line messages, and the TOML a scenario is stored as.

Checking the values is model/scenario_check.py's, loading them model/scenario.py's.
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import json
import re
from dataclasses import dataclass
from collections.abc import Iterable
from typing import Any, TypeVar

from ..errors import OocDemError


class ScenarioError(OocDemError, ValueError):
    """A scenario value, file or override is invalid (message is one line)."""


# Every step count a run derives (from durations, --steps, --duration, --until) is at most
# this: 1e10 steps is 2000 x paper2008's 4.6 M steps, months of wall time at any size, so a
# larger count is a typo; it also keeps every step number far inside int64 in the kernels.
MAX_STEPS = 10**10
# bounds of decomposition.domains / --domains and decomposition.block / --block
MAX_DOMAINS = 4096
MAX_BLOCK = 10000
# bound of physics.history_capacity (and of a stored run's capacity read on resume): a
# particle's history is this many slots in RAM, so a typo must not allocate gigabytes
MAX_HIST_CAP = 64
# scenario.name becomes the default output directory runs/<name>: one safe path component
NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]{0,99}")
NAME_ALLOWED = "1-100 letters, digits and _ . + - (not starting with . + or -; it names runs/<name>)"
MAX_TEXT = 10_000  # characters of a string value (descriptions end up in every manifest)
MAX_SCENARIO_FILE = 1 << 20  # bytes of a scenario TOML file


def show(value: Any, limit: int = 60) -> str:
    """A value as it may appear in a one-line message: never recursive, never long,
    never an int-to-decimal conversion past Python's digit limit."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return repr(value) if value.bit_length() <= 200 else f"<an integer of {value.bit_length()} bits>"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        r = repr(value)
        return r if len(r) <= limit else r[: limit - 4] + "...'"
    if isinstance(value, dict):
        return "<a table>"
    if isinstance(value, list):
        return "<an array>"
    if isinstance(value, tuple):  # a coerced array of numbers (soil.grading.sizes)
        shown = ", ".join(show(v) for v in value[:6])
        return f"[{shown}{', ...' if len(value) > 6 else ''}]"
    return f"<a {type(value).__name__}>"


def show_key(key: str) -> str:
    """A key as it may appear in a one-line message (a plain key as itself)."""
    return key if re.fullmatch(r"[A-Za-z0-9_-]{1,40}", key) else show(key, 40)


def did_you_mean(word: object, choices: Iterable[str]) -> str:
    """'; did you mean 'x'?' for the choice closest to a mistyped word (difflib), or ''."""
    if not isinstance(word, str) or len(word) > 200:
        return ""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def big(n: int) -> str:
    """A large round count as people write it: 1e10, 2e9."""
    return f"{n:.0e}".replace("e+0", "e").replace("e+", "e")


def steps_for_duration(seconds: float, dt: float, what: str) -> int:
    """round(seconds / dt), refused (naming ``what``) unless finite and at most MAX_STEPS."""
    n = seconds / dt  # float division: inf on overflow, never an exception (dt > 0)
    if not (0.0 <= n <= MAX_STEPS):
        raise ScenarioError(
            f"{what}: {show(seconds)} s at physics.dt = {dt!r} s is {n:.3g} steps, "
            f"more than the maximum {big(MAX_STEPS)}"
        )
    return int(round(n))


# ---------------------------------------------------------------- sections
# Every key is declared with key(default, unit, meaning): the unit ("" for a pure number or
# a word) and a short meaning are what docs/parameters.md (tools/gen_parameters_doc.py) and
# `ooc-dem scenarios --show` print beside it; its allowed range is scenario_check's.

_T = TypeVar("_T")


def key(default: _T, unit: str, meaning: str) -> _T:
    """A section's key: its default, with its unit and meaning as the field's metadata."""
    return dataclasses.field(default=default, metadata={"unit": unit, "meaning": meaning})


def key_doc(f: dataclasses.Field[Any]) -> tuple[str, str]:
    """(unit, meaning) of a section's key."""
    return f.metadata.get("unit", ""), f.metadata.get("meaning", "")


@dataclass(frozen=True)
class Meta:
    name: str = key("unnamed", "", "the scenario's name; runs go to runs/<name> unless --out says otherwise")
    description: str = key("", "", "one line saying what the scenario is")


@dataclass(frozen=True)
class Physics:
    gravity: float = key(9.80, "m/s^2", "gravitational acceleration, acts in -y")
    thickness: float = key(0.10, "m", "2D: discs are cylinders of this length (the slice thickness)")
    dt: float = key(1.0e-5, "s", "time step; refused above the critical step of the stiffest contact")
    contacts_per_disc: float = key(4.0, "", "contacts per particle assumed by the critical-step check")
    dim: int = key(2, "", "2: discs in the x-y plane; 3: spheres (z across the bin)")
    impact_speed: float = key(1.0, "m/s", "largest expected impact speed (3D Hertz time-step check)")
    history_capacity: int = key(
        0, "", "contacts a particle may hold (0: 8 in 2D, 12 in 3D; never changes a result bit)"
    )


@dataclass(frozen=True)
class Bin:
    length: float = key(0.60, "m", "length of the bin along the travel (x); end walls at 0 and length")
    height: float = key(0.40, "m", "top of the neighbour grid (the bin is open at the top)")
    width: float = key(0.10, "m", "3D: width across the bin (z); side walls at z = 0 and width")


@dataclass(frozen=True)
class SoilGrading:
    """How the radii are drawn between soil.r_min and soil.r_max (model/grading.py,
    docs/reference/grading.md); each kind reads only its own keys."""

    kind: str = key("uniform", "", "radius distribution: uniform, normal, lognormal or sieve")
    r_mean: float = key(0.0, "m", "normal: mean radius")
    r_std: float = key(0.0, "m", "normal: standard deviation of the radius")
    r_median: float = key(0.0, "m", "lognormal: median radius")
    gsd: float = key(0.0, "", "lognormal: geometric standard deviation of the radius (> 1)")
    sizes: tuple[float, ...] = key((), "m", "sieve: openings (diameters), increasing")
    passing: tuple[float, ...] = key((), "%", "sieve: percent by mass passing each opening")


@dataclass(frozen=True)
class Soil:
    n: int = key(6986, "", "number of grains (discs or spheres)")
    r_min: float = key(0.0018, "m", "smallest grain radius")
    r_max: float = key(0.0022, "m", "largest grain radius")
    density: float = key(2650.0, "kg/m^3", "grain (solid) density")
    seed: int = key(2008, "", "random seed of the bed's radii and fill")
    grading: SoilGrading = key(SoilGrading(), "", "how the radii are drawn between r_min and r_max")


@dataclass(frozen=True)
class Bed:
    settle_speed: float = key(1.0e-4, "m/s", "mean grain speed that ends the bed's settling")
    max_settle_time: float = key(5.0, "s", "a bed not settled by then is refused")
    tile: int = key(0, "", ">0: build the bed by tiling a settled tile of this many grains")
    skin: float = key(0.0006, "m", "Verlet skin of the neighbour lists (speed only; never a result bit)")
    tiles_across: int = key(1, "", "3D tiled beds: tiles across the width (z)")
    # soil-soil friction while the bed is poured (< 0: the contact's own): lower pours denser
    fill_friction: float = key(-1.0, "", "soil-soil friction while the bed is poured (-1: the contact's own)")


@dataclass(frozen=True)
class ContactPair:
    kn: float = key(2.0e5, "N/m", "linear law: normal stiffness")
    ks: float = key(2.0e5 / 3.0, "N/m", "linear law: tangential stiffness")
    damping_n: float = key(1.0, "", "linear law: normal damping, ratio of critical (reduced mass)")
    damping_t: float = key(1.0, "", "linear law: tangential damping, ratio of critical")
    friction: float = key(0.5, "", "Coulomb friction coefficient")
    rolling_friction: float = key(0.0, "", "rolling resistance: limit mu_r * r_eff * Fn")
    rolling_damping: float = key(0.0, "", "rolling damping, ratio of critical")
    law: str = key("linear", "", "linear (kn, ks, damping_*) or hertz (3D: Hertz-Mindlin)")
    youngs_modulus: float = key(1.0e7, "Pa", "hertz: Young's modulus of both surfaces of the pair")
    poisson_ratio: float = key(0.3, "", "hertz: Poisson's ratio")
    restitution: float = key(
        0.5, "", "hertz: restitution coefficient (sets the damping); linear: sets damping_n if that is not given"
    )
    youngs_modulus_2: float = key(0.0, "Pa", "hertz: the second surface (wall, wheel); 0: the same as the first")
    poisson_ratio_2: float = key(0.0, "", "hertz: the second surface's; unused with youngs_modulus_2 = 0")
    cohesion: float = key(0.0, "J/m^3", "simplified-JKR cohesion energy density (0: none)")
    # clamp the normal force at zero (the damping cannot pull); unset: default_no_tension(law)
    no_tension: bool | None = key(None, "", "clamp the normal force at zero (unset: on for linear, off for hertz)")


@dataclass(frozen=True)
class Contacts:
    soil_soil: ContactPair = key(
        ContactPair(rolling_friction=0.10, rolling_damping=0.3), "", "contacts between two grains"
    )
    soil_wall: ContactPair = key(ContactPair(), "", "contacts of a grain with the floor and the bin's walls")
    soil_wheel: ContactPair = key(ContactPair(friction=0.4), "", "contacts of a grain with the wheel (rim, lugs)")


@dataclass(frozen=True)
class Wheel:
    enabled: bool = key(True, "", "a wheel run (false: a bare bed)")
    radius: float = key(0.100, "m", "rim radius")
    width: float = key(0.100, "m", "3D: the wheel's width (z)")
    load: float = key(19.6, "N", "dead weight (mass = load / gravity)")
    n_lugs: int = key(18, "", "number of lugs")
    lug_tip_radius: float = key(0.110, "m", "radius of the lugs' outermost point (lug height = this - radius)")
    lug_thickness: float = key(0.002, "m", "lug thickness (capsule diameter)")
    x0: float = key(0.15, "m", "initial centre along the bin")
    drop_gap: float = key(0.002, "m", "gap between the lug tips and the bed's surface at placement")
    omega: float = key(0.138, "rad/s", "angular speed, clockwise (drives in +x)")
    control: str = key(
        "drawbar",
        "",
        "drawbar (omega prescribed, x free under a drawbar load), slip (omega and forward speed prescribed), "
        "torque (omega free under a driving torque) or towed (omega free, no torque, the carriage at wheel.speed)",
    )
    drawbar_load: float = key(10.0, "N", "drawbar load opposing the travel")
    drawbar_ramp: float = key(1.0, "s", "time over which the drawbar load ramps up")
    slip: float = key(0.0, "", "prescribed slip when control = slip (negative: braking, the carriage outruns the rim)")
    torque: float = key(
        0.0, "N m", "control = torque: driving torque about the axle (clockwise positive: drives in +x)"
    )
    torque_ramp: float = key(1.0, "s", "control = torque: time over which the driving torque ramps up")
    inertia: float = key(
        0.0,
        "kg m^2",
        "moment of inertia about the axle when omega is free (0: a uniform disc, mass radius^2 / 2; "
        "a mesh wheel: its solid holding the mass uniformly)",
    )
    carriage: str = key(
        "drawbar", "", "control = torque: the carriage free under the drawbar load (drawbar) or at wheel.speed (speed)"
    )
    speed: float = key(0.0, "m/s", "the carriage's forward speed (control = towed; torque with carriage = speed)")
    vertical: str = key(
        "free", "", "free (the axle carries the load) or fixed (its height held from the end of settling)"
    )
    settle_time: float = key(1.0, "s", "settling before travel: omega = 0, x held")
    travel_time: float = key(45.0, "s", "travel after settling")
    z0: float = key(0.0, "m", "3D: lateral centre of the wheel (0: the bin's mid-width)")
    mesh: str = key(
        "",
        "",
        "3D: the wheel's surface as a triangle mesh file (STL or OBJ; a relative path is taken from the "
        "scenario file's directory), replacing the rim and lugs for the contact (docs/reference/mesh-wheel.md); "
        "empty: the built-in wheel",
    )
    mesh_scale: float = key(1.0, "m/unit", "metres per mesh unit (0.001: a mesh in millimetres)")
    mesh_rotate: tuple[float, ...] = key(
        (), "deg", "the mesh's rotation into the wheel's frame (axle along z): angles about x, y, z, in that order"
    )
    mesh_offset: tuple[float, ...] = key((), "m", "the mesh's translation after the rotation (x, y, z)")
    outline: str | tuple = key(
        "",
        "m",
        "2D: the wheel as a closed counter-clockwise polyline in its body frame (axle at the origin), "
        "replacing the rim and lugs for the contact: an array of [x, y] or a file of 'x y' lines "
        "(relative to the scenario file); empty: the built-in wheel (docs/physics.md)",
    )


@dataclass(frozen=True)
class Output:
    series_interval: float = key(0.01, "s", "time-series row interval (means over it)")
    steady_start: float = key(9.6, "s", "start of the steady window, in seconds of travel")
    steady_end: float = key(45.0, "s", "end of the steady window, in seconds of travel")
    run_steps: int = key(0, "", "bare beds: `run`'s default step count")
    snapshot_interval: float = key(0.0, "s", "trajectory frame interval (RUN/trajectory/); 0: none")


@dataclass(frozen=True)
class Decomposition:
    policy: str = key("wheel", "", "slab boundaries: wheel (the paper's) or equal")
    domains: int = key(6, "", "number of sub-domains D (ddm, ooc)")
    block: int = key(1, "", "temporal blocking K: steps per epoch")
    margin: float = key(0.01, "m", "wheel slab margin beyond the lug tips")


@dataclass(frozen=True)
class Repose:
    """Angle-of-repose test (3D, docs/reference/repose3d.md): the settled column of
    ``soil.n`` spheres, a cylinder of ``column_radius`` standing on the floor at the bin's
    centre, is released at step 0; its heap's flank angle is measured at the end."""

    enabled: bool = key(False, "", "release the settled column and measure its heap's angle")
    column_radius: float = key(0.02, "m", "radius of the released column (2D: half its width)")
    fit_low: float = key(0.2, "", "flank fit from this fraction of the heap height ...")
    fit_high: float = key(0.8, "", "... to this one")
    sectors: int = key(8, "", "3D: azimuthal sectors, one profile and one fit each")
    bin_width: float = key(0.005, "m", "radial bins of the surface profile (2D: bins along x)")


@dataclass(frozen=True)
class Scenario:
    scenario: Meta = key(Meta(), "", "the scenario's name and description")
    physics: Physics = key(Physics(), "", "gravity, time step and dimension")
    bin: Bin = key(Bin(), "", "the soil bin")
    soil: Soil = key(Soil(), "", "the grains")
    bed: Bed = key(Bed(), "", "how the bed is poured and settled")
    contact: Contacts = key(Contacts(), "", "the contact law of each pair of bodies")
    wheel: Wheel = key(Wheel(), "", "the lugged wheel")
    output: Output = key(Output(), "", "what a run records")
    decomposition: Decomposition = key(Decomposition(), "", "sub-domains and blocking of ddm and ooc")
    repose: Repose = key(Repose(), "", "the angle-of-repose test")

    # ---- derived values
    @property
    def name(self) -> str:
        return self.scenario.name

    @property
    def dim(self) -> int:
        """Dimension of the model (physics.dim: 2, discs in the x-y plane; 3, spheres)."""
        return self.physics.dim

    @property
    def hist_cap(self) -> int:
        """Contact-history capacity per particle (physics.history_capacity, else the
        dimension's default: state.HIST_CAP_BY_DIM)."""
        from .state import default_hist_cap

        return self.physics.history_capacity or default_hist_cap(self.dim)

    @property
    def gravity_vector(self) -> tuple[float, ...]:
        """Gravity as a dim-vector along -y (physics.layout.AX_Y)."""
        from ..physics.layout import AX_Y

        g = [0.0] * self.dim
        g[AX_Y] = -self.physics.gravity
        return tuple(g)

    @property
    def wheel_mass(self) -> float:
        return self.wheel.load / self.physics.gravity

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def to_toml(self) -> str:
        return dict_to_toml(self.to_dict())

    def _hash_dict(self) -> dict:
        """to_dict() without the keys added for 3D (and [soil.grading]) while they hold their
        defaults (so a 2D scenario keeps the hash and bed cache name it had before they existed)."""
        d = self.to_dict()
        for (sec, key), default in _HASH_NEUTRAL.items():
            if d[sec].get(key) == default:
                del d[sec][key]
        for pair in d["contact"].values():
            if pair.get("no_tension") in (None, default_no_tension(pair.get("law", "linear"))):
                pair.pop("no_tension", None)
            for key, neutral in _PAIR_HASH_NEUTRAL.items():
                if pair.get(key) == neutral:
                    del pair[key]
        if d["repose"] == dataclasses.asdict(Repose()):  # added with repose3d
            del d["repose"]
        return d

    def hash(self) -> str:
        """SHA-256 of the physics-relevant content (output settings excluded)."""
        d = self._hash_dict()
        d.pop("output", None)
        d["scenario"].pop("description", None)
        # how the heap is measured is not what it does: only the other [repose] keys count,
        # and only when one of them is not at its default
        physical = lambda rp: {k: v for k, v in rp.items() if k not in REPOSE_MEASUREMENT_KEYS}
        rp = physical(d.pop("repose", {}))
        if rp and rp != physical(dataclasses.asdict(Repose())):
            d["repose"] = rp
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()

    def bed_hash(self) -> str:
        """Hash of what determines the settled bed (cache key)."""
        d = self._hash_dict()
        keep = {k: d[k] for k in ("physics", "bin", "soil", "bed")}
        keep["contact"] = d["contact"]
        if self.repose.enabled:  # the settled column is cut to this radius
            keep["repose"] = {"column_radius": self.repose.column_radius}
        return hashlib.sha256(json.dumps(keep, sort_keys=True).encode()).hexdigest()[:16]


# keys whose default value is left out of the hashes (added with the 3D engine and later)
_HASH_NEUTRAL = {
    ("physics", "dim"): 2,
    ("physics", "impact_speed"): 1.0,
    ("bin", "width"): 0.10,
    ("bed", "tiles_across"): 1,
    ("physics", "history_capacity"): 0,
    ("wheel", "z0"): 0.0,
    ("soil", "grading"): dataclasses.asdict(SoilGrading()),  # added with gradings
    ("bed", "fill_friction"): -1.0,
    ("wheel", "torque"): 0.0,  # added with the free-spin controls and the fixed carriage height
    ("wheel", "torque_ramp"): 1.0,
    ("wheel", "inertia"): 0.0,
    ("wheel", "carriage"): "drawbar",
    ("wheel", "speed"): 0.0,
    ("wheel", "vertical"): "free",
    ("wheel", "mesh"): "",  # added with mesh wheels
    ("wheel", "mesh_scale"): 1.0,
    ("wheel", "mesh_rotate"): (),
    ("wheel", "mesh_offset"): (),
    ("wheel", "outline"): "",  # added with outline wheels
}
_PAIR_HASH_NEUTRAL = {
    "law": "linear",
    "youngs_modulus": 1.0e7,
    "poisson_ratio": 0.3,
    "restitution": 0.5,
    "youngs_modulus_2": 0.0,
    "poisson_ratio_2": 0.0,
    "cohesion": 0.0,
}


def default_no_tension(law: str) -> bool:
    """The no-tension clamp a pair has unless it says: on for the linear law (the paper's),
    off for Hertz (its Tsuji damping then gives exactly the stated restitution)."""
    return law != "hertz"


def clamps(pair: ContactPair) -> bool:
    """Whether the pair's normal force is clamped at zero (its no_tension, else the law's default)."""
    return default_no_tension(pair.law) if pair.no_tension is None else pair.no_tension


LAWS = ("linear", "hertz")
# wheel.control: omega prescribed (drawbar, slip) or free (torque, towed)
WHEEL_CONTROLS = ("drawbar", "slip", "torque", "towed")
REPOSE_MEASUREMENT_KEYS = ("fit_low", "fit_high", "sectors", "bin_width")


def toml_string(text: str) -> str:
    """A TOML basic string for any text: quote, backslash and control characters escaped,
    everything else written as itself (UTF-8). JSON's \\uD83D surrogate pairs are not TOML."""
    out = ['"']
    for ch in text:
        code = ord(ch)
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif code < 0x20 or code == 0x7F:
            out.append(f"\\u{code:04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def dict_to_toml(d: dict) -> str:
    """Minimal TOML writer for the scenario tree (tables of scalars and arrays of them)."""
    lines: list[str] = []

    def scalar(v):
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(scalar(x) for x in v) + "]"
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return repr(v)
        if isinstance(v, int):
            return str(v)
        return toml_string(str(v))

    def emit(prefix, table):
        # an unset optional key (None) is not written: absent, it reads back as unset
        scal = {k: v for k, v in table.items() if not isinstance(v, dict) and v is not None}
        subs = {k: v for k, v in table.items() if isinstance(v, dict)}
        if prefix and scal:
            lines.append(f"[{prefix}]")
        for k, v in scal.items():
            lines.append(f"{k} = {scalar(v)}")
        if scal:
            lines.append("")
        for k, v in subs.items():
            emit(f"{prefix}.{k}" if prefix else k, v)

    emit("", d)
    return "\n".join(lines)
