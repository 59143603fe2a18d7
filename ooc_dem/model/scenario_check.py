"""Checking a scenario: every value against its declared type and range (``_CONSTRAINTS``),
the keys against each other, the time step against the critical step of the stiffest contact
(docs/reference/validation.md: dt_crit = (2/w)(sqrt(1+z^2) - z)), and the quantities the
checks derive (tile geometry, the repose column's fill, the 3D contact tables).

``scenario_from_dict`` builds a Scenario from a dict and checks it; a bad value raises
``ScenarioError`` with one line naming the key, the value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from .grading import KINDS, MAX_SIEVES, PARAMETERS, check_grading, grading_of_soil
from .contacts import contact_table_3d
from .materials import resolve_materials
from .schema import (
    LAWS,
    MAX_BLOCK,
    MAX_DOMAINS,
    MAX_HIST_CAP,
    MAX_STEPS,
    MAX_TEXT,
    NAME_ALLOWED,
    NAME_RE,
    Scenario,
    ScenarioError,
    SoilGrading,
    WHEEL_CONTROLS,
    big,
    did_you_mean,
    show,
    show_key,
    steps_for_duration,
)


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
_GAP = _within(0.0, 1e6)  # m, may be 0
_COUNT = lambda hi: (lambda v: 0 <= v <= hi, f"an integer in [0, {big(hi)}]")
_CONSTRAINTS: dict[tuple[str, str], tuple] = {
    ("scenario", "name"): (lambda v: NAME_RE.fullmatch(v) is not None, NAME_ALLOWED),
    ("scenario", "description"): (lambda v: len(v) <= MAX_TEXT, f"at most {MAX_TEXT} characters"),
    ("physics", "gravity"): _within(0.0, 1000.0),
    ("physics", "thickness"): _LENGTH,
    ("physics", "dt"): _POS,
    ("physics", "contacts_per_disc"): (lambda v: 1 <= v <= 1000, "a number in [1, 1000]"),
    ("physics", "dim"): (lambda v: v in (2, 3), "2 or 3"),
    ("physics", "history_capacity"): (
        lambda v: v == 0 or 4 <= v <= MAX_HIST_CAP,
        f"0 (the dimension's default) or an integer in [4, {MAX_HIST_CAP}]",
    ),
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
    ("wheel", "control"): (lambda v: v in WHEEL_CONTROLS, "one of " + ", ".join(map(repr, WHEEL_CONTROLS))),
    ("wheel", "drawbar_load"): _within(0.0, 1e6),
    ("wheel", "drawbar_ramp"): _NONNEG,
    ("wheel", "slip"): (lambda v: -1 <= v < 1, "a number in [-1, 1)"),
    ("wheel", "torque"): _within(-1e6, 1e6),
    ("wheel", "torque_ramp"): _NONNEG,
    ("wheel", "inertia"): _within(0.0, 1e6),
    ("wheel", "carriage"): (lambda v: v in ("drawbar", "speed"), "one of 'drawbar', 'speed'"),
    ("wheel", "speed"): _within(0.0, 100.0),
    ("wheel", "vertical"): (lambda v: v in ("free", "fixed"), "one of 'free', 'fixed'"),
    ("wheel", "settle_time"): _NONNEG,
    ("wheel", "travel_time"): _NONNEG,
    ("wheel", "z0"): _GAP,
    ("wheel", "mesh_scale"): _within(0.0, 1e6, lo_open=True),
    ("wheel", "mesh_rotate"): (lambda v: len(v) in (0, 3), "three angles (x, y, z) or none"),
    ("wheel", "mesh_offset"): (lambda v: len(v) in (0, 3), "three lengths (x, y, z) or none"),
    ("output", "series_interval"): _POS,
    ("output", "steady_start"): _NONNEG,
    ("output", "steady_end"): _NONNEG,
    ("output", "run_steps"): _COUNT(MAX_STEPS),
    ("output", "snapshot_interval"): _NONNEG,
    ("bed", "fill_friction"): (lambda v: v == -1.0 or 0.0 <= v <= 100.0, "-1 (the contact's friction) or in [0, 100]"),
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
    "youngs_modulus_2": (lambda v: v == 0.0 or 1.0 <= v <= 1e13, "0 (the same as the first surface) or in [1, 1e13]"),
    "poisson_ratio_2": _within(-0.99, 0.49),
    "cohesion": _within(0.0, 1e9),
}


def allowed_values(table: str, key: str) -> str:
    """What a key may hold, as the checks say it (``table``: ``physics``, ``contact.soil_soil``,
    ``soil.grading``); the checks of keys against each other are not listed."""
    if table.startswith("contact."):
        if key == "no_tension":
            return "true, false or unset"
        return _PAIR_CONSTRAINTS[key][1]
    if table == "soil.grading":
        if key == "kind":
            return f"one of {', '.join(map(repr, KINDS))}"
        return "the kind's own keys only (docs/reference/grading.md)"
    if (table, key) == ("wheel", "outline"):
        return "a file's path or an array of 3 to 1e5 points [x, y] (checked when the wheel is on)"
    if (table, key) in _CONSTRAINTS:
        return str(_CONSTRAINTS[(table, key)][1])
    return "true or false" if key == "enabled" else "any"


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
            except OverflowError:  # an integer beyond the float range
                v = math.inf
            if not math.isfinite(v):
                raise ScenarioError(f"{path} = {show(value)}: must be a finite number")
            return v + 0.0  # -0.0 -> 0.0: one spelling of zero in the stored TOML and the hash
    elif typ is tuple:  # an array of numbers (the sieve curve)
        if isinstance(value, (list, tuple)):
            if len(value) > MAX_SIEVES:
                raise ScenarioError(f"{path}: an array of {len(value)} values; at most {MAX_SIEVES}")
            return tuple(_coerce(f"{path}[{k}]", v, float) for k, v in enumerate(value))
        raise ScenarioError(f"{path} = {show(value)}: must be an array of numbers")
    elif typ is str:
        if isinstance(value, str):
            try:
                value.encode("utf-8")
            except UnicodeEncodeError:
                raise ScenarioError(f"{path} = {show(value)}: not valid Unicode text (lone surrogate)") from None
            return value
    raise ScenarioError(f"{path} = {show(value)}: must be {_type_name(typ)}")


_OPTIONAL_TYPES = {("ContactPair", "no_tension"): bool}


def _coerce_outline(path: str, value: Any) -> str | tuple:
    """wheel.outline: a file's path (a string) or an array of [x, y] (a tuple of pairs)."""
    from .wheel_outline import MAX_OUTLINE_VERTICES

    if isinstance(value, str):
        return _coerce(path, value, str)
    if not isinstance(value, (list, tuple)):
        raise ScenarioError(f"{path} = {show(value)}: must be a file's path or an array of [x, y]")
    if len(value) > MAX_OUTLINE_VERTICES:
        raise ScenarioError(f"{path}: an array of {len(value)} points; at most {MAX_OUTLINE_VERTICES}")
    points = []
    for k, p in enumerate(value):
        if not isinstance(p, (list, tuple)) or len(p) != 2:
            raise ScenarioError(f"{path}[{k}] = {show(p)}: must be a point [x, y]")
        points.append((_coerce(f"{path}[{k}][0]", p[0], float), _coerce(f"{path}[{k}][1]", p[1], float)))
    return tuple(points)


def _build(cls, data: Any, path: str, defaults):
    if not isinstance(data, dict):
        raise ScenarioError(f"{path} = {show(data)}: must be a table")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        where = f"{path}.{show_key(unknown[0])}" if path else show_key(unknown[0])
        hint = did_you_mean(unknown[0], fields)
        if unknown[0] == "base" and path:
            hint = "; base goes at the top of the file, before any [section]"
        what = "unknown section" if not path else "unknown key"
        raise ScenarioError(f"{where}: {what} (allowed: {', '.join(fields)}){hint}")
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
            # an optional key (default None) holds the type its annotation names
            typ = _OPTIONAL_TYPES.get((cls.__name__, name), type(default))
            if data[name] is None and (cls.__name__, name) in _OPTIONAL_TYPES:
                kwargs[name] = None  # a dict (not TOML) may hold an unset optional key
            elif (cls.__name__, name) == ("Wheel", "outline"):
                kwargs[name] = _coerce_outline(sub, data[name])
            else:
                kwargs[name] = _coerce(sub, data[name], typ)
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
    if sc.dim == 3:
        for pair in ("soil_soil", "soil_wall", "soil_wheel"):
            p = getattr(sc.contact, pair)
            # the linear law's cohesion grows as fast as its spring (k_c 2 pi R* per unit of
            # overlap): past kn no overlap balances it and the grains sink into each other
            r_star = sc.soil.r_max if pair != "soil_soil" else 0.5 * sc.soil.r_max
            if p.law == "linear" and p.cohesion > 0.0 and 2.0 * math.pi * p.cohesion * r_star >= p.kn:
                raise ScenarioError(
                    f"contact.{pair}.cohesion = {show(p.cohesion)}: with the linear law it must stay below "
                    f"kn / (2 pi R*) = {p.kn / (2.0 * math.pi * r_star):.4g} J/m^3 (R* = {r_star!r} m), "
                    f"or the cohesion outgrows the spring; use the hertz law"
                )
    if sc.dim == 2:
        for pair in ("soil_soil", "soil_wall", "soil_wheel"):
            if getattr(sc.contact, pair).law != "linear":
                raise ScenarioError(
                    f"contact.{pair}.law = {show(getattr(sc.contact, pair).law)}: "
                    f"the 2D engine has the linear law only (hertz needs physics.dim = 3)"
                )
    elif sc.wheel.enabled:
        w = sc.wheel
        z0 = w.z0 if w.z0 > 0.0 else 0.5 * sc.bin.width
        if not (0.5 * w.width <= z0 <= sc.bin.width - 0.5 * w.width):
            raise ScenarioError(
                f"wheel.z0 = {w.z0!r}: the wheel (wheel.width = {w.width!r}) must fit "
                f"across the bin (bin.width = {sc.bin.width!r}): z0 in "
                f"[{0.5 * w.width!r}, {sc.bin.width - 0.5 * w.width!r}], or 0 for "
                f"the mid-width (physics.dim = 3)"
            )
    s = sc.soil
    if s.r_max < s.r_min:
        raise ScenarioError(f"soil.r_max = {s.r_max!r}: must be >= soil.r_min ({s.r_min!r})")
    if 2 * s.r_max >= sc.bin.length:
        raise ScenarioError(f"bin.length = {sc.bin.length!r}: must exceed the largest disc diameter")
    if sc.dim == 3 and 2 * s.r_max >= sc.bin.width:
        raise ScenarioError(f"bin.width = {sc.bin.width!r}: must exceed the largest sphere diameter (physics.dim = 3)")
    w = sc.wheel
    if w.enabled and w.mesh and sc.dim != 3:
        raise ScenarioError(f"wheel.mesh = {show(w.mesh)}: a mesh wheel needs physics.dim = 3")
    if w.enabled and w.outline:
        if sc.dim != 2:
            raise ScenarioError("wheel.outline: an outline wheel needs physics.dim = 2 (3D wheels are rim and lugs)")
        from .wheel_outline import outline_points

        outline_points(sc)  # refused here, with the scenario, when it is not a simple outline
    if w.enabled:
        if w.lug_tip_radius < w.radius:
            raise ScenarioError(f"wheel.lug_tip_radius = {w.lug_tip_radius!r}: must be >= wheel.radius ({w.radius!r})")
        if not (w.lug_tip_radius < w.x0 < sc.bin.length - w.lug_tip_radius):
            raise ScenarioError(
                f"wheel.x0 = {w.x0!r}: the wheel must fit in the bin, x0 in "
                f"({w.lug_tip_radius}, {sc.bin.length - w.lug_tip_radius})"
            )
        if sc.physics.gravity <= 0:
            raise ScenarioError("physics.gravity = 0: a wheel needs gravity > 0 (its mass is load / g)")
        if w.control == "towed" and w.speed <= 0.0:
            raise ScenarioError("wheel.speed = 0.0: a towed wheel needs a carriage speed > 0 (control = towed)")
    _check_grading(sc)
    _check_repose(sc)
    _check_tile(sc)
    o = sc.output
    if o.steady_end < o.steady_start:
        raise ScenarioError(
            f"output.steady_end = {o.steady_end!r}: must be >= output.steady_start ({o.steady_start!r})"
        )
    _check_derived(sc)
    dt, (crit, stiffest) = sc.physics.dt, _critical_step(sc)
    if sc.dim == 3 and dt > crit:
        raise ScenarioError(
            f"physics.dt = {dt!r}: above the stability limit {crit:.3e} s of the stiffest contact "
            f"({stiffest}; physics.dim = 3, lightest sphere of soil.r_min and soil.density, "
            f"physics.contacts_per_disc contacts, physics.impact_speed for hertz); use dt <= {crit:.3e}"
        )
    if dt > crit:
        raise ScenarioError(
            f"physics.dt = {dt!r}: above the stability limit {crit:.3e} s of the stiffest contact "
            f"({stiffest} on the lightest disc (soil.r_min, soil.density, physics.thickness) with "
            f"physics.contacts_per_disc contacts: dt_crit = (2/w)(sqrt(1+z^2)-z)); use dt <= {crit:.3e}"
        )


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
        raise ScenarioError(
            f"bed.tile = {sc.bed.tile}: the bed is settled in tiles of {sc.bed.tile} "
            f"of the soil.n = {sc.soil.n} discs, {size}, and such a tile is refused "
            f"({e}); raise bed.tile"
        ) from None


def _check_grading(sc: Scenario) -> None:
    """[soil.grading]: a known kind, only its own keys set, and its values (model/grading.py)."""
    g = sc.soil.grading
    if g.kind not in KINDS:
        raise ScenarioError(f"soil.grading.kind = {show(g.kind)}: must be one of {', '.join(map(repr, KINDS))}")
    default = SoilGrading()
    for kind, keys in PARAMETERS.items():
        for key in keys:
            if kind != g.kind and getattr(g, key) != getattr(default, key):
                raise ScenarioError(
                    f"soil.grading.{key} = {show(getattr(g, key))}: a key of kind = {kind!r}, "
                    f"not of soil.grading.kind = {g.kind!r}"
                )
    problem = check_grading(
        grading_of_soil(sc.soil), key=lambda k: f"soil.{k}" if k in ("r_min", "r_max") else f"soil.grading.{k}"
    )
    if problem is not None:
        raise ScenarioError(problem)


def _check_repose(sc: Scenario) -> None:
    """The angle-of-repose test's keys against each other and against the bin and the soil."""
    rp, s = sc.repose, sc.soil
    if not rp.fit_low < rp.fit_high:
        raise ScenarioError(
            f"repose.fit_low = {rp.fit_low!r}, repose.fit_high = {rp.fit_high!r}: the "
            f"flank is fitted from fit_low to fit_high of the heap height (fit_low < fit_high)"
        )
    if not rp.enabled:
        return
    if sc.bed.tile:
        raise ScenarioError(
            f"bed.tile = {sc.bed.tile}: the repose column is settled whole (bed.tile = 0 with repose.enabled = true)"
        )
    if rp.column_radius < 2 * s.r_max:
        raise ScenarioError(
            f"repose.column_radius = {rp.column_radius!r}: must be at least two sphere "
            f"diameters (2 soil.r_max = {2 * s.r_max!r}) so that the column holds spheres"
        )
    spans = (("bin.length", sc.bin.length), ("bin.width", sc.bin.width))[: sc.dim - 1]
    for key, size in spans:
        if size < 4 * rp.column_radius:
            raise ScenarioError(
                f"{key} = {size!r}: the heap spreads beyond the column; the bin must be at "
                f"least 4 repose.column_radius = {4 * rp.column_radius!r} across"
            )
    n_fill, top = repose_fill(sc)
    if top > sc.bin.height:
        raise ScenarioError(
            f"bin.height = {sc.bin.height!r}: the loose fill of the repose column ({n_fill} "
            f"{'spheres' if sc.dim == 3 else 'discs'} {2 * rp.column_radius:g} m across, cut to soil.n = {s.n}) needs "
            f"{top:.3f} m; raise bin.height or repose.column_radius"
        )
    if rp.bin_width < s.r_min or rp.bin_width > rp.column_radius:
        raise ScenarioError(
            f"repose.bin_width = {rp.bin_width!r}: the profile's radial bins must be "
            f"between soil.r_min = {s.r_min!r} and repose.column_radius = "
            f"{rp.column_radius!r} wide"
        )


# spheres filled into the column's square box per sphere kept inside the cylinder: the
# square's area over the cylinder's (of the sphere centres, radius R - r_max), and 15 % more
# because the walls of the box pack looser than its middle
REPOSE_FILL_MARGIN = 1.15


def repose_fill(sc: Scenario) -> tuple[int, float]:
    """(spheres filled into the repose column's square box of side 2 column_radius, height of
    that loose fill (initial_fill_3d's grid of pitch 2.2 r_max)); the settled fill is cut to the
    cylinder and its soil.n lowest spheres kept (bed.settled_column). In 2D the box of width
    2 column_radius is the column: soil.n discs in initial_fill's rows."""
    s, R = sc.soil, sc.repose.column_radius
    pitch = 2.2 * s.r_max
    across = max(1, int((2 * R - 2 * s.r_max) / pitch))
    if sc.dim == 2:  # the box is the column: its discs are all kept (initial_fill's rows)
        return s.n, 2 * s.r_max + (-(-s.n // across) - 1) * pitch
    inner = max(R - s.r_max, 0.5 * s.r_max)
    ratio = 2 * R / inner
    n_fill = int(math.ceil(REPOSE_FILL_MARGIN * s.n * (ratio * ratio) / math.pi))
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
                f"must be finite and > 0"
            )
        if not (0.0 < m < math.inf and 0.0 < 0.5 * m * r * r < math.inf):
            raise ScenarioError(
                f"{key} = {r!r}: a disc of this radius has mass soil.density * pi * r^2 * "
                f"physics.thickness = {m:.3g} kg (moment of inertia {0.5 * m * r * r:.3g}): "
                f"must be finite and > 0"
            )
    if sc.wheel.enabled:
        mass = sc.wheel_mass
        if not (0.0 < mass < math.inf):
            raise ScenarioError(
                f"wheel.load = {sc.wheel.load!r}: the wheel mass wheel.load / physics.gravity "
                f"= {mass:.3g} kg must be finite and > 0"
            )
        steps_for_duration(sc.wheel.settle_time + sc.wheel.travel_time, ph.dt, "wheel.settle_time + wheel.travel_time")
    steps_for_duration(sc.bed.max_settle_time, ph.dt, "bed.max_settle_time")
    steps_for_duration(sc.output.series_interval, ph.dt, "output.series_interval")
    if sc.output.snapshot_interval:
        steps_for_duration(sc.output.snapshot_interval, ph.dt, "output.snapshot_interval")


def disc_mass(sc: Scenario, r: float) -> float:
    """density * pi * r^2 * thickness (3D: density * 4/3 pi r^3), as the engine computes it
    (products: inf or 0, never an exception)."""
    if sc.dim == 3:
        return sc.soil.density * (4.0 / 3.0) * math.pi * r**3
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
        for key, w2, z in (
            ("kn", nc * p.kn / m_min, p.damping_n),
            ("ks", nc * p.ks / m_min, p.damping_t),
            ("ks", nc * p.ks * s.r_min * s.r_min / i_min, p.damping_t),
        ):
            lim = limit(w2, z)
            if lim < worst:
                worst, which = lim, f"contact.{name}.{key}"
    return worst, which


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
            warnings.simplefilter("ignore", RuntimeWarning)  # an overflowing stiffness: 0 below
            crit, mode = critical_dt(
                cp,
                disc_mass(sc, s.r_min),
                s.r_min,
                sc.physics.impact_speed,
                sc.physics.contacts_per_disc,
                types=[types],
            )
        if math.isnan(crit):
            crit = 0.0
        if crit < worst:
            if pair.law == "hertz":
                key = f"contact.{name}.youngs_modulus (hertz)"
            else:
                key = f"contact.{name}.{'ks' if 'tangential' in mode else 'kn'} (linear)"
            worst, which = crit, f"{key}, {mode.split(', ')[-1]}"
    return worst, which


def scenario_from_dict(data: dict) -> Scenario:
    """The Scenario of a dict of sections (keys absent: the defaults; [materials] folded into
    the contact pairs, model.materials), checked."""
    sc = _build(Scenario, resolve_materials(data), "", Scenario())
    _check_ranges(sc)
    return sc
