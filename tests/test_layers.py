"""The allowed import direction, read from the folders: physics -> model -> engine -> app
(ooc_dem/app/ and the entry points cli.py and api.py), storage independent, and below them
all ooc_dem/errors.py (the exceptions' base). A module may import its own layer and the
layers below it, never one above; storage imports nothing of the rest but the errors' base.
Read from the source with ast, so a new upward import fails here before it makes a circle."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# the layers are the package's folders, lowest first; the modules at the top of the package
# (the command line, the Python API, the package's __init__) are the application's entry points
ORDER = ["physics", "model", "engine", "app"]
INDEPENDENT = "storage"  # below everything, and imports nothing of the rest
# the base of every error for the user: importable from every layer, storage included; it
# imports nothing of ooc_dem
BASE = "ooc_dem.errors"


def layer(module: str) -> str:
    if module == BASE:
        return "base"
    parts = module.split(".")
    if len(parts) > 1 and parts[1] in (*ORDER, INDEPENDENT):
        return parts[1]
    return "app"


def test_every_module_lives_in_a_layer_folder():
    top = sorted(f.stem for f in ROOT.joinpath("ooc_dem").glob("*.py"))
    assert top == ["__init__", "api", "cli", "errors"], top
    # packages of code (scenarios/ holds the built-in scenarios' TOML files, no code)
    folders = sorted(
        d.name
        for d in ROOT.joinpath("ooc_dem").iterdir()
        if d.is_dir() and any(f.name != "__init__.py" for f in d.glob("*.py"))
    )
    assert folders == sorted([*ORDER, INDEPENDENT]), folders


def imports():
    """(module, imported module) for every ooc_dem / storage import in the package sources."""
    for f in sorted(ROOT.joinpath("ooc_dem").rglob("*.py")):
        parts = f.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        pkg = name if f.name == "__init__.py" else name.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                    targets = [mod] if node.module else [f"{mod}.{a.name}" for a in node.names]
                else:
                    targets = [node.module or ""]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            for t in targets:
                if t.split(".")[0] == "ooc_dem":
                    yield name, t


def test_the_import_graph_is_read():
    pairs = list(imports())
    assert ("ooc_dem.engine.stepper", "ooc_dem.physics") in {(a, b.rsplit(".", 1)[0]) for a, b in pairs} or any(
        a == "ooc_dem.engine.stepper" and b.startswith("ooc_dem.physics") for a, b in pairs
    )
    assert len(pairs) > 50


def test_no_import_goes_up_a_layer():
    bad = []
    for mod, dep in imports():
        lm, ld = layer(mod), layer(dep)
        if lm == "base":
            bad.append(f"{mod} -> {dep} (the errors' base imports nothing of ooc_dem)")
        elif ld == "base":
            continue
        elif lm == INDEPENDENT:
            if ld != INDEPENDENT:
                bad.append(f"{mod} -> {dep} (storage knows nothing of the rest of ooc_dem)")
        elif ld != INDEPENDENT and ORDER.index(ld) > ORDER.index(lm):
            bad.append(f"{mod} ({lm}) -> {dep} ({ld})")
        elif lm == "physics" and ld == INDEPENDENT:
            bad.append(f"{mod} -> {dep} (physics knows nothing of storage)")
    assert not bad, "imports against the module map:\n" + "\n".join(bad)


def _module_files(*dirs):
    """(dotted name, path) of every .py file under the given top-level directories."""
    for top in dirs:
        for f in sorted(ROOT.joinpath(top).rglob("*.py")):
            parts = f.relative_to(ROOT).with_suffix("").parts
            yield ".".join(parts[:-1] if parts[-1] == "__init__" else parts), f


def _import_nodes(name, f):
    """(node, absolute module, imported names) for every import in file f of module name."""
    pkg = name if f.name == "__init__.py" else name.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(f.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            yield node, mod, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            for a in node.names:
                yield node, a.name, []


def _type_only_imports(f) -> set[int]:
    """ids of the import nodes under `if TYPE_CHECKING:` (read by a type checker, never run)."""
    out = set()
    for node in ast.walk(ast.parse(f.read_text())):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            out.update(
                (type(n).__name__, n.lineno)
                for b in node.body
                for n in ast.walk(b)
                if isinstance(n, (ast.Import, ast.ImportFrom))
            )
    return out


def import_graph() -> dict[str, set[str]]:
    """ooc_dem module -> the ooc_dem modules it imports, at module level or inside a
    function alike (a lazy import is still an import: it only hides a circle); an import
    for the type checker only (under TYPE_CHECKING) never runs, so it makes no circle."""
    modules = dict(_module_files("ooc_dem"))
    graph = {m: set() for m in modules}
    for name, f in modules.items():
        type_only = _type_only_imports(f)
        for node, mod, names in _import_nodes(name, f):
            if (type(node).__name__, node.lineno) in type_only:
                continue
            # `from package import module` imports the module (and the package's __init__,
            # which is a circle only where the package's own modules do it)
            submodules = [f"{mod}.{n}" for n in names if f"{mod}.{n}" in modules]
            for target in submodules or [mod]:
                if target in modules and target != name:
                    graph[name].add(target)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle (a list of modules, the first repeated at the end), or None."""
    state, stack = {}, []

    def visit(m):
        state[m] = "open"
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == "open":
                return stack[stack.index(n) :] + [n]
            if n not in state and (c := visit(n)):
                return c
        stack.pop()
        state[m] = "done"
        return None

    for m in sorted(graph):
        if m not in state and (c := visit(m)):
            return c
    return None


def test_cycle_finder_finds_a_circle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def test_no_import_cycle():
    graph = import_graph()
    assert graph["ooc_dem.app.run"] and graph["ooc_dem.app.plots"], "import graph not read"
    cycle = find_cycle(graph)
    assert cycle is None, "import circle: " + " -> ".join(cycle)


def test_no_private_storage_names_outside_storage():
    """The package and the tools use storage's public API only (ooc_dem/storage/__init__.py's
    names): no storage._module and no _name imported or reached from storage. (tests/
    is left out: the store conformance tests check storage's internals on purpose.)"""
    bad = []
    for name, f in _module_files("ooc_dem", "tools"):
        for node, mod, names in _import_nodes(name, f):
            if not (mod == "ooc_dem.storage" or mod.startswith("ooc_dem.storage.")) or name.startswith(
                "ooc_dem.storage"
            ):
                continue
            private = [p for p in mod.split(".")[2:] + names if p.startswith("_")]
            if private:
                bad.append(f"{f.relative_to(ROOT)}:{node.lineno}: {mod} {', '.join(private)}")
        for node in ast.walk(ast.parse(f.read_text())):
            if (
                isinstance(node, ast.Attribute)
                and node.attr.startswith("_")
                and isinstance(node.value, ast.Name)
                and node.value.id == "storage"
            ):
                bad.append(f"{f.relative_to(ROOT)}:{node.lineno}: storage.{node.attr}")
    assert not bad, "private storage names used outside ooc_dem/storage/:\n" + "\n".join(bad)


# the run loop, its planning and resume, the engines, their interface and the mode registry
DISPATCH_FREE = (
    "ooc_dem/app/run.py",
    "ooc_dem/app/plan.py",
    "ooc_dem/app/resume.py",
    "ooc_dem/engine/sweep.py",
    "ooc_dem/engine/ooc.py",
    "ooc_dem/engine/monolithic.py",
    "ooc_dem/engine/interface.py",
    "ooc_dem/engine/modes.py",
    "ooc_dem/engine/budget.py",
    "ooc_dem/engine/mpi/*.py",
)


def test_the_engines_and_the_run_loop_dispatch_on_no_attribute():
    """The run loop asks an engine nothing but the Engine protocol, and the MPI ranks run the
    operations of an engine's table: no hasattr / getattr."""
    files = sorted({f for pattern in DISPATCH_FREE for f in ROOT.glob(pattern)})
    assert len(files) > len(DISPATCH_FREE), files
    bad = []
    for f in files:
        rel = f.relative_to(ROOT)
        for node in ast.walk(ast.parse(f.read_text())):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and node.func.id in ("hasattr", "getattr")
            ):
                bad.append(f"{rel}:{node.lineno}: {node.func.id}")
    assert not bad, "\n".join(bad)


def is_app_code(f) -> bool:
    """Whether the callable f is the application's: a function or method defined in an
    application module, or a method bound to an object of one."""
    owner = getattr(f, "__self__", None)
    modules = [getattr(f, "__module__", None) or "", type(owner).__module__ if owner is not None else ""]
    return any(layer(m) == "app" for m in modules if m.startswith("ooc_dem"))


def test_app_code_is_recognised():
    from ooc_dem.app.run import Simulation
    from ooc_dem.engine.sweep import SlabSweep
    from ooc_dem.app.trajectory import FrameParts

    assert is_app_code(Simulation.commit) and is_app_code(FrameParts(None, 0).write_part)
    assert not is_app_code(lambda: None)
    assert not is_app_code(SlabSweep.info) and not is_app_code(print)


def test_no_engine_takes_a_callback():
    """Engines are given data, never the application's functions: no parameter of an
    engine's constructors is annotated Callable or has a callable default."""
    from ooc_dem.engine.modes import MODES

    bad, seen = [], 0
    for mode in MODES.values():
        cls = mode.engine
        for name in ("__init__", "create", "create_streamed", "reopen", "on_worker"):
            f = inspect.getattr_static(cls, name, None)
            if f is None or f is object.__init__:
                continue
            f = f.__func__ if isinstance(f, classmethod) else f
            for p in inspect.signature(f).parameters.values():
                seen += 1
                callable_default = p.default is not p.empty and callable(p.default)
                if "Callable" in str(p.annotation) or callable_default:
                    bad.append(f"{cls.__name__}.{name}({p.name})")
    assert seen > 50 and not bad, bad


def test_the_modes_are_listed_once():
    """The modes are named in one registry (engine/modes.py): elsewhere in the package no
    tuple, list or set of mode names, and no comparison of a mode with a mode's name (the
    code asks the registry's capabilities)."""
    from ooc_dem.engine.modes import MODES

    names = set(MODES)
    bad = []
    for name, f in _module_files("ooc_dem"):
        if name == "ooc_dem.engine.modes":
            continue
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
                listed = [e.value for e in node.elts if isinstance(e, ast.Constant) and e.value in names]
                if len(listed) >= 2:
                    bad.append(f"{f.relative_to(ROOT)}:{node.lineno}: {listed}")
            elif isinstance(node, ast.Compare):
                left = node.left
                is_mode = (isinstance(left, ast.Name) and left.id == "mode") or (
                    isinstance(left, ast.Attribute) and left.attr == "mode"
                )
                named = [c.value for c in node.comparators if isinstance(c, ast.Constant) and c.value in names]
                if is_mode and named:
                    bad.append(f"{f.relative_to(ROOT)}:{node.lineno}: mode compared with {named}")
    assert not bad, "\n".join(bad)


@pytest.fixture(scope="module")
def tiny_runs(tmp_path_factory):
    """A four-step run of a 300-disc bed in each mode; (mode, engine, simulation)."""
    from ooc_dem.app.run import RunOptions, Simulation
    from ooc_dem.model.scenario import load_scenario

    sc = load_scenario("bed-300", ["decomposition.policy=equal"])
    runs = []
    for mode in ("monolithic", "ddm", "ooc"):
        opts = RunOptions(mode=mode, backend="hdf5", domains=2, block=2, steps=4, progress=False, figures=False)
        sim = Simulation(sc, tmp_path_factory.mktemp(mode) / "run", opts)
        sim.start()
        engine = sim.engine
        summary = sim.run()
        runs.append((mode, engine, sim, summary))
    return runs


def test_every_engine_satisfies_the_protocol(tiny_runs):
    from ooc_dem.engine.interface import Engine
    from ooc_dem.engine.monolithic import MonolithicEngine
    from ooc_dem.app.run import Simulation
    from ooc_dem.engine.ooc import OocEngine
    from ooc_dem.engine.sweep import DdmEngine

    classes = {"monolithic": MonolithicEngine, "ddm": DdmEngine, "ooc": OocEngine}
    # the protocol's members: its methods and properties, and its annotated attributes
    members = sorted({m for m in [*vars(Engine), *Engine.__annotations__] if not m.startswith("_")})
    assert {"advance", "commit", "info", "wheel_state", "epoch_each_advance"} <= set(members)
    hashes = set()
    for mode, engine, sim, summary in tiny_runs:
        assert type(engine) is classes[mode] and engine.name == mode
        assert isinstance(engine, Engine), mode
        # the protocol's methods with the protocol's parameters
        for m in members:
            want = inspect.getattr_static(Engine, m, None)
            if inspect.isfunction(want):
                got = inspect.signature(getattr(type(engine), m))
                assert list(got.parameters) == list(inspect.signature(want).parameters), (mode, m)
        # an engine holds what it was given, never the simulation that made it, nor any
        # function of the application (a bound method of one of its objects, a closure):
        # engines never call back into the application
        assert not any(isinstance(v, Simulation) for v in vars(engine).values()), mode
        held = [(k, v) for k, v in vars(engine).items() if callable(v) and not isinstance(v, type) and is_app_code(v)]
        assert not held, (mode, held)
        assert summary["n_discs"] == 300 and summary["steps"] == 4
        hashes.add(summary["state_hash"])
    assert len(hashes) == 1, "the three engines must give the same bits"
