#!/usr/bin/env python
"""What a mesh wheel costs: the step time of paper2008-3d (its settled bed, the wheel
placed on it with no drop gap) with the built-in wheel and with the same wheel as a mesh
of about 20 000 triangles (tools/make_wheel_meshes.py), one thread. Each wheel first runs
``--settle`` steps (it lands and sinks in; its kernels compile on the first), then
``--steps`` timed steps. Prints JSON (seconds a step, and the mesh / built-in ratio).

    NUMBA_NUM_THREADS=1 python tools/mesh_wheel_cost.py [--settle 4000] [--steps 500]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

sys.path.insert(0, str(Path(__file__).resolve().parent))

from make_wheel_meshes import grousered_wheel  # noqa: E402

SEGMENTS, RINGS = 420, 8  # rim facets and end-face rings: ~20 000 triangles with the lugs


def step_time(overrides: list[str], settle: int, steps: int) -> dict:
    """Seconds a step of paper2008-3d with the overrides after ``settle`` steps."""
    from ooc_dem.app.bed import settled_bed
    from ooc_dem.app.run_setup import place_wheel
    from ooc_dem.engine.stepper import DomainStepper, Model
    from ooc_dem.model.scenario import load_scenario

    sc = load_scenario("paper2008-3d", ["wheel.drop_gap=0.0", "wheel.settle_time=0.005", *overrides])
    bed = settled_bed(sc)
    ws = place_wheel(sc, bed)
    st = DomainStepper(bed, Model.from_scenario(sc), ws)
    st.advance(0, settle)
    t0 = time.perf_counter()
    rec = st.advance(settle, steps)
    dt = time.perf_counter() - t0
    return {"s_per_step": dt / steps, "wheel_contacts_mean": float(rec[:, -1].mean())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--settle", type=int, default=4000, help="steps before timing (the wheel lands)")
    ap.add_argument("--steps", type=int, default=500, help="timed steps")
    a = ap.parse_args(argv)
    from ooc_dem.model.scenario import load_scenario

    w = load_scenario("paper2008-3d").wheel
    mesh = grousered_wheel(w.radius, w.width, w.n_lugs, w.lug_tip_radius, w.lug_thickness, SEGMENTS, RINGS)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "wheel.stl"
        mesh.export(path)
        builtin = step_time([], a.settle, a.steps)
        meshed = step_time([f"wheel.mesh={path}"], a.settle, a.steps)
    out = {
        "scenario": "paper2008-3d",
        "threads": int(os.environ["NUMBA_NUM_THREADS"]),
        "settle_steps": a.settle,
        "timed_steps": a.steps,
        "mesh_triangles": len(mesh.faces),
        "builtin": builtin,
        "mesh": meshed,
        "ratio": meshed["s_per_step"] / builtin["s_per_step"],
    }
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
