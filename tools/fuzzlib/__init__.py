"""Fuzz harness for the `ooc-dem` command line (shared by tests/test_fuzz.py and tools/fuzz.py).

Every generated *case* is a JSON-able dict: the strategy that made it, the base store it starts
from (``h5``: a finished monolithic HDF5 run, ``zarr``: a finished out-of-core zarr run with 3
sub-domains; ``h5_3d``/``zarr_3d``: the same of quick-3d; ``traj``: an HDF5 run with trajectory
frames; ``zarr_zstd``: compressed zarr arrays; ``ddm``: serial DDM; see BASE_RUNS), the material
it ``needs`` (``bed``: a prepared bed in w/out/bed; ``cache``: a bed cache in w/cache, given to
the command as OOC_DEM_CACHE), a list of *edits* applied to a fresh copy of the world before the
command, the ``argv`` given to ``ooc_dem.cli.main`` (or ``@api WHAT RUN``: the Python API), an
optional ``fsize`` (RLIMIT_FSIZE of the command) or ``fresh`` (a fresh interpreter instead of the
worker: what is printed at interpreter exit counts) and a few *expectations*. ``Fuzzer.run_case`` builds the
world, runs the command in a long-lived worker process and checks, for every case:

* exit code 0 (any output), or exit code 2 with exactly one non-empty line on stderr; never a
  traceback, another exit code, a crash or a timeout (reading /dev/zero forever is a bug);
* the worker's peak RSS during the case stays below a bound above its baseline (the worker also
  runs under RLIMIT_AS = its warm size + the bound, so a huge allocation is a MemoryError, i.e. a
  traceback, instead of swapping the machine);
* nothing outside the run directories (``w/run``, ``w/run2``, ``w/out``, ``w/runs``) is created, changed or
  deleted (snapshot of the whole case root: type, size, mtime, mode, sha256, link target);
* read-only commands (`checkpoint list|verify|inspect|hash|export`, `compare`, `check`) leave the
  stores byte-identical (`report` may add ``figures/``); a command that exits 2 leaves the
  committed files (MANIFEST.json and the files it names) byte-identical;
* a write command (`resume`, `checkpoint prune`, `run --out run`) that exits 0 and changed the
  manifest leaves a store that `checkpoint verify` accepts;
* the worker exits cleanly after each strategy: an abort at interpreter exit ("free(): invalid
  pointer") means some case damaged the heap (an out-of-bounds write in a kernel); the case is
  found by bisection in fresh workers and reported as ``heap_damage``;
* no temporary (``*.tmp*``) is left anywhere in the world by a command that ended (exit 0 or 2);
* under a file-size limit, exit 0 never leaves a file of exactly the limit (an output cut short);
* a refusal of a hostile declared size (trajectory rows, npz members, inflated zarr chunks,
  ``hist_cap``) peaks below SIZE_BOUND above the RSS at its call, and is never only the failure
  of an allocation sized by that number ("out of memory");
* per-case expectations, e.g. ``verify`` of an epoch whose bytes were flipped without fixing the
  checksum must not exit 0, and ``export --out`` over MANIFEST.json / an epoch file / a device
  must be refused (exit 2).

World of a case (cwd of the command is ``R/w``)::

    R/                      case root (everything below is snapshotted except w/run, w/run2,
                            w/out, w/runs)
      dev/zero -> /dev/zero (so that "../../dev/zero" from the store stays inside R)
      w/
        run/                the store under test (copy of a base run: MANIFEST.json, epochs/,
                            summary.json, series.csv, initial.npz, scenario.toml)
        run2/               an untouched copy of the other base run (for `compare`; only made when
                            the case names it)
        out/                empty directory for --out files
        runs/               (not made) where `run` without --out writes runs/<scenario name>
        victim/             a.txt, sub/b.txt
        victim_file
        victim_epochs/      copy of run/epochs, made by the "epochs/ is a symlink to it" edit
        link_victim -> victim, link_file -> victim_file, link_zero -> /dev/zero,
        dev_null -> /dev/null, dev_full -> /dev/full, scenario.toml (a valid tiny scenario)

Scenario cases use `ooc-dem check SCENARIO ...`; while the parser has no `check` command they
run as `ooc-dem profile SCENARIO --set ... --modes monolithic --out victim`, which loads and
validates the scenario the same way and then refuses the non-empty --out (counted in the
summary's ``commands_missing``).

All hostile paths resolve inside R (never more than two ".." above the store, absolute paths
only into R, devices only through symlinks), so a buggy delete or write can only hit R.

The parts: ``common`` (constants, shared helpers), ``worker`` (the worker process) and ``handle``
(its parent side), ``world`` (base material, worlds, snapshots), ``edits`` and ``file_edits`` (what
a case does to its world), ``values`` and ``pools`` (what the strategies draw from, a case's
expectations), ``strategies`` (hypothesis), ``known`` (the bugs found by hand), ``fuzzer`` (run and
check one case), ``runner`` (a strategy's run). tools/ is not part of the wheel: tools/fuzz.py
imports this package from beside it, the tests through pyproject's pytest ``pythonpath``.
"""

from __future__ import annotations

from .common import CASE_TIMEOUT, MEM_BOUND, SIZE_BOUND, GiB
from .fuzzer import Fuzzer, failure_class, short
from .handle import Worker, WorkerDied, child_env
from .known import KNOWN
from .runner import BUDGET, STRATEGY_BASES, STRATEGY_NAMES, bases_for, harness_is_test_code, run_strategy
from .strategies import build_strategies
from .values import scenario_keys, scenario_values

__all__ = [
    "BUDGET",
    "CASE_TIMEOUT",
    "KNOWN",
    "MEM_BOUND",
    "SIZE_BOUND",
    "STRATEGY_BASES",
    "STRATEGY_NAMES",
    "Fuzzer",
    "GiB",
    "Worker",
    "WorkerDied",
    "bases_for",
    "build_strategies",
    "child_env",
    "failure_class",
    "run_strategy",
    "scenario_keys",
    "scenario_values",
    "short",
]

harness_is_test_code()
