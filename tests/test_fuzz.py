"""Fuzz suite: hostile scenario values, scenario files, CLI flags, manifest edits, epoch edits,
run-directory files, 3D stores, beds and the bed cache, trajectory frames, initial.npz members,
zarr codecs and file-size limits, every case checked for: exit 0, or exit 2 with exactly one
line on stderr (no traceback, no other exit code, no signal, no timeout); nothing outside the run
directories created, changed or deleted; committed epochs untouched by a refused command; no
temporary left; peak memory bounded (300 MB for a refusal of a hostile declared size). The
harness is tools/fuzzlib (shared with `python tools/fuzz.py --cases 5000 --seed S`).

The cases run in one long-lived worker process (``ooc_dem.cli.main`` called in-process). This is
the CI slice: every strategy, a few dozen generated cases each plus every bug found by hand
(hypothesis @example), about a minute in all; the campaigns are tools/fuzz.py's.
"""

import time

import fuzzlib
import pytest
from fuzzlib import BUDGET

pytestmark = pytest.mark.slow

TIMEOUT = 10.0  # s per command in the default run (tools/fuzz.py: 20 s)


@pytest.fixture(scope="module")
def fuzzer(tmp_path_factory):
    fz = fuzzlib.Fuzzer(
        bases_dir=tmp_path_factory.mktemp("fuzz-bases"),
        timeout=TIMEOUT,
        bisect_budget_s=30,
        bases=fuzzlib.bases_for(fuzzlib.STRATEGY_NAMES, heavy=False),
    )
    yield fz
    fz.close()


@pytest.fixture(scope="module")
def strategies():
    return fuzzlib.build_strategies()


def _report(fails) -> str:
    classes = {}
    for f in fails:
        classes.setdefault(f["class"], []).append(f)
    out = [f"{len(fails)} failing case(s), {len(classes)} distinct class(es):"]
    for k, fs in sorted(classes.items()):
        f = fs[0]
        out.append(
            f"- [{len(fs)}x] {k}\n    argv: {fuzzlib.short(f['argv'])}\n    base: {f['base']}"
            f"  edits: {str(fuzzlib.short(f['edits']))[:400]}\n    {f['detail']}"
            f"\n    stderr: {(f['stderr'] or '').strip()[-400:]}"
            + (
                f"\n    (crash after, in the same worker: {fuzzlib.short(f['preceded_by'])})"
                if f.get("preceded_by")
                else ""
            )
        )
    return "\n".join(out)


@pytest.mark.parametrize("name", fuzzlib.STRATEGY_NAMES)
def test_fuzz(name, fuzzer, strategies, capsys):
    t0 = time.monotonic()
    before = len(fuzzer.failures)
    # one worker for the whole slice (a restart costs its warm-up); its exit status, i.e. heap
    # damage by any case, is checked by test_fuzz_total
    n = fuzzlib.run_strategy(fuzzer, name, BUDGET[name], strategies=strategies, heavy=False, end=False)
    dt = time.monotonic() - t0
    fails = fuzzer.failures[before:]
    with capsys.disabled():
        print(
            f"\nfuzz {name}: {n} cases ({len(fuzzlib.KNOWN[name])} known) in {dt:.1f} s "
            f"({n / dt:.1f} cases/s), {len(fails)} failing"
            + (f"; commands missing: {fuzzer.missing}" if fuzzer.missing else "")
        )
    assert n >= BUDGET[name], f"only {n} cases ran for {name} (budget {BUDGET[name]})"
    assert not fails, _report(fails)


def test_fuzz_total(fuzzer, capsys):
    """The default setting covers every strategy and does not silently shrink; the worker that
    ran the slice exits cleanly (no case damaged its heap)."""
    assert set(BUDGET) == set(fuzzlib.STRATEGY_NAMES)
    assert sum(BUDGET.values()) >= 100
    before = len(fuzzer.failures)
    fuzzer.end_worker()
    assert not fuzzer.failures[before:], _report(fuzzer.failures[before:])
    if set(fuzzer.counts) >= set(fuzzlib.STRATEGY_NAMES):  # all strategies ran in this session
        with capsys.disabled():
            s = fuzzer.summary()
            print(
                f"\nfuzz total: {s['cases']} cases in {s['elapsed_s']} s ({s['cases_per_s']} cases/s), "
                f"{s['failures']} failing, worker restarts {s['worker_restarts']}, "
                f"max peak RSS {s['max_peak_rss_mb']} MB; slowest: {'; '.join(s['slowest_cases'][:5])}"
            )
        assert fuzzer.n >= 300  # with the known cases
