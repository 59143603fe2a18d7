"""The allowed import direction (README "Module map"): physics -> state -> engine ->
application, storage independent. A module may import its own layer and the layers
below it, never one above; storage imports nothing of ooc_dem. Read from the source
with ast, so a new upward import fails here before it makes a circle."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ORDER = ["physics", "state", "engine", "application"]
STATE = {"ooc_dem.state", "ooc_dem.statehash", "ooc_dem.checkpoint", "ooc_dem.scenario", "ooc_dem.decomposition",
         "ooc_dem.fields", "ooc_dem.atomic"}
ENGINE = {"ooc_dem.engine", "ooc_dem.engine.stepper", "ooc_dem.engine.live", "ooc_dem.engine.sweep",
          "ooc_dem.bed"}


def layer(module: str) -> str:
    if module == "storage" or module.startswith("storage."):
        return "storage"
    if module.startswith("ooc_dem.physics"):
        return "physics"
    if module in STATE:
        return "state"
    if module in ENGINE:
        return "engine"
    return "application"    # engine.run (the Simulation), metrics, plots, export, cli, api, ...


def imports():
    """(module, imported module) for every ooc_dem / storage import in the package sources."""
    for f in sorted([*ROOT.joinpath("ooc_dem").rglob("*.py"), *ROOT.joinpath("storage").rglob("*.py")]):
        parts = f.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        pkg = name if f.name == "__init__.py" else name.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg.split(".")[:len(pkg.split(".")) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                    targets = [mod] if node.module else [f"{mod}.{a.name}" for a in node.names]
                else:
                    targets = [node.module or ""]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            for t in targets:
                if t.split(".")[0] in ("ooc_dem", "storage"):
                    yield name, t


def test_the_import_graph_is_read():
    pairs = list(imports())
    assert ("ooc_dem.engine.stepper", "ooc_dem.physics") in {(a, b.rsplit(".", 1)[0]) for a, b in pairs} \
        or any(a == "ooc_dem.engine.stepper" and b.startswith("ooc_dem.physics") for a, b in pairs)
    assert len(pairs) > 50


def test_no_import_goes_up_a_layer():
    bad = []
    for mod, dep in imports():
        lm, ld = layer(mod), layer(dep)
        if lm == "storage":
            if ld != "storage":
                bad.append(f"{mod} -> {dep} (storage knows nothing of ooc_dem)")
        elif ld != "storage" and ORDER.index(ld) > ORDER.index(lm):
            bad.append(f"{mod} ({lm}) -> {dep} ({ld})")
        elif lm == "physics" and ld == "storage":
            bad.append(f"{mod} -> {dep} (physics knows nothing of storage)")
    assert not bad, "imports against the module map:\n" + "\n".join(bad)
