"""The pinned runs compiled for several x86-64 targets: do the bits depend on the instructions?

Runs pinned cases of tests/test_kernel_bits.py (by default quick: 2D, the wheel in the soil;
and quick-3d: Hertz spheres with rolling resistance and the wheel) once per numba target CPU
(``NUMBA_CPU_NAME``; ``host`` leaves it unset), each in a fresh interpreter with an empty
numba cache and an empty bed cache, so that the kernels are compiled for that target and the
bed is settled by them. Prints JSON: per target and case the state hash, whether it is the
pinned one, the wall time, and a digest of the compiled objects numba cached (different
digests show that the targets really compiled different code).

A target the host cannot execute (an instruction it lacks) fails with SIGILL: reported as
such, not as a difference. Run with the checkout on the path (``PYTHONPATH=.``).

    PYTHONPATH=. python tools/cpu_targets.py
    PYTHONPATH=. python tools/cpu_targets.py --target generic --target znver3 --case quick-3d
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from test_kernel_bits import CASES, _args  # noqa: E402  (the pinned cases, one definition)
from trace_bits import machine  # noqa: E402  (the facts a difference between machines may come from)

TARGETS = ["host", "generic", "haswell", "skylake-avx512", "znver3"]


def cached_objects_digest(cache: Path) -> tuple[str, int]:
    """A digest of numba's cached object files (``*.nbc``), in name order, and their count."""
    h = hashlib.sha256()
    files = sorted(cache.rglob("*.nbc"))
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16], len(files)


def run_case(case: str, target: str, work: Path) -> dict[str, object]:
    spec, _env, expected = CASES[case]
    env = dict(os.environ)
    env.pop("NUMBA_CPU_NAME", None)
    if target != "host":
        env["NUMBA_CPU_NAME"] = target
    cache = work / f"numba-{target}-{case}"
    env["NUMBA_CACHE_DIR"] = str(cache)
    env["OOC_DEM_CACHE"] = str(work / f"beds-{target}-{case}")
    out = work / f"run-{target}-{case}"
    args = [sys.executable, "-m", "ooc_dem.cli", "run", *map(str, _args(spec))]
    args += ["--out", str(out), "--no-progress", "--no-figures"]
    t0 = time.perf_counter()
    cp = subprocess.run(args, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    row: dict[str, object] = {"target": target, "case": case, "wall_s": round(wall, 1), "returncode": cp.returncode}
    if cp.returncode != 0:
        row["error"] = "SIGILL: the host cannot execute this target" if cp.returncode == -4 else cp.stderr[-400:]
        return row
    got = json.loads((out / "summary.json").read_text())["state_hash"]
    digest, count = cached_objects_digest(cache)
    row.update(state_hash=got, pinned=got == expected, compiled_objects=count, compiled_digest=digest)
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", action="append", help=f"numba target CPU (default: {' '.join(TARGETS)})")
    ap.add_argument("--case", action="append", help="a case of test_kernel_bits (default: quick-monolithic, quick-3d)")
    ap.add_argument("--keep", help="keep the runs and caches in this directory")
    a = ap.parse_args()
    targets = a.target or TARGETS
    cases = a.case or ["quick-monolithic", "quick-3d"]
    for c in cases:
        if c not in CASES:
            ap.error(f"unknown case {c!r}: one of {', '.join(CASES)}")
    with tempfile.TemporaryDirectory(prefix="cpu-targets-") as tmp:
        work = Path(a.keep) if a.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        rows = []
        for case in cases:
            for t in targets:
                rows.append(run_case(case, t, work))
                print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    per_case = {
        c: sorted({str(r.get("state_hash")) for r in rows if r["case"] == c and "state_hash" in r}) for c in cases
    }
    result = {
        "machine": machine(),
        "runs": rows,
        "one_hash_per_case": all(len(v) == 1 for v in per_case.values()),
        "all_pinned": all(r.get("pinned") is True for r in rows),
    }
    print(json.dumps(result, indent=1))
    return 0 if result["all_pinned"] else 1


if __name__ == "__main__":
    sys.exit(main())
