#!/usr/bin/env python
"""Peak RSS of monolithic and out-of-core runs against N (bare beds), with fitted slopes.

Each (mode, N) runs in a fresh subprocess (ooc_dem.app.profiling) after JIT warm-up;
the peak is measured from just before the scenario is set up (so the bed and
store setup count), above the post-warm-up baseline. The slope of peak-above-
baseline against N (least squares) is the memory cost per disc of each mode.

    python tools/memsweep.py --sizes 1e4,1e5,1e6,4e6 --domains 32 --steps 20 --out memsweep
    python tools/memsweep.py --sizes 1e5,4e5,2e6 --slab-discs 12500 --out memsweep-slab   # fixed slab
    python tools/memsweep.py --family bed3d --sizes 1e4,1e5,1e6,4e6 --out memsweep3d   # spheres
    python tools/memsweep.py --sizes 1e5,1e6,1e7,5e7 --slab-discs 500000 --monolithic-max 1e7   # past RAM
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ooc_dem.app.profiling import run_child  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1e4,1e5,1e6,4e6")
    ap.add_argument("--domains", type=int, default=32)
    ap.add_argument(
        "--slab-discs", type=int, help="fixed slab size instead of a fixed D: out-of-core D = ceil(N / this)"
    )
    ap.add_argument("--block", type=int, help="K for out-of-core (default: chosen from the geometry)")
    ap.add_argument("--backend", default="hdf5", choices=["hdf5", "zarr"])
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--modes", default="monolithic,ooc")
    ap.add_argument(
        "--monolithic-max",
        type=float,
        help="run monolithic only up to this N (beyond it the whole bed would not fit "
        "in this machine's RAM; out-of-core goes on)",
    )
    ap.add_argument("--out", default="memsweep")
    ap.add_argument(
        "--family", default="bed", choices=["bed", "bed3d"], help="bed-N (2D discs) or bed3d-N (3D spheres)"
    )
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    sizes = [int(float(s)) for s in a.sizes.split(",")]
    modes = a.modes.split(",")
    runs = []
    for n in sizes:
        for m in modes:
            if m == "monolithic" and a.monolithic_max is not None and n > a.monolithic_max:
                continue
            r = run_child(
                f"{a.family}-{n}",
                m,
                overrides=["decomposition.policy=equal"],
                backend=a.backend,
                domains=(-(-n // a.slab_discs) if a.slab_discs else a.domains) if m != "monolithic" else None,
                block=a.block if m != "monolithic" else None,
                steps=a.steps,
                work=out / "work",
            )
            r.pop("rss_series", None)
            runs.append(r)
            print(
                json.dumps(
                    {
                        k: r[k]
                        for k in (
                            "mode",
                            "n_discs",
                            "peak_rss_bytes",
                            "peak_above_baseline_bytes",
                            "resident_discs_max",
                            "particle_steps_per_s",
                            "block",
                        )
                    }
                ),
                file=sys.stderr,
                flush=True,
            )
    fits = {}
    for m in modes:
        rs = [r for r in runs if r["mode"] == m]
        if len(rs) >= 2:
            n = np.array([r["n_discs"] for r in rs], float)
            y = np.array([r["peak_above_baseline_bytes"] for r in rs], float)
            slope, icpt = np.polyfit(n, y, 1)
            fits[m] = {"bytes_per_disc": float(slope), "intercept_bytes": float(icpt)}
    if "monolithic" in fits and "ooc" in fits:
        fits["ooc_over_monolithic_slope"] = fits["ooc"]["bytes_per_disc"] / fits["monolithic"]["bytes_per_disc"]
    doc = {
        "domains": a.domains,
        "slab_discs": a.slab_discs,
        "backend": a.backend,
        "steps": a.steps,
        "monolithic_max": a.monolithic_max,
        "runs": runs,
        "fits": fits,
    }
    (out / "memsweep.json").write_text(json.dumps(doc, indent=2))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    what = "spheres" if a.family == "bed3d" else "discs"
    for m in modes:
        rs = [r for r in runs if r["mode"] == m]
        n = [r["n_discs"] for r in rs]
        ax.plot(
            n,
            [r["peak_above_baseline_bytes"] / 2**20 for r in rs],
            "o-",
            label=f"{m}: {fits.get(m, {}).get('bytes_per_disc', float('nan')):.0f} B/{what[:-1]}",
        )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(f"{what} N")
    ax.set_ylabel("peak RSS above baseline [MiB]")
    ax.set_title(
        f"peak memory against N (out-of-core: "
        f"{f'slabs of {a.slab_discs} {what}' if a.slab_discs else f'D = {a.domains}'})"
    )
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "memsweep.png", dpi=110)
    print(json.dumps({"fits": fits, "json": str(out / "memsweep.json"), "png": str(out / "memsweep.png")}, indent=2))


if __name__ == "__main__":
    main()
