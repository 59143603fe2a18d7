"""Materials and the contact pairs derived from them.

A scenario may name the materials of the soil, the walls and the wheel (``[materials.soil]``,
``[materials.wall]``, ``[materials.wheel]``: a ``preset`` and/or its own ``youngs_modulus``,
``poisson_ratio``, ``restitution``, ``friction``, ``rolling_friction``, ``cohesion``). Each
contact pair (``[contact.soil_soil]``, ``soil_wall``, ``soil_wheel``) takes every key it does
not set itself from its two materials, by these mixing rules:

- elastic constants: the soil's surface is the pair's first (``youngs_modulus``,
  ``poisson_ratio``), the other body's the second (``youngs_modulus_2``, ``poisson_ratio_2``);
  the Hertz law combines them exactly (1/E* = (1 - nu1^2)/E1 + (1 - nu2^2)/E2). A pair whose
  two materials have a Young's modulus uses the Hertz law unless it names its law (3D).
- restitution, friction, rolling friction, cohesion: the smaller of the two materials'
  values (the pair is as lossy, slippery and weakly bonded as its weaker surface); when only
  one material gives a value, that one.
- ``stiffness = "soil"`` on the wall or the wheel: its contacts take the soil's elastic
  constants instead of its own (a steel wheel on a soil whose modulus was lowered for the
  time step stays as soft as the soil: the usual remedy, rather than a step ~10x smaller).

A pair's own keys always win; what is derived is written into the pair, so a stored
scenario holds the values the run used. The linear law's normal damping may be given as a
restitution coefficient: ``restitution`` without ``damping_n`` sets
damping_n = -ln e / sqrt(pi^2 + ln^2 e), the ratio that gives e for a linear spring-dashpot
whose force may pull (``no_tension = false``); with the clamp on the rebound is livelier
(the README has the table). A table giving both must give the same damping (as a stored
scenario does), except restitution = 0.5, which older versions wrote for every pair; a
``--set`` of one replaces the other.

Resolution works on the scenario's raw tables, before they are checked, so "a key the pair
sets" is simply a key present in its table.
"""

from __future__ import annotations

import math
from typing import Any

from ..physics import exactmath
from .schema import ScenarioError, did_you_mean, show, show_key

# elastic constants of common materials (room temperature; handbook values, rounded)
PRESETS: dict[str, dict[str, float]] = {
    "steel": {"youngs_modulus": 2.0e11, "poisson_ratio": 0.30},
    "stainless_steel": {"youngs_modulus": 1.93e11, "poisson_ratio": 0.29},
    "aluminium": {"youngs_modulus": 6.9e10, "poisson_ratio": 0.33},
    "glass": {"youngs_modulus": 6.3e10, "poisson_ratio": 0.22},
    "quartz": {"youngs_modulus": 7.6e10, "poisson_ratio": 0.08},
    "rubber": {"youngs_modulus": 1.0e7, "poisson_ratio": 0.49},
}
BODIES = ("soil", "wall", "wheel")
MATERIAL_KEYS = (
    "preset",
    "youngs_modulus",
    "poisson_ratio",
    "restitution",
    "friction",
    "rolling_friction",
    "cohesion",
    "stiffness",
)
PAIRS = {"soil_soil": "soil", "soil_wall": "wall", "soil_wheel": "wheel"}
MIN_RULE_KEYS = ("restitution", "friction", "rolling_friction", "cohesion")


# what older versions wrote as every pair's restitution (the linear law ignored it)
LEGACY_RESTITUTION = 0.5


def zeta_of_restitution(e: float) -> float:
    """The damping ratio of a linear spring-dashpot whose rebound has restitution e (the
    force allowed to pull): -ln e / sqrt(pi^2 + ln^2 e); 0 for e = 1. ln correctly rounded
    (the same on every machine: exactmath)."""
    if e >= 1.0:
        return 0.0
    le = exactmath.ln(e)
    return -le / math.sqrt(le * le + math.pi * math.pi)


def restitution_of_zeta(zeta: float) -> float:
    """The restitution of a linear spring-dashpot of damping ratio zeta < 1 (the force
    allowed to pull): exp(-pi zeta / sqrt(1 - zeta^2)); 0 from zeta = 1 on."""
    if zeta >= 1.0:
        return 0.0
    return exactmath.exp(-math.pi * zeta / math.sqrt(1.0 - zeta * zeta))


def _material(raw: Any, body: str) -> dict[str, Any]:
    """One [materials.<body>] table with its preset expanded (its own keys win)."""
    where = f"materials.{body}"
    if not isinstance(raw, dict):
        raise ScenarioError(f"{where} = {show(raw)}: must be a table")
    unknown = sorted(set(raw) - set(MATERIAL_KEYS))
    if unknown:
        raise ScenarioError(
            f"{where}.{show_key(unknown[0])}: unknown key (allowed: {', '.join(MATERIAL_KEYS)})"
            + did_you_mean(unknown[0], MATERIAL_KEYS)
        )
    out: dict[str, Any] = {}
    if "preset" in raw:
        name = raw["preset"]
        if not isinstance(name, str) or name not in PRESETS:
            raise ScenarioError(f"{where}.preset = {show(name)}: must be one of {', '.join(map(repr, PRESETS))}")
        out.update(PRESETS[name])
    for key, v in raw.items():
        if key == "preset":
            continue
        if key == "stiffness":
            if v not in ("own", "soil") or body == "soil":
                allowed = "'own' or 'soil'" if body != "soil" else "not a key of the soil itself"
                raise ScenarioError(f"{where}.stiffness = {show(v)}: must be {allowed}")
            out[key] = v
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ScenarioError(f"{where}.{key} = {show(v)}: must be a finite number")
        out[key] = float(v)
    return out


def _mixed(key: str, a: dict, b: dict) -> float | None:
    """The pair value of a min-rule key from materials a and b (None: neither has it)."""
    vals = [m[key] for m in (a, b) if key in m]
    return min(vals) if vals else None


def resolve_materials(data: dict) -> dict:
    """The scenario's raw tables with [materials] folded into the contact pairs (see the
    module doc) and the linear law's restitution turned into its damping ratio. Returns a
    new dict without the [materials] table; the input is not changed."""
    if not isinstance(data, dict):
        return data
    out = {k: v for k, v in data.items() if k != "materials"}
    raw = data.get("materials", {})
    if not isinstance(raw, dict):
        raise ScenarioError(f"materials = {show(raw)}: must be a table")
    unknown = sorted(set(raw) - set(BODIES))
    if unknown:
        raise ScenarioError(
            f"materials.{show_key(unknown[0])}: unknown material (allowed: {', '.join(BODIES)})"
            + did_you_mean(unknown[0], BODIES)
        )
    mats = {body: _material(raw.get(body, {}), body) for body in BODIES}
    physics = data.get("physics", {})
    dim = physics.get("dim", 2) if isinstance(physics, dict) else 2
    if dim != 3:
        for body, m in mats.items():
            for key in ("youngs_modulus", "poisson_ratio"):
                if key in m:
                    raise ScenarioError(
                        f"materials.{body}.{key}: elastic constants need physics.dim = 3 "
                        f"(2D discs take contact.*.kn and ks)"
                    )
    contact = data.get("contact", {})
    if not isinstance(contact, dict):
        return out  # the schema check names it
    new_contact = dict(contact)
    for pair, other in PAIRS.items():
        table = contact.get(pair, {})
        if not isinstance(table, dict):
            continue  # the schema check names it
        t = dict(table)
        soil, mat = mats["soil"], mats[other]
        if mat.get("stiffness") == "soil":
            mat = {k: v for k, v in mat.items() if k not in ("youngs_modulus", "poisson_ratio")}
            mat.update({k: soil[k] for k in ("youngs_modulus", "poisson_ratio") if k in soil})
        linear_damped = t.get("law", "linear") == "linear" and "damping_n" in t
        for key in MIN_RULE_KEYS:
            v = _mixed(key, soil, mat)
            if v is not None and key not in t and not (key == "restitution" and linear_damped):
                t[key] = v
        if "youngs_modulus" in soil and "youngs_modulus" in mat:
            t.setdefault("law", "hertz")
        for mine, src in (("youngs_modulus", soil), ("poisson_ratio", soil)):
            if mine in src and mine not in t:
                t[mine] = src[mine]
        for mine, key in (("youngs_modulus_2", "youngs_modulus"), ("poisson_ratio_2", "poisson_ratio")):
            if key in mat and mine not in t:
                t[mine] = mat[key]
        e = t.get("restitution")
        if (
            t.get("law", "linear") == "linear"
            and isinstance(e, (int, float))
            and not isinstance(e, bool)
            and 0.0 < e <= 1.0
        ):
            zeta = zeta_of_restitution(float(e))
            if "damping_n" not in t:
                t["damping_n"] = zeta
            elif t["damping_n"] != zeta and e != LEGACY_RESTITUTION:
                raise ScenarioError(
                    f"contact.{pair}: restitution = {show(e)} and damping_n = {show(t['damping_n'])} "
                    f"disagree (the linear law's damping is one of them: restitution {show(e)} is "
                    f"damping_n {zeta!r}); give one"
                )
        if t != table or pair in contact:
            new_contact[pair] = t
    out["contact"] = new_contact
    return out
