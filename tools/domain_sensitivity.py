#!/usr/bin/env python
"""Domain sensitivity of a tiled 3D wheel scenario: the bin's width and its length ahead of
the wheel, in a paired design.

Between two random beds the wheel's numbers differ far more than a domain change moves
them (the static sinkage of paper2008-3d ranges 9.5-17 mm over beds). So every
configuration of one seed is built from the same settled tile, and the wheel is put on the
same kind of tile seam: the soil under the wheel is the same and only the walls move.
Tiles are mirrored in z every other tile, so the seam at mid-width is of the base's kind
(an unmirrored tile on its left, a mirrored one on its right) when the number of tiles
across is 2 m with m odd (2, 6, 10, ...); the tiles along x are the base's from x = 0, so
more of them only moves the end wall away. The settled tile depends on ``soil.seed``:
several seeds give the spread of the paired differences (the measure of what a difference
means).

    python tools/domain_sensitivity.py --scenario paper2008-3d --seeds 2008,2009,2010 \\
        --across 2,6 --along 2,3 --set wheel.control=slip --set wheel.slip=0.3 ...

Each run is ``ooc-dem run SCENARIO --set ...`` in a subprocess (monolithic); its
``summary.json`` is kept in --out (a run already there is not redone). Prints one JSON
object per run, then the report: per quantity and configuration, the paired differences
from the base (the first --across and --along) and their mean and standard error.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
from pathlib import Path

QUANTITIES = {
    "net_traction": ("net_traction", "steady"),
    "gross_traction": ("gross_traction", "steady"),
    "net_traction_whole": ("net_traction", "whole_travel"),
    "sinkage": ("sinkage", "steady"),
    "static_sinkage": ("sinkage", "static"),
}


def seam_matches_base(across: int) -> bool:
    """True if the seam at mid-width is of the base's kind (2 m tiles across, m odd)."""
    return across % 2 == 0 and (across // 2) % 2 == 1


def configurations(across: list[int], along: list[int]) -> list[tuple[str, int, int]]:
    """(name, tiles across, tiles along): the base, then each other width at the base's
    length and each other length at the base's width."""
    a0, l0 = across[0], along[0]
    out = [("base", a0, l0)]
    out += [(f"across{a}", a, l0) for a in across[1:]]
    out += [(f"along{n}", a0, n) for n in along[1:]]
    return out


def run_settings(sc, settings: list[str], seed: int, n_across: int, n_along: int) -> list[str]:
    """The --set values of one run: the base scenario ``sc`` (with ``settings``) on a bin
    n_across x n_along of its tiles, seeded with ``seed``, monolithic, no snapshots."""
    from ooc_dem.model.scenario_check import tile_size

    tile_len, tile_wid = tile_size(sc)
    return [
        *settings,
        f"soil.seed={seed}",
        f"bed.tiles_across={n_across}",
        f"bin.width={n_across * tile_wid:.15g}",
        f"bin.length={n_along * tile_len:.15g}",
        f"soil.n={n_across * n_along * sc.bed.tile}",
        "output.snapshot_interval=0",
        "decomposition.domains=1",
    ]


def value(summary: dict, key: str, window: str) -> float | None:
    """summary[key][window]["value"] (window: whole_travel, steady or static), None if absent."""
    return summary.get(key, {}).get(window, {}).get("value")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="paper2008-3d")
    ap.add_argument("--seeds", default="2008,2009")
    ap.add_argument("--across", default="2,6", help="tiles across the width: the base first")
    ap.add_argument("--along", default="2,3", help="tiles along x: the base first")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a scenario value for every run (e.g. wheel.slip=0.3)",
    )
    ap.add_argument("--out", default="domain-sensitivity")
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args(argv)
    try:
        seeds = [int(s) for s in a.seeds.split(",")]
        across = [int(s) for s in a.across.split(",")]
        along = [int(s) for s in a.along.split(",")]
    except ValueError as e:
        print(f"domain_sensitivity: bad list: {e}", file=sys.stderr)
        return 2
    bad = [n for n in across if not seam_matches_base(n)]
    if bad or min(along) < 1:
        print(
            f"domain_sensitivity: tiles across must be 2 m with m odd (2, 6, 10, ...) so that the "
            f"wheel stands on the base's kind of seam; got {bad}"
            if bad
            else "domain_sensitivity: tiles along must be >= 1",
            file=sys.stderr,
        )
        return 2
    from ooc_dem.model.scenario_check import tile_size
    from ooc_dem.model.scenario import ScenarioError, load_scenario

    try:  # the settings checked here, once, rather than by every run
        sc = load_scenario(a.scenario, a.set)
    except (ScenarioError, OSError) as e:
        print(f"domain_sensitivity: {e}", file=sys.stderr)
        return 2
    if sc.dim != 3 or sc.bed.tile <= 0 or not sc.wheel.enabled:
        print("domain_sensitivity: needs a 3D wheel scenario with a tiled bed (bed.tile > 0)", file=sys.stderr)
        return 2
    tile_len, tile_wid = tile_size(sc)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "NUMBA_NUM_THREADS": str(a.threads)}
    runs: dict[str, dict] = {}
    for seed in seeds:
        for name, n_across, n_along in configurations(across, along):
            run = out / f"s{seed}-{name}"
            sets = run_settings(sc, a.set, seed, n_across, n_along)
            if not (run / "summary.json").is_file():
                cmd = [
                    sys.executable,
                    "-m",
                    "ooc_dem.cli",
                    "run",
                    a.scenario,
                    "--out",
                    str(run),
                    "--no-progress",
                    "--no-figures",
                ] + [x for kv in sets for x in ("--set", kv)]
                cp = subprocess.run(cmd, env=env, capture_output=True, text=True)
                if cp.returncode != 0:
                    print(f"domain_sensitivity: {run.name}: {cp.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
                    return 1
            s = json.loads((run / "summary.json").read_text())
            row = {
                "run": run.name,
                "seed": seed,
                "config": name,
                "tiles_across": n_across,
                "tiles_along": n_along,
                "width_m": n_across * tile_wid,
                "length_m": n_along * tile_len,
                "spheres": s["n_discs"],
                "wall_time_s": s["wall_time_s"],
                "state_hash": s["state_hash"],
            }
            row.update({q: value(s, *kw) for q, kw in QUANTITIES.items()})
            runs[run.name] = row
            print(json.dumps(row), flush=True)
    report = {"scenario": a.scenario, "settings": a.set, "seeds": seeds, "differences": {}}
    for name, _, _ in configurations(across, along)[1:]:
        per_q = {}
        for q in QUANTITIES:
            base = [runs[f"s{s}-base"][q] for s in seeds]
            diffs = [runs[f"s{s}-{name}"][q] - runs[f"s{s}-base"][q] for s in seeds]
            m = statistics.fmean(diffs)
            se = statistics.stdev(diffs) / math.sqrt(len(diffs)) if len(diffs) > 1 else None
            bm = statistics.fmean(base)
            per_q[q] = {
                "diffs": diffs,
                "mean": m,
                "se": se,
                "base_mean": bm,
                "mean_percent": 100.0 * m / bm if bm else None,
            }
        report["differences"][name] = per_q
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
