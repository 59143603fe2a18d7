"""Typed, validated scenarios: TOML -> frozen dataclasses.

A scenario is a built-in (``ooc_dem/scenarios/*.toml``, ``bed-N``, ``bed3d-N``) or a TOML
file, with ``--set``-style overrides; every value is checked (model/scenario_check.py) and a
bad one raises ``ScenarioError`` with one line naming the key, the value and what is allowed.

This module loads scenarios; the sections, limits and message helpers are model/schema.py's,
building and checking (and the critical time step) model/scenario_check.py's. ``Scenario``
and ``ScenarioError`` are the package's public names (``ooc_dem.Scenario``,
``ooc_dem.ScenarioError``) and are taken from here.
"""

from __future__ import annotations

import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from .scenario_check import scenario_from_dict
from .schema import MAX_SCENARIO_FILE, NAME_RE, Scenario, ScenarioError, show, show_key

__all__ = [
    "Scenario",
    "ScenarioError",
    "apply_overrides",
    "builtin_names",
    "load_scenario",
    "scenario_from_toml",
]


def builtin_names() -> list[str]:
    files = resources.files("ooc_dem.scenarios")
    names = sorted(p.name[:-5] for p in files.iterdir() if p.name.endswith(".toml"))
    return names + ["bed-N", "bed3d-N"]


def _builtin_text(name: str) -> str | None:
    if NAME_RE.fullmatch(name) is None:  # never a path: built-ins are files of one package
        return None
    f = resources.files("ooc_dem.scenarios") / f"{name}.toml"
    if f.is_file():
        return f.read_text()
    return None


def _builtin_dict(name: str) -> dict:
    """A built-in scenario the package must hold (the beds tiles are cut from), parsed."""
    text = _builtin_text(name)
    if text is None:
        raise ScenarioError(f"built-in scenario {name!r} is missing from the installed package")
    return tomllib.loads(text)


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
    if not math.isfinite(v) or v < 1 or v != int(v):  # inf, nan, 1e400, 0, -5, 12.5
        return None
    return int(v)


def bed_scenario_dict(n: int) -> dict:
    """A bare bed of n discs with paper2008's soil, built from settled tiles.

    The bin is as deep as paper2008's bed; its length grows with n.
    """
    base = _builtin_dict("bed")
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
    base = _builtin_dict("bed3d")
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
    except ValueError as e:  # e.g. an integer beyond Python's int-string conversion limit
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
        if len(parts) > 3:  # the deepest key is contact.<pair>.<key>
            raise ScenarioError(
                f"--set {show(item)}: key {show(key, 40)} has {len(parts)} parts; "
                f"keys are section.key or contact.pair.key"
            )
        node = data
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ScenarioError(f"--set {show(item)}: {show_key(p)} is not a section")
        node[parts[-1]] = _parse_value(text.strip(), item)
        # the linear law's damping is stated either way: the override replaces the other
        other = {"restitution": "damping_n", "damping_n": "restitution"}.get(parts[-1])
        if parts[0] == "contact" and other:
            node.pop(other, None)
    return data


def _parse_toml(text: str, src: str) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(f"scenario {show(src, 400)}: invalid TOML ({_first_line(e)})") from None
    except RecursionError:
        raise ScenarioError(f"scenario {show(src, 400)}: invalid TOML (tables or arrays nested too deeply)") from None
    except ValueError as e:  # an integer beyond Python's int-string conversion limit
        raise ScenarioError(f"scenario {show(src, 400)}: invalid TOML ({_first_line(e)})") from None


def load_scenario(source: str | Path, overrides: list[str] | None = None) -> Scenario:
    """Load a built-in scenario by name (``paper2008``, ``quick``, ``bed-100k``) or a TOML file."""
    text = None
    data: dict
    src = str(source)
    if src.startswith("bed3d-") and _builtin_text(src) is None:
        n = _parse_count(src[6:])
        if n is None:
            raise ScenarioError(
                f"scenario {show(src, 400)}: bed3d-N needs a sphere count N such as bed3d-20000, bed3d-100k, bed3d-1m"
            )
        data = bed3d_scenario_dict(n)
    elif src.startswith("bed-") and _builtin_text(src) is None:
        n = _parse_count(src[4:])
        if n is None:
            raise ScenarioError(
                f"scenario {show(src, 400)}: bed-N needs a disc count N such as bed-7000, bed-100k, bed-1m"
            )
        data = bed_scenario_dict(n)
    else:
        text = _builtin_text(src)
        if text is None:
            p = Path(src)
            try:
                is_file = p.is_file()
                size = p.stat().st_size if is_file else 0
            except (OSError, ValueError):  # name too long, NUL byte
                is_file, size = False, 0
            if not is_file:
                raise ScenarioError(
                    f"scenario {show(src, 400)}: not a built-in ({', '.join(builtin_names())}) and no such file"
                )
            if size > MAX_SCENARIO_FILE:
                raise ScenarioError(
                    f"scenario {show(src, 400)}: {size} bytes; a scenario file is at most {MAX_SCENARIO_FILE} bytes"
                )
            try:
                text = p.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as e:
                raise ScenarioError(f"scenario {show(src, 400)}: cannot read ({_first_line(e)})") from None
        data = _parse_toml(text, src)
    data = apply_overrides(data, overrides or [])
    return scenario_from_dict(data)


def scenario_from_toml(text: str) -> Scenario:
    return scenario_from_dict(_parse_toml(text, "(stored)"))
