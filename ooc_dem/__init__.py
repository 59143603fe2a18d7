"""ooc-dem: out-of-core 2D DEM of soil-wheel interaction (Nakashima 2008, serial DDM).

Python API (the same checks, code paths and bits as the ``ooc-dem`` command line)::

    import ooc_dem
    sc = ooc_dem.load_scenario("quick", overrides={"wheel.travel_time": 0.3})
    res = ooc_dem.run(sc, out="runs/quick-short")          # -> RunResult
    res.summary["slip"]["whole_travel"]["value"]            # summary.json as a dict
    res.series["net_traction"]                              # series.csv, structured array
    res.state()["id"]                                       # discs of the last epoch, by id
    ooc_dem.resume("runs/quick-short", until=1.0)           # continue a killed/finished run

Functions
---------
load_scenario(name_or_path, overrides=None) -> Scenario
    A built-in scenario or TOML file, validated, with ``--set``-style overrides.
run(scenario, out=None, mode="monolithic", domains=None, block=None, backend="hdf5",
    steps=None, duration=None, progress=False, ...) -> RunResult
    Run to the end, as ``ooc-dem run`` (progress bar off unless ``progress=True``).
resume(path, steps=None, until=None, progress=False, figures=False) -> RunResult
    Continue from the last committed epoch, as ``ooc-dem resume``.
open_run(path) -> RunResult
    The results of an existing run directory.
open_store(path) -> ooc_dem.storage.Store
    A run's store, read-only (epochs, verify, read_epoch).

Classes
-------
RunResult: ``path``, ``summary``, ``series``, ``series_frame()`` / ``to_pandas()``,
``epochs()``, ``state(epoch=None)``, ``trajectory()`` (frames, sorted by id).
Scenario: the frozen, validated scenario dataclass.

Exceptions (every message is one line, as the CLI prints it)
----------
OocDemError, the base of them all: ScenarioError (a ValueError), RunError, StoreError,
StateError (a ValueError), EngineError, BedError, RunFileError (a ValueError).

Names are imported on first use, so ``import ooc_dem`` stays cheap. The full reference is
docs/api.md in the repository (generated from these docstrings by tools/gen_api_docs.py).
"""

__version__ = "0.1.0"

# An ooc-dem process lives on a few arrays of one value per particle, made and freed
# as it sets up, sorts, rebuilds neighbour lists and streams slabs: malloc's mmap
# threshold is fixed for the whole process (heap.py), so that every freed large array
# is given back instead of kept in a heap glibc carves the next ones from (a monolithic
# bed-1000000 kept ~55 B/disc of its set-up's freed arrays). Costs ~6 ms.
from .engine.heap import bound_heap as _bound_heap  # noqa: E402

_bound_heap()

# name -> module that defines it (relative to this package)
_LAZY = {
    "load_scenario": ".api",
    "run": ".api",
    "resume": ".api",
    "open_run": ".api",
    "open_store": ".api",
    "RunResult": ".api",
    "OocDemError": ".errors",
    "Scenario": ".model.scenario",
    "ScenarioError": ".model.scenario",
    "RunError": ".app.run",
    "EngineError": ".engine.stepper",
    "StateError": ".model.state_check",
    "BedError": ".app.bed",
    "RunFileError": ".app.runfiles",
    "StoreError": ".storage",
}

__all__ = ["__version__", *_LAZY]  # noqa: PLE0604  (the keys of _LAZY: strings)


def __getattr__(name):
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'ooc_dem' has no attribute {name!r}")
    import importlib

    value = getattr(
        importlib.import_module(mod, __name__) if mod.startswith(".") else importlib.import_module(mod), name
    )
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
