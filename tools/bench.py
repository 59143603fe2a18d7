#!/usr/bin/env python
"""Throughput benchmark: settled bare beds of given sizes, a fixed number of steps.

Each size runs in a fresh subprocess (so its peak RSS is its own) after a JIT
warm-up. Prints one JSON object per size and a final JSON list. ``--family bed``
(default) runs the 2D beds ``bed-N`` (discs), ``--family bed3d`` the 3D beds
``bed3d-N`` (spheres); ``--set`` overrides scenario values of every size.

    python tools/bench.py                       # 7k, 100k, 1M discs, 200 steps each
    python tools/bench.py --sizes 7000,100000 --steps 500 --threads 2
    python tools/bench.py --family bed3d --sizes 20000 --steps 200
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time


FAMILIES = ("bed", "bed3d")


def one(n: int, steps: int, threads: int, warmup: int, family: str = "bed", overrides: list[str] | None = None) -> dict:
    """One measurement on the settled bed of ``{family}-{n}`` (in this process)."""
    import numba

    numba.set_num_threads(threads)
    import numpy as np
    from ooc_dem.app.bed import settled_bed
    from ooc_dem.engine.memlimit import own_peak_rss_bytes
    from ooc_dem.engine.stepper import DomainStepper, Model
    from ooc_dem.model.scenario import load_scenario

    t0 = time.time()
    sc = load_scenario(f"{family}-{n}", overrides)
    bed = settled_bed(sc)
    t_bed = time.time() - t0
    rss_bed = own_peak_rss_bytes()
    st = DomainStepper(bed, Model.from_scenario(sc))
    del bed
    # warm-up: JIT (cached), first neighbour build, and the tiled bed's seams
    # relaxing (tiles lose their side walls) before the timed steps
    st.advance(0, warmup)
    t = time.perf_counter()
    st.advance(warmup, steps)
    el = time.perf_counter() - t
    peak = own_peak_rss_bytes()
    contacts = float(np.mean(st.p.hist_n))
    extra = {}
    if hasattr(st, "nbytes"):  # the stepper's own arrays besides the discs, and its pair list
        extra = {
            "stepper_bytes_per_disc": round(st.nbytes() / n, 1),
            "candidate_pairs_per_disc": round(st.pairs / n, 3),
        }
    return {
        "n": n,
        "family": family,
        "dim": sc.dim,
        "steps": steps,
        "threads": threads,
        "warmup_steps": warmup,
        "seconds": round(el, 4),
        "particle_steps_per_s": n * steps / el,
        "contacts_per_disc": round(contacts, 3),
        "neighbour_rebuilds": st.rebuilds,
        "peak_rss_bytes": peak,
        "peak_rss_bytes_per_disc": round(peak / n, 1),
        "bed_setup_s": round(t_bed, 2),
        "rss_after_bed_bytes": rss_bed,
        **extra,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="7000,100000,1000000")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--warmup", type=int, default=300)
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument(
        "--family", default="bed", choices=FAMILIES, help="bed: 2D bed-N (discs); bed3d: 3D bed3d-N (spheres)"
    )
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="scenario override (every size)")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(a.one, a.steps, a.threads, a.warmup, a.family, a.set)))
        return
    results = []
    for n in [int(float(s)) for s in a.sizes.split(",")]:
        out = subprocess.run(
            [
                sys.executable,
                __file__,
                "--one",
                str(n),
                "--steps",
                str(a.steps),
                "--threads",
                str(a.threads),
                "--warmup",
                str(a.warmup),
                "--family",
                a.family,
            ]
            + [f"--set={o}" for o in a.set],
            capture_output=True,
            text=True,
        )
        if out.returncode != 0:
            print(out.stderr, file=sys.stderr)
            sys.exit(out.returncode)
        res = json.loads(out.stdout.strip().splitlines()[-1])
        print(json.dumps(res), file=sys.stderr)
        results.append(res)
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
