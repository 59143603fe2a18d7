"""The strategies by name, the base material they need, and a strategy's run (its known cases and
n generated ones, under hypothesis)."""

from __future__ import annotations

import sys

from .fuzzer import Fuzzer
from .known import KNOWN
from .strategies import build_strategies


STRATEGY_NAMES = (
    "scenario",
    "scenario_file",
    "cli",
    "manifest",
    "epoch",
    "runfiles",
    "epoch3d",
    "bed",
    "trajectory",
    "npz",
    "zarr_codec",
    "fsize",
)
# the base material each strategy's worlds start from
STRATEGY_BASES = {
    "scenario": ("h5", "zarr"),
    "scenario_file": ("h5", "zarr"),
    "cli": ("h5", "zarr"),
    "manifest": ("h5", "zarr"),
    "epoch": ("h5", "zarr", "ddm"),
    "runfiles": ("h5", "zarr"),
    "epoch3d": ("h5_3d", "zarr_3d"),
    "bed": ("h5", "zarr", "bed"),
    "trajectory": ("traj", "h5"),
    "npz": ("h5", "zarr", "traj"),
    "zarr_codec": ("zarr", "h5", "zarr_3d", "h5_3d", "zarr_zstd"),
    "fsize": ("h5", "zarr", "traj", "h5_3d", "bed"),
}
# generated cases per strategy in the test run (tests/test_fuzz.py; the known cases come on top),
# and the proportions of tools/fuzz.py's --cases
BUDGET = {
    "scenario": 20,
    "scenario_file": 6,
    "cli": 20,
    "manifest": 20,
    "epoch": 12,
    "runfiles": 8,
    "epoch3d": 6,
    "bed": 3,
    "trajectory": 6,
    "npz": 5,
    "zarr_codec": 6,
    "fsize": 6,
}


def bases_for(names, heavy: bool = True) -> list[str]:
    """The base material the named strategies need (h5 and zarr always: the worker warms on
    them); with heavy, also what their heavy known cases start from."""
    out = ["h5", "zarr"]
    for n in names:
        out += [b for b in STRATEGY_BASES[n] if b not in out]
        if heavy:
            out += [c["base"] for c in KNOWN.get(n, []) if c.get("heavy") and c["base"] not in out]
    return out


def run_strategy(
    fuzzer: Fuzzer,
    name: str,
    n: int,
    seed: int | None = None,
    known: bool = True,
    strategies: dict | None = None,
    heavy: bool = True,
    end: bool = True,
) -> int:
    """Run the known cases of a strategy plus n generated ones; returns the number of cases run.
    heavy=False leaves out the known cases marked heavy (seconds to build their input);
    end=False keeps the worker for the next strategy (its exit is checked at the last one)."""
    from hypothesis import HealthCheck, Phase, example, given, settings
    from hypothesis import seed as hseed

    strategies = strategies or build_strategies()
    before = fuzzer.counts.get(name, 0)

    @settings(
        max_examples=max(n, 1),
        deadline=None,
        derandomize=seed is None,
        database=None,
        phases=[Phase.explicit, Phase.generate],
        suppress_health_check=list(HealthCheck),
        report_multiple_bugs=False,
    )
    @given(case=strategies[name])
    def body(case):
        fuzzer.run_case(case)

    if known:
        for ex in KNOWN.get(name, []):
            if heavy or not ex.get("heavy"):
                body = example(case=ex)(body)
    if seed is not None:
        body = hseed(seed)(body)
    if n > 0 or known:
        body()
    if end:
        fuzzer.end_worker()  # the next strategy gets a fresh worker
    return fuzzer.counts.get(name, 0) - before


def harness_is_test_code() -> None:
    """Keep this package's literals out of what hypothesis draws from. Hypothesis (6.131 on)
    draws some values from the constants of the 'local' modules loaded, but not from test code
    (a path with a tests/ part): the harness is test code that lives in tools/, and its own
    literals must not move the cases a seed gives (nor did they when it lived in tests/). No
    public switch exists: the modules are marked as already read, where hypothesis keeps that
    (called when the package is imported, before any case is drawn)."""
    try:
        from hypothesis.internal.conjecture import providers
    except ImportError:
        return
    seen = getattr(providers, "_seen_modules", None)
    if isinstance(seen, set):
        seen.update(
            id(m) for name, m in list(sys.modules.items()) if name == __package__ or name.startswith(__package__ + ".")
        )
