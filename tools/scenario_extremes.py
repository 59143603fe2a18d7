#!/usr/bin/env python
"""Every numeric key of the built-in `quick` (2D) and `quick-3d` (3D) scenarios at extreme values,
through `ooc-dem check` and, when check accepts, a 3-step `ooc-dem run`.

    python tools/scenario_extremes.py [--scenarios quick,quick-3d] [--keys physics.dt,...]

The promise checked: `check` and `run` share one parameter validation, so a value `check`
accepts never crashes `run` -- each command ends with exit 0, or exit 2 and one line on stderr
(never a traceback, a signal, a timeout or a memory blow-up). Floats get 0, 5e-324, 1e-300,
1e-30, 1e30, 1e300 and 1.7e308; integers 0, 1, 2^31 and 2^62.

Both commands run in one long-lived worker (tools/fuzzlib's: captured stderr, a per-call
timeout, RLIMIT_AS of its warm size + 4 GiB and an RSS watch); a crash kills only the worker,
which is restarted. The worker settles beds for a few steps only (`--full-settle` settles them
as `run` does): a settle runs the step's kernels on the scenario's values, so what would crash
a run crashes there too, and a full settle of every changed bed would take minutes per case.
Beds go to a private cache (OOC_DEM_CACHE).

Prints one JSON object: counts, and every failure (scenario, key, value, command, exit, stderr).
Exit status 1 on any failure.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FLOATS = (0.0, 5e-324, 1e-300, 1e-30, 1e30, 1e300, 1.7e308)
INTS = (0, 1, 2**31, 2**62)
SCENARIOS = ("quick", "quick-3d")
RUN_ARGS = ("--no-progress", "--no-figures")
STEPS = 3
TIMEOUT = 20.0
RETRY_TIMEOUT = 120.0
MEM_BOUND = 4 << 30
SHORT_SETTLE_STEPS = 20


def _fuzzing():
    import fuzzlib  # beside this file (tools/ is the script's directory)

    return fuzzlib


def numeric_keys(sc) -> list[tuple[str, type]]:
    """(dotted key, int or float) of every numeric value of a scenario (booleans excluded)."""
    return [(k, type(v)) for k, v in _fuzzing().scenario_values(sc) if type(v) in (int, float)]


def cases(scenarios, only_keys=None) -> list[dict]:
    from ooc_dem.model.scenario import load_scenario

    got = []
    for name in scenarios:
        for key, typ in numeric_keys(load_scenario(name)):
            if only_keys and key not in only_keys:
                continue
            for v in FLOATS if typ is float else INTS:
                got.append({"scenario": name, "key": key, "value": repr(v)})
    return got


def verdict(res: dict) -> str | None:
    """None when the command kept the promise, else what went wrong."""
    rc = res.get("rc")
    if rc is None:
        return res.get("error") or "no result"
    err = res.get("stderr") or ""
    if "Traceback" in err:
        return f"traceback ({res.get('exc') or 'exit ' + str(rc)})"
    if rc == 0:
        return None
    # (the warnings `run` prints before it starts are not the refusal's)
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("ooc-dem: warning: ")]
    if rc == 2 and len(lines) == 1:
        return None
    return f"exit {rc} with {len(lines)} lines on stderr"


def survey(scenarios, only_keys=None, full_settle=False, steps=STEPS) -> dict:
    fz = _fuzzing()
    work = Path(tempfile.mkdtemp(prefix="ooc-dem-extremes-"))
    cache = work / "cache"
    env = {"OOC_DEM_CACHE": str(cache)}
    if not full_settle:
        env["OOC_DEM_EXTREMES_SHORT_SETTLE"] = "1"
    os.environ.update(env)
    # a run of each scenario on a bed of its own compiles the settle's and the run's kernels
    # (minutes for 3D) before the first case: else the first cases would time out on it
    run_args = (*RUN_ARGS, "--steps", str(steps))
    warm = [
        (["run", name, "--set", "soil.seed=1", *run_args, "--out", str(work / f"warm-{name}")], str(work))
        for name in scenarios
    ]
    # the worker is this script (--worker): fuzzlib's worker with the short settle patched in
    worker = fz.Worker(warmup=warm, mem_bound=MEM_BOUND, errlog=work / "worker.err", script=Path(__file__).resolve())
    todo = cases(scenarios, only_keys)
    counts = {
        "cases": len(todo),
        "check_refused": 0,
        "check_accepted": 0,
        "run_ok": 0,
        "run_refused": 0,
        "failures": 0,
        "worker_restarts": 0,
        "retried": 0,
    }
    failures, run_refusals = [], []
    t0 = time.monotonic()
    try:
        for i, case in enumerate(todo):
            item = f"{case['key']}={case['value']}"
            check = worker.call(["check", case["scenario"], "--set", item], work, timeout=TIMEOUT)
            bad = verdict(check)
            if bad:
                failures.append(
                    {
                        **case,
                        "command": "check",
                        "problem": bad,
                        "rc": check.get("rc"),
                        "stderr": (check.get("stderr") or "")[-3000:],
                    }
                )
                continue
            if check["rc"] != 0:
                counts["check_refused"] += 1
                continue
            counts["check_accepted"] += 1
            out = work / "out"
            shutil.rmtree(out, ignore_errors=True)
            run = worker.call(
                ["run", case["scenario"], "--set", item, *run_args, "--out", str(out)], work, timeout=TIMEOUT
            )
            if run.get("rc") is None:
                # killed (timeout, signal, memory): once more in a fresh worker, whose caches the
                # first try warmed, with more time -- a first compile of a kernel takes minutes
                counts["retried"] += 1
                shutil.rmtree(out, ignore_errors=True)
                run = worker.call(
                    ["run", case["scenario"], "--set", item, *run_args, "--out", str(out)], work, timeout=RETRY_TIMEOUT
                )
            shutil.rmtree(out, ignore_errors=True)
            bad = verdict(run)
            if bad:
                failures.append(
                    {
                        **case,
                        "command": "run",
                        "problem": bad,
                        "rc": run.get("rc"),
                        "elapsed": round(run.get("elapsed", 0), 1),
                        "stderr": (run.get("stderr") or "")[-3000:],
                    }
                )
            elif run["rc"] == 2:
                counts["run_refused"] += 1
                run_refusals.append({**case, "stderr": run["stderr"].strip()})
            else:
                counts["run_ok"] += 1
            print(
                f"[{i + 1}/{len(todo)}] {case['scenario']} {item}: {bad or ('refused' if run['rc'] else 'ok')}",
                file=sys.stderr,
                flush=True,
            )
    finally:
        worker.kill()
        worker.kill_cleanup()
        counts["worker_restarts"] = worker.restarts
        shutil.rmtree(work, ignore_errors=True)
    counts["failures"] = len(failures)
    counts["elapsed_s"] = round(time.monotonic() - t0, 1)
    return {"counts": counts, "failures": failures, "run_refusals": run_refusals}


def _short_settle(sc, p, progress=None):
    """A few steps of the settle's own kernels instead of a settle to rest."""
    from ooc_dem.engine.stepper import DomainStepper, Model

    stepper = DomainStepper(p, Model.from_scenario(sc).without_wheel())
    stepper.advance(0, SHORT_SETTLE_STEPS)
    return stepper.p, SHORT_SETTLE_STEPS


def _worker() -> int:
    sys.path.insert(0, str(ROOT))
    if os.environ.get("OOC_DEM_EXTREMES_SHORT_SETTLE"):
        import ooc_dem.app.bed

        ooc_dem.app.bed.settle = _short_settle
    from fuzzlib.worker import _worker_main

    return _worker_main()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", default=",".join(SCENARIOS))
    ap.add_argument("--keys", default="", help="comma-separated dotted keys (default: every numeric key)")
    ap.add_argument("--steps", type=int, default=STEPS, help="steps of each run (default %(default)s)")
    ap.add_argument("--full-settle", action="store_true", help="settle beds to rest as `run` does (slow)")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    keys = {k for k in args.keys.split(",") if k} or None
    result = survey(args.scenarios.split(","), keys, args.full_settle, args.steps)
    print(json.dumps(result, indent=2))
    return 1 if result["failures"] else 0


if __name__ == "__main__":
    if sys.argv[1:] == ["--worker"]:
        sys.exit(_worker())
    sys.exit(main())
