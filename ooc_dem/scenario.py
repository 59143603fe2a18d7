"""Typed, validated scenarios: TOML -> frozen dataclasses.

Every value is checked against a declared type and range; a bad value raises
``ScenarioError`` with one line naming the key, the value and what is allowed.
The time step is checked against the critical step of the stiffest contact
(reference/validation.md: dt_crit = (2/w)(sqrt(1+z^2) - z)).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any


class ScenarioError(ValueError):
    """A scenario value, file or override is invalid (message is one line)."""


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


@dataclass(frozen=True)
class Bin:
    length: float = 0.60           # m
    height: float = 0.40           # m, top of the neighbour grid (open top)


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


@dataclass(frozen=True)
class ContactPair:
    kn: float = 2.0e5
    ks: float = 2.0e5 / 3.0
    damping_n: float = 1.0         # ratio of critical, normal
    damping_t: float = 1.0         # ratio of critical, tangential
    friction: float = 0.5
    rolling_friction: float = 0.0  # limit mu_r * r_eff * Fn
    rolling_damping: float = 0.0   # ratio of critical, rolling


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


@dataclass(frozen=True)
class Output:
    series_interval: float = 0.01  # s, time-series row interval (means over it)
    steady_start: float = 9.6      # s of travel
    steady_end: float = 45.0       # s of travel
    run_steps: int = 0             # bare beds: default step count of `run`


@dataclass(frozen=True)
class Decomposition:
    policy: str = "wheel"          # "wheel" (paper) or "equal"
    domains: int = 6
    block: int = 1                 # temporal blocking K (steps per epoch)
    margin: float = 0.01           # m, wheel slab margin beyond the lug tips


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

    # ---- derived values
    @property
    def name(self) -> str:
        return self.scenario.name

    @property
    def gravity_vector(self) -> tuple[float, float]:
        return (0.0, -self.physics.gravity)

    @property
    def wheel_mass(self) -> float:
        return self.wheel.load / self.physics.gravity

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def to_toml(self) -> str:
        return dict_to_toml(self.to_dict())

    def hash(self) -> str:
        """SHA-256 of the physics-relevant content (output settings excluded)."""
        d = self.to_dict()
        d.pop("output", None)
        d["scenario"].pop("description", None)
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()

    def bed_hash(self) -> str:
        """Hash of what determines the settled bed (cache key)."""
        d = self.to_dict()
        keep = {k: d[k] for k in ("physics", "bin", "soil", "bed")}
        keep["contact"] = d["contact"]
        return hashlib.sha256(json.dumps(keep, sort_keys=True).encode()).hexdigest()[:16]


# ------------------------------------------------------------ constraints
# (section, key) -> (predicate, description of what is allowed)
_POS = (lambda v: v > 0, "a number > 0")
_NONNEG = (lambda v: v >= 0, "a number >= 0")
_RATIO = (lambda v: 0 <= v <= 1, "a number in [0, 1]")
_CONSTRAINTS: dict[tuple[str, str], tuple] = {
    ("physics", "gravity"): _NONNEG,
    ("physics", "thickness"): _POS,
    ("physics", "dt"): _POS,
    ("physics", "contacts_per_disc"): (lambda v: v >= 1, "a number >= 1"),
    ("bin", "length"): _POS,
    ("bin", "height"): _POS,
    ("soil", "n"): (lambda v: 1 <= v <= 2_000_000_000, "an integer in [1, 2e9]"),
    ("soil", "r_min"): _POS,
    ("soil", "r_max"): _POS,
    ("soil", "density"): _POS,
    ("soil", "seed"): (lambda v: 0 <= v < 2**63, "an integer >= 0"),
    ("bed", "settle_speed"): _POS,
    ("bed", "max_settle_time"): _POS,
    ("bed", "tile"): (lambda v: v >= 0, "an integer >= 0"),
    ("bed", "skin"): _POS,
    ("wheel", "radius"): _POS,
    ("wheel", "width"): _POS,
    ("wheel", "load"): _POS,
    ("wheel", "n_lugs"): (lambda v: 0 <= v <= 360, "an integer in [0, 360]"),
    ("wheel", "lug_tip_radius"): _POS,
    ("wheel", "lug_thickness"): _POS,
    ("wheel", "x0"): _NONNEG,
    ("wheel", "drop_gap"): _NONNEG,
    ("wheel", "omega"): _NONNEG,
    ("wheel", "control"): (lambda v: v in ("drawbar", "slip"), "one of 'drawbar', 'slip'"),
    ("wheel", "drawbar_load"): _NONNEG,
    ("wheel", "drawbar_ramp"): _NONNEG,
    ("wheel", "slip"): (lambda v: -1 <= v < 1, "a number in [-1, 1)"),
    ("wheel", "settle_time"): _NONNEG,
    ("wheel", "travel_time"): _NONNEG,
    ("output", "series_interval"): _POS,
    ("output", "steady_start"): _NONNEG,
    ("output", "steady_end"): _NONNEG,
    ("output", "run_steps"): (lambda v: v >= 0, "an integer >= 0"),
    ("decomposition", "policy"): (lambda v: v in ("wheel", "equal"), "one of 'wheel', 'equal'"),
    ("decomposition", "domains"): (lambda v: 1 <= v <= 4096, "an integer in [1, 4096]"),
    ("decomposition", "block"): (lambda v: 1 <= v <= 10000, "an integer in [1, 10000]"),
    ("decomposition", "margin"): _NONNEG,
}
_PAIR_CONSTRAINTS = {
    "kn": _POS,
    "ks": _POS,
    "damping_n": (lambda v: 0 <= v <= 10, "a number in [0, 10]"),
    "damping_t": (lambda v: 0 <= v <= 10, "a number in [0, 10]"),
    "friction": _NONNEG,
    "rolling_friction": _NONNEG,
    "rolling_damping": (lambda v: 0 <= v <= 10, "a number in [0, 10]"),
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
            v = float(value)
            if not math.isfinite(v):
                raise ScenarioError(f"{path} = {value!r}: must be a finite number")
            return v
    elif typ is str:
        if isinstance(value, str):
            return value
    raise ScenarioError(f"{path} = {value!r}: must be {_type_name(typ)}")


def _build(cls, data: Any, path: str, defaults):
    if not isinstance(data, dict):
        raise ScenarioError(f"{path} = {data!r}: must be a table")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ScenarioError(f"{path}.{unknown[0]}: unknown key (allowed: {', '.join(fields)})")
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
            raise ScenarioError(f"{sec}.{key} = {v!r}: must be {allowed}")
    for pair in ("soil_soil", "soil_wall", "soil_wheel"):
        p = getattr(sc.contact, pair)
        for key, (pred, allowed) in _PAIR_CONSTRAINTS.items():
            v = getattr(p, key)
            if not pred(v):
                raise ScenarioError(f"contact.{pair}.{key} = {v!r}: must be {allowed}")
    s = sc.soil
    if s.r_max < s.r_min:
        raise ScenarioError(f"soil.r_max = {s.r_max!r}: must be >= soil.r_min ({s.r_min!r})")
    if 2 * s.r_max >= sc.bin.length:
        raise ScenarioError(f"bin.length = {sc.bin.length!r}: must exceed the largest disc diameter")
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
    o = sc.output
    if o.steady_end < o.steady_start:
        raise ScenarioError(f"output.steady_end = {o.steady_end!r}: must be >= output.steady_start ({o.steady_start!r})")
    dt, crit = sc.physics.dt, critical_time_step(sc)
    if dt > crit:
        raise ScenarioError(
            f"physics.dt = {dt!r}: above the stability limit {crit:.3e} s of the stiffest contact "
            f"(dt_crit = (2/w)(sqrt(1+z^2)-z)); use dt <= {crit:.3e}")


def critical_time_step(sc: Scenario) -> float:
    """Critical explicit step of the stiffest contact (validation.md).

    w = sqrt(n_c * kn / m_min) with n_c contacts per disc, z the damping ratio;
    rolling springs are included through their rotational frequency.
    """
    s = sc.soil
    m_min = s.density * math.pi * s.r_min**2 * sc.physics.thickness
    i_min = 0.5 * m_min * s.r_min**2
    nc = sc.physics.contacts_per_disc
    worst = math.inf
    pairs = [sc.contact.soil_soil, sc.contact.soil_wall]
    if sc.wheel.enabled:
        pairs.append(sc.contact.soil_wheel)
    for p in pairs:
        for k, z in ((p.kn, p.damping_n), (p.ks, p.damping_t)):
            w = math.sqrt(nc * k / m_min)
            worst = min(worst, 2.0 / w * (math.sqrt(1 + z * z) - z))
        # tangential spring acting on rotation: torque ks r^2 on inertia I
        w = math.sqrt(nc * p.ks * s.r_min**2 / i_min)
        worst = min(worst, 2.0 / w * (math.sqrt(1 + p.damping_t**2) - p.damping_t))
    return worst


# --------------------------------------------------------------- loading


def builtin_names() -> list[str]:
    files = resources.files("ooc_dem.scenarios")
    names = sorted(p.name[:-5] for p in files.iterdir() if p.name.endswith(".toml"))
    return names + ["bed-N"]


def _builtin_text(name: str) -> str | None:
    f = resources.files("ooc_dem.scenarios") / f"{name}.toml"
    if f.is_file():
        return f.read_text()
    return None


def _parse_count(text: str) -> int | None:
    t = text.lower().replace("_", "")
    mult = 1
    if t.endswith("k"):
        mult, t = 1000, t[:-1]
    elif t.endswith("m"):
        mult, t = 1_000_000, t[:-1]
    try:
        v = float(t) * mult
    except ValueError:
        return None
    if v != int(v) or v < 1:
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


def _parse_value(text: str) -> Any:
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text  # bare word -> string


def apply_overrides(data: dict, overrides: list[str]) -> dict:
    for item in overrides or []:
        if "=" not in item:
            raise ScenarioError(f"--set {item!r}: expected section.key=value")
        key, text = item.split("=", 1)
        parts = key.strip().split(".")
        if len(parts) < 2 or not all(parts):
            raise ScenarioError(f"--set {item!r}: key must be section.key (e.g. physics.dt=1e-5)")
        node = data
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ScenarioError(f"--set {item!r}: {p} is not a section")
        node[parts[-1]] = _parse_value(text.strip())
    return data


def load_scenario(source: str | Path, overrides: list[str] | None = None) -> Scenario:
    """Load a built-in scenario by name (``paper2008``, ``quick``, ``bed-100k``) or a TOML file."""
    text = None
    data: dict
    src = str(source)
    if src.startswith("bed-") and _builtin_text(src) is None:
        n = _parse_count(src[4:])
        if n is None:
            raise ScenarioError(f"scenario {src!r}: bed-N needs a disc count N such as bed-7000, bed-100k, bed-1m")
        data = bed_scenario_dict(n)
    else:
        text = _builtin_text(src)
        if text is None:
            p = Path(src)
            if not p.is_file():
                raise ScenarioError(
                    f"scenario {src!r}: not a built-in ({', '.join(builtin_names())}) and no such file")
            try:
                text = p.read_text()
            except (OSError, UnicodeDecodeError) as e:
                raise ScenarioError(f"scenario {src!r}: cannot read ({e})") from None
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise ScenarioError(f"scenario {src!r}: invalid TOML ({e})") from None
    data = apply_overrides(data, overrides or [])
    return scenario_from_dict(data)


def scenario_from_dict(data: dict) -> Scenario:
    sc = _build(Scenario, data, "", Scenario())
    _check_ranges(sc)
    return sc


def scenario_from_toml(text: str) -> Scenario:
    return scenario_from_dict(tomllib.loads(text))


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
        return json.dumps(v)

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
