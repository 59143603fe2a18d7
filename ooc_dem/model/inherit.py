"""Scenario files that inherit: ``base = "quick-3d"`` at the top of a file (a built-in name,
or a file path relative to the file that names it) and the file holds only what it changes.

The base's tables and the file's are merged section by section and key by key, nested tables
too (``[soil.grading]``, ``[contact.*]``, ``[materials.*]``), so that the file resolves to
exactly the scenario the complete file would be, the same as ``--set`` of each of its keys.
Where a key-wise merge would keep a base key that contradicts the file, the file's table
wins as ``--set`` does:

- ``[soil.grading]`` naming another ``kind`` than the base's replaces the base's table (each
  kind reads only its own keys; the base's would be refused beside the new kind);
- in a ``[contact.<pair>]`` table ``restitution`` and ``damping_n`` state the linear law's
  one damping: the file's replaces the base's other one;
- a ``[materials.<body>]`` table naming a ``preset`` drops the base's own elastic constants
  of that body (``youngs_modulus``, ``poisson_ratio``) unless it gives them too.

The ``[scenario]`` name is inherited too (runs go to ``runs/<name>``): set it when the file is
a scenario of its own. Chains are allowed; a cycle or a missing base is refused in one line.
"""

from __future__ import annotations

import copy
from typing import Any

# the linear law's normal damping is stated either way: stating one replaces the other
DAMPING_TWINS = {"restitution": "damping_n", "damping_n": "restitution"}
PRESET_KEYS = ("youngs_modulus", "poisson_ratio")


def merge_tables(base: dict, child: dict, path: tuple[str, ...] = ()) -> dict:
    """The base's tables with the child's merged in, key by key (the rules of the module
    doc); neither input is changed."""
    out = copy.deepcopy(base)
    for key, value in child.items():
        here = (*path, key)
        have = out.get(key)
        if isinstance(value, dict) and isinstance(have, dict) and not _replaces(here, have, value):
            out[key] = merge_tables(have, value, here)
        else:
            out[key] = copy.deepcopy(value)
    if len(path) == 2 and path[0] == "contact":
        for key, other in DAMPING_TWINS.items():
            if key in child and other not in child:
                out.pop(other, None)
    if len(path) == 2 and path[0] == "materials" and "preset" in child:
        for key in PRESET_KEYS:
            if key not in child:
                out.pop(key, None)
    return out


def _replaces(path: tuple[str, ...], base: dict, child: dict) -> bool:
    """Whether the child's table replaces the base's whole (a grading of another kind)."""
    if path == ("soil", "grading") and "kind" in child:
        return child["kind"] != base.get("kind", "uniform")
    return False


def base_of(data: Any) -> Any:
    """The ``base`` a file's tables name (None: none)."""
    return data.get("base") if isinstance(data, dict) else None
