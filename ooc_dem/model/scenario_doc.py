"""A scenario's keys with their units and meanings (schema.py's ``key`` metadata) and their
allowed values (scenario_check.py's): the walk over the sections that docs/parameters.md
(tools/gen_parameters_doc.py) is generated from, and the complete, commented TOML of a
resolved scenario that `ooc-dem scenarios --show` prints (it loads back to the same
scenario)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Any

from .scenario_check import allowed_values
from .schema import Scenario, dict_to_toml, key_doc


@dataclasses.dataclass(frozen=True)
class KeyInfo:
    """One key of a section: its dotted table (``contact.soil_soil``), name, type, default,
    unit, meaning and allowed values."""

    table: str
    name: str
    typ: str
    default: Any
    unit: str
    meaning: str
    allowed: str

    @property
    def path(self) -> str:
        return f"{self.table}.{self.name}"


def _type_of(f: dataclasses.Field[Any], default: Any) -> str:
    if isinstance(default, bool) or f.name in ("enabled", "no_tension"):
        return "bool"
    if isinstance(default, tuple):
        return "array of numbers"
    return {int: "integer", float: "number", str: "string"}.get(type(default), "table")


def walk_tables(obj: Any, table: str = "") -> Iterator[tuple[str, Any, str, str]]:
    """(dotted name, section object, unit, meaning) of every table of ``obj`` (a Scenario
    or a section), outer tables first."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            name = f"{table}.{f.name}" if table else f.name
            unit, meaning = key_doc(f)
            yield name, value, unit, meaning
            yield from walk_tables(value, name)


def table_keys(table: str, section: Any) -> Iterator[KeyInfo]:
    """The scalar keys (and arrays) of one table, in declaration order."""
    for f in dataclasses.fields(section):
        value = getattr(section, f.name)
        if dataclasses.is_dataclass(value):
            continue
        unit, meaning = key_doc(f)
        yield KeyInfo(table, f.name, _type_of(f, value), value, unit, meaning, allowed_values(table, f.name))


def every_key(sc: Scenario | None = None) -> Iterator[KeyInfo]:
    """Every key of a scenario (default: the defaults), table by table."""
    for table, section, _, _ in walk_tables(sc if sc is not None else Scenario()):
        yield from table_keys(table, section)


def _comment(info: KeyInfo) -> str:
    return f"[{info.unit}] {info.meaning}" if info.unit else info.meaning


def commented_toml(sc: Scenario, header: list[str]) -> str:
    """The complete TOML of ``sc``, every key with a comment (unit: meaning); an unset
    optional key is a commented-out line. Loads back to the same scenario."""
    lines = [f"# {h}" if h else "#" for h in header]
    for table, section, _, meaning in walk_tables(sc):
        infos = list(table_keys(table, section))
        if not infos:
            continue
        lines += ["", f"[{table}]  # {meaning}"]
        rows = []
        for info in infos:
            if info.default is None:
                rows.append((f"# {info.name} = (unset)", _comment(info)))
            else:
                text = dict_to_toml({info.name: info.default}).strip()
                rows.append((text, _comment(info)))
        width = min(44, max(len(r[0]) for r in rows))
        lines += [f"{text:<{width}}  # {comment}" for text, comment in rows]
    return "\n".join(lines) + "\n"
