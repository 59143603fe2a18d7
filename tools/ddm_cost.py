#!/usr/bin/env python
"""Serial DDM against the monolithic step at one state, and what the difference is made
of. Prints JSON.

    python tools/ddm_cost.py RUN_DIR [--domains 6] [--block 1] [--steps 2000] [--threads 2] [--repeat 2]

RUN_DIR: a run's store (``ooc-dem run ... --out RUN_DIR``); its last committed epoch is
the state (e.g. paper2008 stopped mid-travel). Everything runs in this process after a
JIT warm-up, on ``--threads`` threads:

- ``mono_us`` / ``ddm_us``: microseconds a step of the monolithic engine and of serial
  DDM (D = ``--domains``, K = 1), the best of ``--repeat``, both from the same state;
  ``same_state``: their states after the steps are equal (positions and velocities);
- ``rows``: the DDM local sets (owned discs plus halo) per sub-domain, ``rows_per_disc``
  their sum over the discs;
- ``refresh_us``: the sweep's halo refresh and ownership (``live_kernels.refresh_own_pieces``);
- ``blocked_us``: {K: microseconds a step} of the sub-domains' local sets stepped K steps
  each in turn, nothing refreshed between them. Timing only (the halos go stale): what
  stepping a sub-domain several times while it is in cache gains a row, the premise of
  temporal blocking, against K = 1 (one thread: the loop a lane runs; null for a
  dimension whose kernels have no one-thread step, 3D today).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="a run's store (its last committed epoch is the state)")
    ap.add_argument("--domains", type=int, default=6)
    ap.add_argument("--block", type=int, default=1, help="serial DDM's K: steps a sub-domain takes per sweep")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--blocks", default="1,2,4,8", help="K values of blocked_us")
    a = ap.parse_args(argv)
    if a.domains < 2 or a.steps < 1 or a.threads < 1 or a.repeat < 1:
        print("ddm_cost: --domains must be >= 2, --steps, --threads and --repeat >= 1", file=sys.stderr)
        return 2
    if not (Path(a.run) / "scenario.toml").is_file():
        print(f"ddm_cost: {a.run} is not a run store (no scenario.toml)", file=sys.stderr)
        return 2
    try:
        blocks_k = sorted({int(k) for k in a.blocks.split(",")})
    except ValueError:
        blocks_k = []
    if a.block < 1:
        print(f"ddm_cost: --block {a.block}: K >= 1", file=sys.stderr)
        return 2
    if not blocks_k or min(blocks_k) < 1:
        print(f"ddm_cost: --blocks {a.blocks!r}: comma-separated K values >= 1", file=sys.stderr)
        return 2
    import numba

    numba.set_num_threads(a.threads)
    import numpy as np
    from numba import njit
    from ooc_dem.model.checkpoint import read_all_particles
    from ooc_dem.engine import live_kernels
    from ooc_dem.engine.monolithic import MonolithicEngine
    from ooc_dem.engine.stepper import Model
    from ooc_dem.engine.sweep import DdmEngine
    from ooc_dem.physics import kernels
    from ooc_dem.physics.history import ROLE_STABLE
    from ooc_dem.physics.layout import PLATE, PLATE_RECORD, WHEEL_RECORD, Plates
    from ooc_dem.model.scenario import load_scenario
    from ooc_dem.storage import open_store

    sc = load_scenario(str(Path(a.run) / "scenario.toml"))
    model = Model.from_scenario(sc)
    with open_store(a.run) as st:
        r = st.read_epoch(None)
        arrays, attrs = r.read_globals()
        discs = read_all_particles(r, sc.dim, model.hist_cap)
        step0 = int(attrs["step"])
        r.close()
    ws0 = np.asarray(arrays["wheel_state"], np.float64)
    warm = 50

    def fresh(mode):
        p = discs.take(np.arange(len(discs)))
        if mode == "mono":
            eng = MonolithicEngine(p, ws0.copy(), model)
        else:
            eng = DdmEngine.create(sc, model, p, ws0.copy(), domains=a.domains, block=a.block)
        eng.advance(step0, warm)
        return eng

    def state(eng):
        p = eng.particles()
        o = np.argsort(p.id)
        return p.pos[o], p.vel[o]

    out = {
        "run": a.run,
        "step": step0,
        "discs": len(discs),
        "domains": a.domains,
        "block": a.block,
        "threads": a.threads,
        "steps": a.steps,
    }
    ends = {}
    for mode in ("mono", "ddm"):
        best = float("inf")
        for _ in range(a.repeat):
            eng = fresh(mode)
            t = time.perf_counter()
            eng.advance(step0 + warm, a.steps)
            best = min(best, (time.perf_counter() - t) / a.steps * 1e6)
        out[f"{mode}_us"] = round(best, 1)
        ends[mode] = state(eng)
        if mode == "ddm":
            lv = eng._live
            out["rows"] = lv.resident()
            out["rows_per_disc"] = round(sum(lv.resident()) / len(discs), 4)
    out["ddm_over_mono"] = round(out["ddm_us"] / out["mono_us"], 3)
    out["same_state"] = bool(all(np.array_equal(x, y) for x, y in zip(ends["mono"], ends["ddm"])))

    # the refresh and the ownership of a sweep, alone
    p = lv.p

    @njit
    def refresh_loop(
        k,
        pieces,
        ids,
        owner_row,
        pos,
        vel,
        spin,
        hist_n,
        hist_id,
        hist_s,
        hist_m,
        x_built,
        ref,
        disp2,
        part,
        skin,
        bounds,
        owned,
        owned_before,
        role,
    ):
        c = 0
        for _ in range(k):
            c += live_kernels.refresh_own_pieces(
                pieces,
                ids,
                owner_row,
                pos,
                vel,
                spin,
                hist_n,
                hist_id,
                hist_s,
                hist_m,
                x_built,
                ref,
                disp2,
                False,
                part,
                skin,
                bounds,
                owned,
                owned_before,
                role,
            )[1]
        return c

    args = (
        lv._pieces,
        p.id,
        lv.owner_row,
        p.pos,
        p.vel,
        p.spin,
        p.hist_n,
        p.hist_id,
        p.hist_s,
        p.hist_m,
        lv.x_built,
        lv.ref,
        lv.disp2,
        lv._part,
        np.inf,
        lv.bounds,
        lv.owned,
        lv.owned_before,
        lv.role,
    )
    refresh_loop(1, *args)
    t = time.perf_counter()
    refresh_loop(a.steps, *args)
    out["refresh_us"] = round((time.perf_counter() - t) / a.steps * 1e6, 1)

    # the local sets stepped K steps each in turn (one thread's loop, as a lane runs them);
    # a dimension whose kernels have no one-thread step has no compiled sweeps to compare
    step_serial = getattr(kernels(sc.dim), "run_steps_serial", None)
    if step_serial is None:
        out["blocked_us"] = None
        print(json.dumps(out, indent=2))
        return 0

    @njit
    def blocks(nsteps, K, s0, doms, recs, stable, every, no_plates):
        s = 0
        while s < nsteps:
            for j in range(len(doms)):
                kp, d, pl, bd, forces, ws, err, flags, roles = doms[j]
                step_serial(
                    K,
                    s0 + s,
                    kp,
                    d,
                    pl,
                    bd,
                    forces,
                    ws,
                    no_plates,
                    err,
                    recs[j],
                    False,
                    False,
                    stable[: d.gid.shape[0]],
                    every,
                )
            s += K
        return s

    from numba.typed import List

    every = np.zeros((0, 2), np.int64)
    no_plates = Plates(np.empty(0, PLATE), np.empty(0, PLATE_RECORD))  # the sub-domains have no plates
    blocked = {}
    for K in blocks_k:
        n = max(K, (a.steps // 2 // K) * K)
        best = float("inf")
        for _ in range(a.repeat):
            lv = fresh("ddm")._live
            doms = lv._domain_list()
            stable = np.full(max(lv.resident()), ROLE_STABLE, np.int8)
            recs = List([np.zeros(n + K, WHEEL_RECORD) for _ in range(lv.D)])
            blocks(K, K, step0 + warm, doms, recs, stable, every, no_plates)
            t = time.perf_counter()
            blocks(n, K, step0 + warm + K, doms, recs, stable, every, no_plates)
            best = min(best, (time.perf_counter() - t) / n * 1e6)
        blocked[K] = round(best, 1)
    out["blocked_us"] = blocked
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
