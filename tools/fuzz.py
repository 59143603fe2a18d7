#!/usr/bin/env python
"""Long fuzz run of the `ooc-dem` command line (the setting of tests/test_fuzz.py, longer).

    python tools/fuzz.py --cases 5000 [--seed S] [--strategies scenario,cli,manifest,...]
    python tools/fuzz.py --long --seed S          # the release campaign (>= 5000 cases, every class)

Runs the strategies of tools/fuzzlib (hostile scenario values, scenario files, CLI flags,
manifest edits, epoch edits, run-directory files, 3D stores, beds and the bed cache, trajectory
frames, initial.npz members, zarr codecs, file-size limits; plus every bug found by hand) in one long-lived
worker process and checks every case: exit 0, or exit 2 with exactly one line on stderr; nothing
outside the run directories created, changed or deleted; committed epochs untouched by a refused
command; no temporary left; peak RSS bounded (300 MB above the call's RSS for a refusal of a
hostile declared size); no timeout. --cases is split over the chosen strategies in the
proportions of the default test run. The same --seed, --cases and --strategies give the same
cases (hypothesis, no example database); without --seed the run is derandomized.

Prints one JSON object on stdout (progress goes to stderr): cases per strategy, elapsed time,
cases/s, the distinct failure classes (one reproducer each) and every failure (argv, edits, exit
code, stderr, the property that broke). Exit status 1 on any failure.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

# the harness itself (not only its worker) stays inside a memory bound: a harness bug must fail
# this run, never push the machine into its OOM killer
HARNESS_ADDRESS_SPACE = 8 << 30
LONG_CASES = 20000
LONG_TIMEOUT = 60.0


def main(argv=None) -> int:
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY or soft > HARNESS_ADDRESS_SPACE:
        resource.setrlimit(resource.RLIMIT_AS, (HARNESS_ADDRESS_SPACE, hard))
    import fuzzlib  # beside this file (tools/ is the script's directory), under the bound too

    weights = fuzzlib.BUDGET
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "--cases", type=int, default=None, help=f"generated cases in total (default 5000; --long: {LONG_CASES})"
    )
    p.add_argument(
        "--long",
        action="store_true",
        help=f"the release campaign: {LONG_CASES} cases over every strategy, {LONG_TIMEOUT:.0f} s a command",
    )
    p.add_argument(
        "--seed", type=int, default=None, help="hypothesis seed (default: derandomized, the same cases every run)"
    )
    p.add_argument(
        "--strategies",
        default=",".join(fuzzlib.STRATEGY_NAMES),
        help="comma-separated subset of: " + ", ".join(fuzzlib.STRATEGY_NAMES),
    )
    p.add_argument("--timeout", type=float, default=None, help=f"per command, s (default {fuzzlib.CASE_TIMEOUT:.0f})")
    p.add_argument(
        "--mem-bound-gib",
        type=float,
        default=fuzzlib.MEM_BOUND / fuzzlib.GiB,
        help="peak RSS above the worker's baseline, GiB",
    )
    p.add_argument("--no-known", action="store_true", help="skip the known-bug examples")
    p.add_argument("--workdir", help="keep case directories here (default: a temporary directory)")
    p.add_argument(
        "--keep-failed",
        type=int,
        default=0,
        metavar="K",
        help="keep the directories of the first K failing cases (with --workdir)",
    )
    p.add_argument("--quiet", action="store_true", help="no per-failure progress on stderr")
    a = p.parse_args(argv)
    names = [s.strip() for s in a.strategies.split(",") if s.strip()]
    bad = [s for s in names if s not in fuzzlib.STRATEGY_NAMES]
    if bad or not names:
        p.error(f"--strategies: unknown {bad}; choose from {', '.join(fuzzlib.STRATEGY_NAMES)}")
    if a.cases is None:
        a.cases = LONG_CASES if a.long else 5000
    if a.timeout is None:
        a.timeout = LONG_TIMEOUT if a.long else fuzzlib.CASE_TIMEOUT
    if a.cases < 0:
        p.error("--cases must be >= 0")
    total_w = sum(weights[s] for s in names)
    per = {s: int(round(a.cases * weights[s] / total_w)) for s in names}

    def log(msg):
        if not a.quiet:
            print(msg[:400], file=sys.stderr, flush=True)

    t0 = time.monotonic()
    fz = fuzzlib.Fuzzer(
        workdir=Path(a.workdir) if a.workdir else None,
        timeout=a.timeout,
        mem_bound=int(a.mem_bound_gib * fuzzlib.GiB),
        keep_failed=a.keep_failed,
        log=log,
        bases=fuzzlib.bases_for(names),
    )
    try:
        strategies = fuzzlib.build_strategies()
        for s in names:
            ts = time.monotonic()
            n = fuzzlib.run_strategy(fz, s, per[s], seed=a.seed, known=not a.no_known, strategies=strategies)
            print(f"fuzz: {s}: {n} cases in {time.monotonic() - ts:.1f} s", file=sys.stderr, flush=True)
        summary = fz.summary()
    finally:
        fz.close()
    summary.update(
        {
            "seed": a.seed,
            "long": a.long,
            "strategies": names,
            "command": "python tools/fuzz.py " + " ".join(sys.argv[1:] if argv is None else argv),
            "requested_cases": a.cases,
            "generated_per_strategy": per,
            "timeout_s": a.timeout,
            "wall_s": round(time.monotonic() - t0, 1),
            "all_failures": [
                {
                    k: (f[k][-1500:] if k == "stderr" else fuzzlib.short(f[k]))
                    for k in (
                        "class",
                        "strategy",
                        "base",
                        "edits",
                        "argv",
                        "property",
                        "detail",
                        "preceded_by",
                        "exit_code",
                        "stderr",
                        "kept_dir",
                    )
                    if f.get(k) is not None
                }
                for f in fz.failures
            ],
        }
    )
    summary["ok"] = not fz.failures
    print(json.dumps(summary, indent=2, ensure_ascii=False))
    return 0 if summary["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
