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
from .inherit import merge_tables
from .schema import MAX_SCENARIO_FILE, NAME_RE, Scenario, ScenarioError, did_you_mean, show, show_key

__all__ = [
    "Scenario",
    "ScenarioError",
    "apply_overrides",
    "builtin_names",
    "load_scenario",
    "scenario_from_toml",
    "scenario_tables",
]

MAX_BASES = 32  # bases in one chain (a longer chain is a mistake, and each is a file read)


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
    """Load a built-in scenario by name (``paper2008``, ``quick``, ``bed-100k``) or a TOML file
    (which may name a ``base`` it changes: model/inherit.py)."""
    return scenario_from_dict(scenario_tables(source, overrides)[0])


def scenario_tables(source: str | Path, overrides: list[str] | None = None) -> tuple[dict, str | None]:
    """The raw tables of a scenario before its defaults are filled in (its bases merged in,
    the overrides applied) and the ``base`` the file names (None: none)."""
    src = str(source)
    data, base = _resolve(src, None, ())
    data = apply_overrides(data, overrides or [])
    _anchor_paths(data, Path.cwd())  # given by --set or by a built-in: from the working directory
    return data, base


def _anchor_paths(data: dict, directory: Path) -> None:
    """wheel.mesh and wheel.outline made absolute when they are relative paths (taken from
    ``directory``), so that the stored scenario of a run names the same files wherever it
    is resumed."""
    wheel = data.get("wheel")
    if not isinstance(wheel, dict):
        return
    for name in ("mesh", "outline"):
        path = wheel.get(name)
        if isinstance(path, str) and path and "\0" not in path and not Path(path).is_absolute():
            wheel[name] = str(directory / path)


def _builtin_tables(src: str) -> dict | None:
    """The tables of a built-in name (``quick``, ``bed-7000``), or None if src is not one."""
    if src.startswith("bed3d-") and _builtin_text(src) is None:
        n = _parse_count(src[6:])
        if n is None:
            raise ScenarioError(
                f"scenario {show(src, 400)}: bed3d-N needs a sphere count N such as bed3d-20000, bed3d-100k, bed3d-1m"
            )
        return bed3d_scenario_dict(n)
    if src.startswith("bed-") and _builtin_text(src) is None:
        n = _parse_count(src[4:])
        if n is None:
            raise ScenarioError(
                f"scenario {show(src, 400)}: bed-N needs a disc count N such as bed-7000, bed-100k, bed-1m"
            )
        return bed_scenario_dict(n)
    text = _builtin_text(src)
    return None if text is None else _parse_toml(text, src)


def _file_text(p: Path, src: str, what: str) -> str:
    """The text of a scenario file; ``what`` starts the one-line refusal (naming how it was given)."""
    try:
        is_file = p.is_file()
        size = p.stat().st_size if is_file else 0
    except (OSError, ValueError):  # name too long, NUL byte
        is_file, size = False, 0
    if not is_file:
        names = builtin_names()
        raise ScenarioError(
            f"{what}: not a built-in ({', '.join(names)}) and no such file" + did_you_mean(src, names[:-2])
        )
    if size > MAX_SCENARIO_FILE:
        raise ScenarioError(f"{what}: {size} bytes; a scenario file is at most {MAX_SCENARIO_FILE} bytes")
    try:
        return p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ScenarioError(f"{what}: cannot read ({_first_line(e)})") from None


def _resolve(src: str, naming: tuple[Path, str] | None, chain: tuple[tuple[str, str], ...]) -> tuple[dict, str | None]:
    """(tables, the base they name) of a built-in or a file, its chain of bases merged in.
    ``naming``: the file that names src as its base and how it was given (a relative path
    is taken from that file's directory); ``chain``: (identity, as given) of the files
    and built-ins that led here (a cycle is refused)."""
    what = f"scenario {show(src, 400)}"
    if naming is not None:
        what = f"scenario {show(naming[1], 400)}: base = {show(src, 400)}"
    data = _builtin_tables(src)
    path: Path | None = None
    if data is not None:
        identity = f"built-in {src}"
    else:
        path = Path(src) if naming is None else naming[0].parent / src
        text = _file_text(path, src, what)
        try:
            identity = str(path.resolve())
        except (OSError, RuntimeError):  # a symlink loop: the path as given
            identity = str(path)
        data = _parse_toml(text, src)
        _anchor_paths(data, path.parent.absolute())
    if identity in (ident for ident, _ in chain):
        cycle = " -> ".join([shown for _, shown in chain] + [src])
        raise ScenarioError(f"{what}: the bases make a cycle ({show(cycle, 400)})")
    base = data.pop("base", None)
    if base is None:
        return data, None
    if not isinstance(base, str) or not base:
        raise ScenarioError(
            f"scenario {show(src, 400)}: base = {show(base)}: must be a built-in name or a scenario file (a string)"
        )
    if len(chain) >= MAX_BASES:
        raise ScenarioError(f"{what}: more than {MAX_BASES} bases in a chain")
    origin = path if path is not None else Path.cwd() / "(built-in)"
    parent, _ = _resolve(base, (origin, src), (*chain, (identity, src)))
    return merge_tables(parent, data), base


def scenario_from_toml(text: str) -> Scenario:
    return scenario_from_dict(_parse_toml(text, "(stored)"))
