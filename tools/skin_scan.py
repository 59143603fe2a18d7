#!/usr/bin/env python
"""Which Verlet skin makes a run fastest: advance the same state with several skins and time it.

The pair list holds every pair within r_i + r_j + skin and is rebuilt when some particle has
moved half the skin, so the skin never changes a result, only the time: a smaller skin means
fewer candidate pairs to test each step and more rebuilds. This takes the last committed epoch
of a run's store (so the particles move as they do in that run: a wheel mid-travel, a bed
settling), advances it --steps steps monolithically once per skin and prints, per skin, the
time a step, the rebuilds, the candidate pairs a particle and the state's hash after the steps
(every skin must give the same: ``same_bits``). Skins are interleaved over --repeat rounds
(this machine's speed drifts); the best round of each is ``us_per_step``.

    python tools/skin_scan.py RUN --skins 0.0006,0.0002,0.0001,0.00005 --steps 20000

RUN: a store written by ``ooc-dem run`` (its own scenario.toml is used, with bed.skin set).
The whole state is held in memory: a tool for runs that fit in RAM.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def _model(run: Path, skin: float | None = None):
    """The run's own scenario (with bed.skin set unless skin is None), as the kernels' model."""
    from ooc_dem.engine.stepper import Model
    from ooc_dem.model.scenario import load_scenario

    overrides = [] if skin is None else [f"bed.skin={skin}"]
    return Model.from_scenario(load_scenario(str(run / "scenario.toml"), overrides))


def last_epoch(run: Path):
    """(particles, wheel state, step) of the run's last committed epoch, read once."""
    from ooc_dem.model.checkpoint import read_all_particles
    from ooc_dem.storage import open_store

    model = _model(run)  # its dimension and history capacity
    with open_store(run) as store:
        reader = store.read_epoch(None)
        try:
            arrays, attrs = reader.read_globals()
            particles = read_all_particles(reader, model.dim, model.hist_cap)
        finally:
            reader.close()
    return particles, np.asarray(arrays["wheel_state"], np.float64), int(attrs["step"])


def one(run: Path, epoch, skin: float, steps: int) -> dict:
    from ooc_dem.engine.monolithic import MonolithicEngine
    from ooc_dem.model.state import state_hash

    base, ws, step0 = epoch
    model = _model(run, skin)
    particles = base.take(np.arange(len(base)))  # a copy: the engine advances it in place
    engine = MonolithicEngine(particles, ws, model)
    warm = 10
    engine.advance(step0, warm)  # compiles (or loads) the kernels, builds the list
    builds0 = engine.stepper.rebuilds
    t0 = time.perf_counter()
    engine.advance(step0 + warm, steps)
    wall = time.perf_counter() - t0
    p = engine.particles()
    # the canonical state hash (as `ooc-dem checkpoint hash`): a history slot beyond a
    # particle's hist_n is no part of its state (a stale spring may stay there)
    return {
        "skin": skin,
        "us_per_step": round(wall / steps * 1e6, 1),
        "rebuilds": engine.stepper.rebuilds - builds0,
        "candidate_pairs_per_particle": round(engine.stepper.pairs / len(p), 3),
        "state_hash": state_hash(p, engine.wheel_state, step0 + warm + steps),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--skins", default="0.0006,0.0002,0.0001,0.00005")
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args(argv)
    try:
        skins = [float(x) for x in a.skins.split(",")]
    except ValueError:
        print(f"skin_scan: --skins {a.skins!r}: expected comma-separated lengths in m", file=sys.stderr)
        return 2
    if not skins or any(not (s > 0.0) for s in skins) or a.steps < 1 or a.repeat < 1:
        print("skin_scan: --skins must be positive lengths, --steps and --repeat at least 1", file=sys.stderr)
        return 2
    if not (a.run / "scenario.toml").is_file():
        print(f"skin_scan: {a.run}: not a run store (no scenario.toml)", file=sys.stderr)
        return 2
    from ooc_dem.storage import StoreError

    best: dict[float, dict] = {}
    times: dict[float, list] = {s: [] for s in skins}
    try:
        epoch = last_epoch(a.run)
        for _ in range(a.repeat):
            for s in skins:
                r = one(a.run, epoch, s, a.steps)
                times[s].append(r["us_per_step"])
                if s not in best or r["us_per_step"] < best[s]["us_per_step"]:
                    best[s] = r
    except (StoreError, ValueError, KeyError, OSError) as e:  # foreign or damaged store
        print(f"skin_scan: {a.run}: {' '.join(str(e).split())}", file=sys.stderr)
        return 2
    rows = [dict(best[s], us_per_step_rounds=times[s]) for s in skins]
    out = {
        "run": str(a.run),
        "steps": a.steps,
        "rows": rows,
        "same_bits": len({r["state_hash"] for r in rows}) == 1,
        "fastest_skin": min(rows, key=lambda r: r["us_per_step"])["skin"],
    }
    print(json.dumps(out, indent=1))
    return 0 if out["same_bits"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
