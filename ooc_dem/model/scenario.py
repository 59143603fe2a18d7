"""Typed, validated scenarios: TOML -> frozen dataclasses.

Every value is checked against a declared type and range; a bad value raises
``ScenarioError`` with one line naming the key, the value and what is allowed.
The time step is checked against the critical step of the stiffest contact
(docs/reference/validation.md: dt_crit = (2/w)(sqrt(1+z^2) - z)).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import re
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any


class ScenarioError(ValueError):
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
MAX_TEXT = 10_000          # characters of a string value (descriptions end up in every manifest)
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
    return f"<a {type(value).__name__}>"


def big(n: int) -> str:
    """A large round count as people write it: 1e10, 2e9."""
    return f"{n:.0e}".replace("e+0", "e").replace("e+", "e")


def steps_for_duration(seconds: float, dt: float, what: str) -> int:
    """round(seconds / dt), refused (naming ``what``) unless finite and at most MAX_STEPS."""
    n = seconds / dt   # float division: inf on overflow, never an exception (dt > 0)
    if not (0.0 <= n <= MAX_STEPS):
        raise ScenarioError(f"{what}: {show(seconds)} s at physics.dt = {dt!r} s is {n:.3g} steps, "
                            f"more than the maximum {big(MAX_STEPS)}")
    return int(round(n))


# ---------------------------------------------------------------- sections


@dataclass(frozen=True)
class Meta:
    name: str = "unnamed"
    description: str = ""


@dataclass(frozen=True)
class Physics:
    gravity: float = 9.80          # m/s^2, acts in -y
    thickness: float = 0.10        # m, discs are cylinders of this length
    dt: float = 1.0e-5             # s
    contacts_per_disc: float = 4.0  # used for the critical-step estimate
    dim: int = 2                   # 2: discs in the x-y plane; 3: spheres (z across the bin)
    impact_speed: float = 1.0      # m/s, largest expected impact speed (3D Hertz time-step check)
    history_capacity: int = 0      # contacts a particle may hold (0: 8 in 2D, 12 in 3D; never a result bit)


@dataclass(frozen=True)
class Bin:
    length: float = 0.60           # m
    height: float = 0.40           # m, top of the neighbour grid (open top)
    width: float = 0.10            # m, across the bin (z; 3D only: side walls at z = 0 and width)


@dataclass(frozen=True)
class Soil:
    n: int = 6986
    r_min: float = 0.0018
    r_max: float = 0.0022
    density: float = 2650.0
    seed: int = 2008


@dataclass(frozen=True)
class Bed:
    settle_speed: float = 1.0e-4   # m/s, mean speed that ends deposition
    max_settle_time: float = 5.0   # s, refuse beds that never settle
    tile: int = 0                  # >0: build the bed by tiling a settled tile of this many discs
    skin: float = 0.0006           # m, Verlet skin of the neighbour lists
    tiles_across: int = 1          # 3D tiled beds: tiles across the width (z)


@dataclass(frozen=True)
class ContactPair:
    kn: float = 2.0e5
    ks: float = 2.0e5 / 3.0
    damping_n: float = 1.0         # ratio of critical, normal
    damping_t: float = 1.0         # ratio of critical, tangential
    friction: float = 0.5
    rolling_friction: float = 0.0  # limit mu_r * r_eff * Fn
    rolling_damping: float = 0.0   # ratio of critical, rolling
    law: str = "linear"            # "linear" (kn, ks, damping_*) or "hertz" (3D: Hertz-Mindlin)
    youngs_modulus: float = 1.0e7  # Pa, hertz: both surfaces of the pair
    poisson_ratio: float = 0.3     # hertz
    restitution: float = 0.5       # hertz: coefficient of restitution (sets the damping)


@dataclass(frozen=True)
class Contacts:
    soil_soil: ContactPair = ContactPair(rolling_friction=0.10, rolling_damping=0.3)
    soil_wall: ContactPair = ContactPair()
    soil_wheel: ContactPair = ContactPair(friction=0.4)


@dataclass(frozen=True)
class Wheel:
    enabled: bool = True
    radius: float = 0.100
    width: float = 0.100
    load: float = 19.6             # N, dead weight (mass = load / g)
    n_lugs: int = 18
    lug_tip_radius: float = 0.110  # m, outermost point of a lug
    lug_thickness: float = 0.002   # m, capsule diameter
    x0: float = 0.15               # m, initial centre
    drop_gap: float = 0.002        # m, gap between lug tips and the surface at placement
    omega: float = 0.138           # rad/s, clockwise, drives in +x
    control: str = "drawbar"       # "drawbar" (free x) or "slip" (prescribed forward speed)
    drawbar_load: float = 10.0     # N, opposes travel
    drawbar_ramp: float = 1.0      # s
    slip: float = 0.0              # prescribed slip when control = "slip"
    settle_time: float = 1.0       # s, omega = 0, x held
    travel_time: float = 45.0      # s
    z0: float = 0.0                # m, 3D: lateral centre of the wheel (0: the bin's mid-width)


@dataclass(frozen=True)
class Output:
    series_interval: float = 0.01  # s, time-series row interval (means over it)
    steady_start: float = 9.6      # s of travel
    steady_end: float = 45.0       # s of travel
    run_steps: int = 0             # bare beds: default step count of `run`
    snapshot_interval: float = 0.0  # s, trajectory frame interval (RUN/trajectory/); 0 = none


@dataclass(frozen=True)
class Decomposition:
    policy: str = "wheel"          # "wheel" (paper) or "equal"
    domains: int = 6
    block: int = 1                 # temporal blocking K (steps per epoch)
    margin: float = 0.01           # m, wheel slab margin beyond the lug tips


@dataclass(frozen=True)
class Repose:
    """Angle-of-repose test (3D, docs/reference/repose3d.md): the settled column of
    ``soil.n`` spheres, a cylinder of ``column_radius`` standing on the floor at the bin's
    centre, is released at step 0; its heap's flank angle is measured at the end."""
    enabled: bool = False
    column_radius: float = 0.02    # m, radius of the released column
    fit_low: float = 0.2           # flank fit from this fraction of the heap height ...
    fit_high: float = 0.8          # ... to this one
    sectors: int = 8               # azimuthal sectors, one profile and one fit each
    bin_width: float = 0.005       # m, radial bins of the surface profile


@dataclass(frozen=True)
class Scenario:
    scenario: Meta = Meta()
    physics: Physics = Physics()
    bin: Bin = Bin()
    soil: Soil = Soil()
    bed: Bed = Bed()
    contact: Contacts = Contacts()
    wheel: Wheel = Wheel()
    output: Output = Output()
    decomposition: Decomposition = Decomposition()
    repose: Repose = Repose()

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
        """to_dict() without the keys added for 3D while they hold their defaults (so a 2D
        scenario keeps the hash and bed cache name it had before they existed)."""
        d = self.to_dict()
        for (sec, key), default in _HASH_NEUTRAL.items():
            if d[sec].get(key) == default:
                del d[sec][key]
        for pair in d["contact"].values():
            for key, default in _PAIR_HASH_NEUTRAL.items():
                if pair.get(key) == default:
                    del pair[key]
        if d["repose"] == dataclasses.asdict(Repose()):   # added with repose3d
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
        if self.repose.enabled:   # the settled column is cut to this radius
            keep["repose"] = {"column_radius": self.repose.column_radius}
        return hashlib.sha256(json.dumps(keep, sort_keys=True).encode()).hexdigest()[:16]


# keys whose default value is left out of the hashes (added with the 3D engine)
_HASH_NEUTRAL = {("physics", "dim"): 2, ("physics", "impact_speed"): 1.0, ("bin", "width"): 0.10,
                 ("bed", "tiles_across"): 1, ("physics", "history_capacity"): 0,
                 ("wheel", "z0"): 0.0}
_PAIR_HASH_NEUTRAL = {"law": "linear", "youngs_modulus": 1.0e7, "poisson_ratio": 0.3,
                      "restitution": 0.5}
LAWS = ("linear", "hertz")
REPOSE_MEASUREMENT_KEYS = ("fit_low", "fit_high", "sectors", "bin_width")

# ------------------------------------------------------------ constraints
# (section, key) -> (predicate, description of what is allowed)
_POS = (lambda v: v > 0, "a number > 0")
_NONNEG = (lambda v: v >= 0, "a number >= 0")
_RATIO = (lambda v: 0 <= v <= 1, "a number in [0, 1]")


def _within(lo: float, hi: float, lo_open: bool = False, what: str = "a number"):
    """A closed (or left-open) interval. The upper bounds are far beyond any soil bin; they
    exist so that every derived quantity (masses, steps, grid sizes) stays finite."""
    if lo_open:
        return (lambda v: lo < v <= hi, f"{what} in ({lo:g}, {hi:g}]")
    return (lambda v: lo <= v <= hi, f"{what} in [{lo:g}, {hi:g}]")


# m. The floor keeps every length resolvable at any coordinate in the bin: at 1e6 m a
# double's spacing is 1.2e-10 m, so a narrower wheel or bin (wheel.width = 1e-300) made
# z0 + w/2 - (z0 - w/2) == 0 and divided by zero in the bed's surface height
MIN_LENGTH = 1e-9
_LENGTH = _within(MIN_LENGTH, 1e6)
_GAP = _within(0.0, 1e6)                        # m, may be 0
_COUNT = lambda hi: (lambda v: 0 <= v <= hi, f"an integer in [0, {big(hi)}]")
_CONSTRAINTS: dict[tuple[str, str], tuple] = {
    ("scenario", "name"): (lambda v: NAME_RE.fullmatch(v) is not None, NAME_ALLOWED),
    ("scenario", "description"): (lambda v: len(v) <= MAX_TEXT, f"at most {MAX_TEXT} characters"),
    ("physics", "gravity"): _within(0.0, 1000.0),
    ("physics", "thickness"): _LENGTH,
    ("physics", "dt"): _POS,
    ("physics", "contacts_per_disc"): (lambda v: 1 <= v <= 1000, "a number in [1, 1000]"),
    ("physics", "dim"): (lambda v: v in (2, 3), "2 or 3"),
    ("physics", "history_capacity"): (lambda v: v == 0 or 4 <= v <= MAX_HIST_CAP,
                                      f"0 (the dimension's default) or an integer in [4, {MAX_HIST_CAP}]"),
    ("physics", "impact_speed"): _within(0.0, 1e4, lo_open=True),
    ("bin", "length"): _LENGTH,
    ("bin", "height"): _LENGTH,
    ("bin", "width"): _LENGTH,
    ("soil", "n"): (lambda v: 1 <= v <= 2_000_000_000, "an integer in [1, 2e9]"),
    ("soil", "r_min"): _LENGTH,
    ("soil", "r_max"): _LENGTH,
    ("soil", "density"): _within(0.0, 1e6, lo_open=True),
    ("soil", "seed"): (lambda v: 0 <= v < 2**63, "an integer in [0, 2^63)"),
    ("bed", "settle_speed"): _POS,
    ("bed", "max_settle_time"): _POS,
    ("bed", "tile"): _COUNT(2_000_000_000),
    ("bed", "skin"): _LENGTH,
    ("bed", "tiles_across"): (lambda v: 1 <= v <= 100_000, "an integer in [1, 100000]"),
    ("wheel", "radius"): _LENGTH,
    ("wheel", "width"): _LENGTH,
    ("wheel", "load"): _within(0.0, 1e6, lo_open=True),
    ("wheel", "n_lugs"): (lambda v: 0 <= v <= 360, "an integer in [0, 360]"),
    ("wheel", "lug_tip_radius"): _LENGTH,
    ("wheel", "lug_thickness"): _LENGTH,
    ("wheel", "x0"): _GAP,
    ("wheel", "drop_gap"): _GAP,
    ("wheel", "omega"): _within(0.0, 1000.0),
    ("wheel", "control"): (lambda v: v in ("drawbar", "slip"), "one of 'drawbar', 'slip'"),
    ("wheel", "drawbar_load"): _within(0.0, 1e6),
    ("wheel", "drawbar_ramp"): _NONNEG,
    ("wheel", "slip"): (lambda v: -1 <= v < 1, "a number in [-1, 1)"),
    ("wheel", "settle_time"): _NONNEG,
    ("wheel", "travel_time"): _NONNEG,
    ("wheel", "z0"): _GAP,
    ("output", "series_interval"): _POS,
    ("output", "steady_start"): _NONNEG,
    ("output", "steady_end"): _NONNEG,
    ("output", "run_steps"): _COUNT(MAX_STEPS),
    ("output", "snapshot_interval"): _NONNEG,
    ("decomposition", "policy"): (lambda v: v in ("wheel", "equal"), "one of 'wheel', 'equal'"),
    ("decomposition", "domains"): (lambda v: 1 <= v <= MAX_DOMAINS, f"an integer in [1, {MAX_DOMAINS}]"),
    ("decomposition", "block"): (lambda v: 1 <= v <= MAX_BLOCK, f"an integer in [1, {MAX_BLOCK}]"),
    ("decomposition", "margin"): _GAP,
    ("repose", "column_radius"): _LENGTH,
    ("repose", "fit_low"): _RATIO,
    ("repose", "fit_high"): _RATIO,
    ("repose", "sectors"): (lambda v: 1 <= v <= 360, "an integer in [1, 360]"),
    ("repose", "bin_width"): _LENGTH,
}
_PAIR_CONSTRAINTS = {
    "kn": _POS,
    "ks": _POS,
    "damping_n": (lambda v: 0 <= v <= 10, "a number in [0, 10]"),
    "damping_t": (lambda v: 0 <= v <= 10, "a number in [0, 10]"),
    "friction": _within(0.0, 100.0),
    "rolling_friction": _within(0.0, 100.0),
    "rolling_damping": (lambda v: 0 <= v <= 10, "a number in [0, 10]"),
    "law": (lambda v: v in LAWS, "one of 'linear', 'hertz'"),
    "youngs_modulus": _within(1.0, 1e13),
    "poisson_ratio": _within(-0.99, 0.49),
    "restitution": _within(0.0, 1.0, lo_open=True),
}


def _type_name(t) -> str:
    return {float: "a number", int: "an integer", str: "a string", bool: "true or false"}.get(t, str(t))


def _coerce(path: str, value: Any, typ) -> Any:
    if typ is bool:
        if isinstance(value, bool):
            return value
    elif typ is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif typ is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                v = float(value)
            except OverflowError:   # an integer beyond the float range
                v = math.inf
            if not math.isfinite(v):
                raise ScenarioError(f"{path} = {show(value)}: must be a finite number")
            return v + 0.0   # -0.0 -> 0.0: one spelling of zero in the stored TOML and the hash
    elif typ is str:
        if isinstance(value, str):
            try:
                value.encode("utf-8")
            except UnicodeEncodeError:
                raise ScenarioError(f"{path} = {show(value)}: not valid Unicode text "
                                    f"(lone surrogate)") from None
            return value
    raise ScenarioError(f"{path} = {show(value)}: must be {_type_name(typ)}")


def _show_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]{1,40}", key) else show(key, 40)


def _build(cls, data: Any, path: str, defaults):
    if not isinstance(data, dict):
        raise ScenarioError(f"{path} = {show(data)}: must be a table")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        where = f"{path}.{_show_key(unknown[0])}" if path else _show_key(unknown[0])
        raise ScenarioError(f"{where}: unknown key (allowed: {', '.join(fields)})")
    kwargs = {}
    for name, f in fields.items():
        default = getattr(defaults, name)
        if name not in data:
            kwargs[name] = default
            continue
        sub = f"{path}.{name}" if path else name
        if dataclasses.is_dataclass(default):
            kwargs[name] = _build(type(default), data[name], sub, default)
        else:
            kwargs[name] = _coerce(sub, data[name], type(default))
    return cls(**kwargs)


def _check_ranges(sc: Scenario) -> None:
    for (sec, key), (pred, allowed) in _CONSTRAINTS.items():
        v = getattr(getattr(sc, sec), key)
        if not pred(v):
            raise ScenarioError(f"{sec}.{key} = {show(v)}: must be {allowed}")
    for pair in ("soil_soil", "soil_wall", "soil_wheel"):
        p = getattr(sc.contact, pair)
        for key, (pred, allowed) in _PAIR_CONSTRAINTS.items():
            v = getattr(p, key)
            if not pred(v):
                raise ScenarioError(f"contact.{pair}.{key} = {show(v)}: must be {allowed}")
    if sc.dim == 2:
        for pair in ("soil_soil", "soil_wall", "soil_wheel"):
            if getattr(sc.contact, pair).law != "linear":
                raise ScenarioError(f"contact.{pair}.law = {show(getattr(sc.contact, pair).law)}: "
                                    f"the 2D engine has the linear law only (hertz needs physics.dim = 3)")
    elif sc.wheel.enabled:
        w = sc.wheel
        z0 = w.z0 if w.z0 > 0.0 else 0.5 * sc.bin.width
        if not (0.5 * w.width <= z0 <= sc.bin.width - 0.5 * w.width):
            raise ScenarioError(f"wheel.z0 = {w.z0!r}: the wheel (wheel.width = {w.width!r}) must fit "
                                f"across the bin (bin.width = {sc.bin.width!r}): z0 in "
                                f"[{0.5 * w.width!r}, {sc.bin.width - 0.5 * w.width!r}], or 0 for "
                                f"the mid-width (physics.dim = 3)")
    s = sc.soil
    if s.r_max < s.r_min:
        raise ScenarioError(f"soil.r_max = {s.r_max!r}: must be >= soil.r_min ({s.r_min!r})")
    if 2 * s.r_max >= sc.bin.length:
        raise ScenarioError(f"bin.length = {sc.bin.length!r}: must exceed the largest disc diameter")
    if sc.dim == 3 and 2 * s.r_max >= sc.bin.width:
        raise ScenarioError(f"bin.width = {sc.bin.width!r}: must exceed the largest sphere diameter "
                            f"(physics.dim = 3)")
    w = sc.wheel
    if w.enabled:
        if w.lug_tip_radius < w.radius:
            raise ScenarioError(f"wheel.lug_tip_radius = {w.lug_tip_radius!r}: must be >= wheel.radius ({w.radius!r})")
        if not (w.lug_tip_radius < w.x0 < sc.bin.length - w.lug_tip_radius):
            raise ScenarioError(
                f"wheel.x0 = {w.x0!r}: the wheel must fit in the bin, x0 in "
                f"({w.lug_tip_radius}, {sc.bin.length - w.lug_tip_radius})")
        if sc.physics.gravity <= 0:
            raise ScenarioError("physics.gravity = 0: a wheel needs gravity > 0 (its mass is load / g)")
    _check_repose(sc)
    _check_tile(sc)
    o = sc.output
    if o.steady_end < o.steady_start:
        raise ScenarioError(f"output.steady_end = {o.steady_end!r}: must be >= output.steady_start ({o.steady_start!r})")
    _check_derived(sc)
    dt, (crit, stiffest) = sc.physics.dt, _critical_step(sc)
    if sc.dim == 3 and dt > crit:
        raise ScenarioError(
            f"physics.dt = {dt!r}: above the stability limit {crit:.3e} s of the stiffest contact "
            f"({stiffest}; physics.dim = 3, lightest sphere of soil.r_min and soil.density, "
            f"physics.contacts_per_disc contacts, physics.impact_speed for hertz); use dt <= {crit:.3e}")
    if dt > crit:
        raise ScenarioError(
            f"physics.dt = {dt!r}: above the stability limit {crit:.3e} s of the stiffest contact "
            f"({stiffest} on the lightest disc (soil.r_min, soil.density, physics.thickness) with "
            f"physics.contacts_per_disc contacts: dt_crit = (2/w)(sqrt(1+z^2)-z)); use dt <= {crit:.3e}")


def tile_grid(sc: Scenario) -> tuple[int, int]:
    """(tiles along x, tiles across z) of a tiled bed (2D: across = 1)."""
    tiles = -(-sc.soil.n // sc.bed.tile)
    across = sc.bed.tiles_across if sc.dim == 3 else 1
    return -(-tiles // across), across


def tile_share(extent: float, n: int) -> float:
    """extent / n without the division's rounding noise: 0.6 / 6 is 0.09999999999999999,
    which would make the tile of a 0.6 m bin of 6 tiles another scenario (another settled
    tile) than the 0.1 m tile of a 0.2 m bin of 2. The shortest 15-digit value is taken
    when n times it gives the extent back to within 2 ulp; otherwise (1 / 3) the quotient
    itself."""
    share = extent / n
    tidy = float(f"{share:.15g}")
    return tidy if abs(tidy * n - extent) <= 2.0 * math.ulp(extent) else share


def tile_size(sc: Scenario) -> tuple[float, float]:
    """(length, width) of one tile of a tiled bed (2D: width is the bin's, unused)."""
    nx, nz = tile_grid(sc)
    return tile_share(sc.bin.length, nx), (tile_share(sc.bin.width, nz) if sc.dim == 3 else sc.bin.width)


def tile_scenario(sc: Scenario) -> Scenario:
    """The scenario one tile of a tiled bed is settled as: bed.tile discs in its share of the bin."""
    d = sc.to_dict()
    tile_len, tile_wid = tile_size(sc)
    d["soil"]["n"] = sc.bed.tile
    d["bin"]["length"] = tile_len
    if sc.dim == 3:
        d["bin"]["width"] = tile_wid
        d["bed"]["tiles_across"] = 1
    d["bed"]["tile"] = 0
    d["wheel"]["enabled"] = False
    return scenario_from_dict(d)


def _check_tile(sc: Scenario) -> None:
    """A tiled bed is settled as the scenario of one tile (tile_scenario: bed.tile discs in
    bin.length / tiles along x); that scenario must hold too, or `run` would refuse, naming a
    bin the user never wrote, what `check` accepted."""
    if not 0 < sc.bed.tile < sc.soil.n:
        return
    try:
        tile_scenario(sc)
    except ScenarioError as e:
        length, width = tile_size(sc)
        size = f"{length:.3g} m long" + (f", {width:.3g} m wide" if sc.dim == 3 else "")
        raise ScenarioError(f"bed.tile = {sc.bed.tile}: the bed is settled in tiles of {sc.bed.tile} "
                            f"of the soil.n = {sc.soil.n} discs, {size}, and such a tile is refused "
                            f"({e}); raise bed.tile") from None


def _check_repose(sc: Scenario) -> None:
    """The angle-of-repose test's keys against each other and against the bin and the soil."""
    rp, s = sc.repose, sc.soil
    if not rp.fit_low < rp.fit_high:
        raise ScenarioError(f"repose.fit_low = {rp.fit_low!r}, repose.fit_high = {rp.fit_high!r}: the "
                            f"flank is fitted from fit_low to fit_high of the heap height (fit_low < fit_high)")
    if not rp.enabled:
        return
    if sc.dim != 3:
        raise ScenarioError("repose.enabled = true: the angle-of-repose test is 3D (set physics.dim = 3)")
    if sc.bed.tile:
        raise ScenarioError(f"bed.tile = {sc.bed.tile}: the repose column is settled whole (bed.tile = 0 "
                            f"with repose.enabled = true)")
    if rp.column_radius < 2 * s.r_max:
        raise ScenarioError(f"repose.column_radius = {rp.column_radius!r}: must be at least two sphere "
                            f"diameters (2 soil.r_max = {2 * s.r_max!r}) so that the column holds spheres")
    for key, size in (("bin.length", sc.bin.length), ("bin.width", sc.bin.width)):
        if size < 4 * rp.column_radius:
            raise ScenarioError(f"{key} = {size!r}: the heap spreads beyond the column; the bin must be at "
                                f"least 4 repose.column_radius = {4 * rp.column_radius!r} across")
    n_fill, top = repose_fill(sc)
    if top > sc.bin.height:
        raise ScenarioError(f"bin.height = {sc.bin.height!r}: the loose fill of the repose column ({n_fill} "
                            f"spheres in a {2 * rp.column_radius:g} m square, cut to soil.n = {s.n}) needs "
                            f"{top:.3f} m; raise bin.height or repose.column_radius")
    if rp.bin_width < s.r_min or rp.bin_width > rp.column_radius:
        raise ScenarioError(f"repose.bin_width = {rp.bin_width!r}: the profile's radial bins must be "
                            f"between soil.r_min = {s.r_min!r} and repose.column_radius = "
                            f"{rp.column_radius!r} wide")


# spheres filled into the column's square box per sphere kept inside the cylinder: the
# square's area over the cylinder's (of the sphere centres, radius R - r_max), and 15 % more
# because the walls of the box pack looser than its middle
REPOSE_FILL_MARGIN = 1.15


def repose_fill(sc: Scenario) -> tuple[int, float]:
    """(spheres filled into the repose column's square box of side 2 column_radius, height of
    that loose fill (initial_fill_3d's grid of pitch 2.2 r_max)); the settled fill is cut to the
    cylinder and its soil.n lowest spheres kept (bed.settled_column)."""
    s, R = sc.soil, sc.repose.column_radius
    inner = max(R - s.r_max, 0.5 * s.r_max)
    n_fill = int(math.ceil(REPOSE_FILL_MARGIN * s.n * (2 * R / inner) ** 2 / math.pi))
    pitch = 2.2 * s.r_max
    across = max(1, int((2 * R - 2 * s.r_max) / pitch))
    rows = -(-n_fill // (across * across))
    return n_fill, 2 * s.r_max + (rows - 1) * pitch


def _check_derived(sc: Scenario) -> None:
    """Quantities computed from several keys: finite, positive, and step counts bounded
    (each message names the keys that make the quantity)."""
    s, ph = sc.soil, sc.physics
    for key, r in (("soil.r_min", s.r_min), ("soil.r_max", s.r_max)):
        m = disc_mass(sc, r)
        if sc.dim == 3 and not (0.0 < m < math.inf and 0.0 < 0.4 * m * r * r < math.inf):
            raise ScenarioError(
                f"{key} = {r!r}: a sphere of this radius has mass soil.density * 4/3 pi r^3 = "
                f"{m:.3g} kg (moment of inertia {0.4 * m * r * r:.3g}; physics.dim = 3): "
                f"must be finite and > 0")
        if not (0.0 < m < math.inf and 0.0 < 0.5 * m * r * r < math.inf):
            raise ScenarioError(
                f"{key} = {r!r}: a disc of this radius has mass soil.density * pi * r^2 * "
                f"physics.thickness = {m:.3g} kg (moment of inertia {0.5 * m * r * r:.3g}): "
                f"must be finite and > 0")
    if sc.wheel.enabled:
        mass = sc.wheel_mass
        if not (0.0 < mass < math.inf):
            raise ScenarioError(f"wheel.load = {sc.wheel.load!r}: the wheel mass wheel.load / physics.gravity "
                                f"= {mass:.3g} kg must be finite and > 0")
        steps_for_duration(sc.wheel.settle_time + sc.wheel.travel_time, ph.dt,
                           "wheel.settle_time + wheel.travel_time")
    steps_for_duration(sc.bed.max_settle_time, ph.dt, "bed.max_settle_time")
    steps_for_duration(sc.output.series_interval, ph.dt, "output.series_interval")
    if sc.output.snapshot_interval:
        steps_for_duration(sc.output.snapshot_interval, ph.dt, "output.snapshot_interval")


def disc_mass(sc: Scenario, r: float) -> float:
    """density * pi * r^2 * thickness (3D: density * 4/3 pi r^3), as the engine computes it
    (products: inf or 0, never an exception)."""
    if sc.dim == 3:
        return sc.soil.density * (4.0 / 3.0) * math.pi * r ** 3
    return sc.soil.density * math.pi * r * r * sc.physics.thickness


def critical_time_step(sc: Scenario) -> float:
    """Critical explicit step of the stiffest contact (docs/reference/validation.md).

    w = sqrt(n_c * kn / m_min) with n_c contacts per disc, z the damping ratio;
    rolling springs are included through their rotational frequency. Called on
    validated values (0 < m_min < inf): 0.0 when a stiffness overflows, never an exception.
    """
    return _critical_step(sc)[0]


def _critical_step(sc: Scenario) -> tuple[float, str]:
    """(critical step, the key of the stiffness that sets it)."""
    s = sc.soil
    if sc.dim == 3:
        return _critical_step_3d(sc)
    m_min = disc_mass(sc, s.r_min)
    i_min = 0.5 * m_min * s.r_min * s.r_min
    nc = sc.physics.contacts_per_disc
    worst, which = math.inf, "none"
    pairs = ["soil_soil", "soil_wall"] + (["soil_wheel"] if sc.wheel.enabled else [])

    def limit(w2: float, z: float) -> float:
        return 2.0 / math.sqrt(w2) * (math.sqrt(1 + z * z) - z) if w2 > 0 else math.inf

    for name in pairs:
        p = getattr(sc.contact, name)
        # tangential spring acting on rotation: torque ks r^2 on inertia I
        for key, w2, z in (("kn", nc * p.kn / m_min, p.damping_n), ("ks", nc * p.ks / m_min, p.damping_t),
                           ("ks", nc * p.ks * s.r_min * s.r_min / i_min, p.damping_t)):
            lim = limit(w2, z)
            if lim < worst:
                worst, which = lim, f"contact.{name}.{key}"
    return worst, which


def contact_params_3d(pair: ContactPair) -> tuple:
    """The 3D kernels' CONTACT_PARAMS tuple of a scenario contact section (physics.d3.layout):
    linear with the 2D keys, or Hertz-Mindlin with both surfaces of youngs_modulus and
    poisson_ratio, damping from restitution."""
    from ..physics.d3 import layout as L3
    if pair.law == "hertz":
        return L3.hertz_params(pair.youngs_modulus, pair.poisson_ratio, pair.restitution,
                               mu=pair.friction, mur=pair.rolling_friction, zr=pair.rolling_damping,
                               E2=pair.youngs_modulus, nu2=pair.poisson_ratio, no_tension=False)
    return L3.linear_params(pair.kn, pair.ks, pair.damping_n, pair.damping_t, pair.friction,
                            pair.rolling_friction, pair.rolling_damping)


def contact_table_3d(sc: Scenario):
    """CONTACT_PARAMS table [type_a, type_b] of a 3D scenario (soil-soil, soil-wall, soil-wheel)."""
    from ..physics.d3 import layout as L3
    c = sc.contact
    return L3.contact_table({(L3.T_SOIL, L3.T_SOIL): contact_params_3d(c.soil_soil),
                             (L3.T_WALL, L3.T_SOIL): contact_params_3d(c.soil_wall),
                             (L3.T_WHEEL, L3.T_SOIL): contact_params_3d(c.soil_wheel)})


def _critical_step_3d(sc: Scenario) -> tuple[float, str]:
    """physics.d3.timestep.critical_dt over soil-soil, soil-wall and (with a wheel)
    soil-wheel (either law); the key
    named is the stiffness of the pair and mode that sets it."""
    import warnings

    from ..physics.d3 import layout as L3
    from ..physics.d3.timestep import critical_dt
    s = sc.soil
    cp = contact_table_3d(sc)
    worst, which = math.inf, "none"
    pairs = [("soil_soil", (L3.T_SOIL, L3.T_SOIL)), ("soil_wall", (L3.T_WALL, L3.T_SOIL))]
    if sc.wheel.enabled:
        pairs.append(("soil_wheel", (L3.T_WHEEL, L3.T_SOIL)))
    for name, types in pairs:
        pair = getattr(sc.contact, name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # an overflowing stiffness: 0 below
            crit, mode = critical_dt(cp, disc_mass(sc, s.r_min), s.r_min, sc.physics.impact_speed,
                                     sc.physics.contacts_per_disc, types=[types])
        if math.isnan(crit):
            crit = 0.0
        if crit < worst:
            if pair.law == "hertz":
                key = f"contact.{name}.youngs_modulus (hertz)"
            else:
                key = f"contact.{name}.{'ks' if 'tangential' in mode else 'kn'} (linear)"
            worst, which = crit, f"{key}, {mode.split(', ')[-1]}"
    return worst, which


# --------------------------------------------------------------- loading


def builtin_names() -> list[str]:
    files = resources.files("ooc_dem.scenarios")
    names = sorted(p.name[:-5] for p in files.iterdir() if p.name.endswith(".toml"))
    return names + ["bed-N", "bed3d-N"]


def _builtin_text(name: str) -> str | None:
    if NAME_RE.fullmatch(name) is None:   # never a path: built-ins are files of one package
        return None
    f = resources.files("ooc_dem.scenarios") / f"{name}.toml"
    if f.is_file():
        return f.read_text()
    return None


def _parse_count(text: str) -> int | None:
    """N of ``bed-N``: a positive whole number, optionally with a k or m suffix (``100k``, ``1.5m``)."""
    t = text.lower().replace("_", "")
    mult = 1
    if t.endswith("k"):
        mult, t = 1000, t[:-1]
    elif t.endswith("m"):
        mult, t = 1_000_000, t[:-1]
    if not t or len(t) > 30:
        return None
    try:
        v = float(t) * mult
    except ValueError:
        return None
    if not math.isfinite(v) or v < 1 or v != int(v):   # inf, nan, 1e400, 0, -5, 12.5
        return None
    return int(v)


def bed_scenario_dict(n: int) -> dict:
    """A bare bed of n discs with paper2008's soil, built from settled tiles.

    The bin is as deep as paper2008's bed; its length grows with n.
    """
    base = tomllib.loads(_builtin_text("bed"))
    tile = base["bed"]["tile"]
    tile_len = base["bin"]["length"]
    tiles = -(-n // tile)
    base["scenario"]["name"] = f"bed-{n}"
    base["soil"]["n"] = n
    base["bin"]["length"] = tiles * tile_len
    return base


def bed3d_scenario_dict(n: int) -> dict:
    """A bare 3D bed of n spheres with bed3d's soil, built from settled tiles:
    ``bed.tiles_across`` tiles across the width, the bin growing along x."""
    base = tomllib.loads(_builtin_text("bed3d"))
    tile = base["bed"]["tile"]
    across = base["bed"]["tiles_across"]
    tile_len = base["bin"]["length"]
    along = -(-(-(-n // tile)) // across)
    base["scenario"]["name"] = f"bed3d-{n}"
    base["soil"]["n"] = n
    base["bin"]["length"] = along * tile_len
    base["bin"]["width"] = across * base["bin"]["width"]
    return base


def _parse_value(text: str, item: str) -> Any:
    """A --set value as TOML (``1e-5``, ``true``, ``"x"``, ``[1, 2]``); a bare word is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text  # bare word -> string
    except RecursionError:
        raise ScenarioError(f"--set {show(item)}: value nested too deeply") from None
    except ValueError as e:   # e.g. an integer beyond Python's int-string conversion limit
        raise ScenarioError(f"--set {show(item)}: unreadable value ({_first_line(e)})") from None


def _first_line(e: BaseException) -> str:
    text = str(e).splitlines()[0] if str(e) else type(e).__name__
    return text if len(text) <= 120 else text[:117] + "..."


def apply_overrides(data: dict, overrides: list[str]) -> dict:
    for item in overrides or []:
        if "=" not in item:
            raise ScenarioError(f"--set {show(item)}: expected section.key=value")
        key, text = item.split("=", 1)
        parts = key.strip().split(".")
        if len(parts) < 2 or not all(parts):
            raise ScenarioError(f"--set {show(item)}: key must be section.key (e.g. physics.dt=1e-5)")
        if len(parts) > 3:   # the deepest key is contact.<pair>.<key>
            raise ScenarioError(f"--set {show(item)}: key {show(key, 40)} has {len(parts)} parts; "
                                f"keys are section.key or contact.pair.key")
        node = data
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ScenarioError(f"--set {show(item)}: {_show_key(p)} is not a section")
        node[parts[-1]] = _parse_value(text.strip(), item)
    return data


def _parse_toml(text: str, src: str) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(f"scenario {show(src, 400)}: invalid TOML ({_first_line(e)})") from None
    except RecursionError:
        raise ScenarioError(f"scenario {show(src, 400)}: invalid TOML (tables or arrays nested too deeply)") from None
    except ValueError as e:   # an integer beyond Python's int-string conversion limit
        raise ScenarioError(f"scenario {show(src, 400)}: invalid TOML ({_first_line(e)})") from None


def load_scenario(source: str | Path, overrides: list[str] | None = None) -> Scenario:
    """Load a built-in scenario by name (``paper2008``, ``quick``, ``bed-100k``) or a TOML file."""
    text = None
    data: dict
    src = str(source)
    if src.startswith("bed3d-") and _builtin_text(src) is None:
        n = _parse_count(src[6:])
        if n is None:
            raise ScenarioError(f"scenario {show(src, 400)}: bed3d-N needs a sphere count N such as "
                                f"bed3d-20000, bed3d-100k, bed3d-1m")
        data = bed3d_scenario_dict(n)
    elif src.startswith("bed-") and _builtin_text(src) is None:
        n = _parse_count(src[4:])
        if n is None:
            raise ScenarioError(f"scenario {show(src, 400)}: bed-N needs a disc count N such as bed-7000, "
                                f"bed-100k, bed-1m")
        data = bed_scenario_dict(n)
    else:
        text = _builtin_text(src)
        if text is None:
            p = Path(src)
            try:
                is_file = p.is_file()
                size = p.stat().st_size if is_file else 0
            except (OSError, ValueError):   # name too long, NUL byte
                is_file, size = False, 0
            if not is_file:
                raise ScenarioError(
                    f"scenario {show(src, 400)}: not a built-in ({', '.join(builtin_names())}) and no such file")
            if size > MAX_SCENARIO_FILE:
                raise ScenarioError(f"scenario {show(src, 400)}: {size} bytes; a scenario file is at most "
                                    f"{MAX_SCENARIO_FILE} bytes")
            try:
                text = p.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as e:
                raise ScenarioError(f"scenario {show(src, 400)}: cannot read ({_first_line(e)})") from None
        data = _parse_toml(text, src)
    data = apply_overrides(data, overrides or [])
    return scenario_from_dict(data)


def scenario_from_dict(data: dict) -> Scenario:
    sc = _build(Scenario, data, "", Scenario())
    _check_ranges(sc)
    return sc


def scenario_from_toml(text: str) -> Scenario:
    return scenario_from_dict(_parse_toml(text, "(stored)"))


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
    """Minimal TOML writer for the scenario tree (tables of scalars)."""
    lines: list[str] = []

    def scalar(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return repr(v)
        if isinstance(v, int):
            return str(v)
        return toml_string(str(v))

    def emit(prefix, table):
        scal = {k: v for k, v in table.items() if not isinstance(v, dict)}
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
