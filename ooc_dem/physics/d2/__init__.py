"""The 2D step kernels (discs in the x-y plane, spin about z): the per-dimension entry
points the engine calls (``physics.kernels(dim)``), ``run_steps`` (and its one-thread
twin ``run_steps_serial``, with ``sync_history_serial`` for serial DDM's compiled sweeps)
and ``spatial_order``.

A step (``run_steps``): wheel controls, ``forces.produce`` (one row per contact),
``forces.gather_integrate`` (each disc sums its rows in ascending partner-id order
and is advanced), the wheel's reaction summed in ascending disc id, the wheel's
leapfrog, and a rebuild of the half pair list when some disc has moved half the skin.
"""
import numpy as np
from numba import njit

from .. import layout as L
from ..forces import (N_CHUNKS, gather_integrate, load_history, lug_directions, produce,
                      sync_history, wheel_reaction)
from ..forces import sync_history_serial  # noqa: F401  (serial DDM's write-back, engine.live)
from ..integrate import apply_wheel_controls, record_and_integrate_wheel
from ..twins import step_twin
from ..layout import AX_Y, ERR_BODY_CAPACITY, ERR_HIST_OVERFLOW, ERR_PAIR_CAPACITY
from ..neighbors import build_pairs
from ..neighbors import spatial_order  # noqa: F401  (the entry point: spatial_order(pos, n, cell))

DIM = 2


# nogil: an out-of-core sweep reads and writes slabs in other threads while this runs
@njit(cache=True, nogil=True)
def run_steps(nsteps, step0, kp, d, pl, bd, forces, ws, err, rec, rebuild_now, pairs_done, role,
              spans):
    """Advance discs 0..len(d.gid)-1 (and the wheel when kp.wg.enabled) nsteps from global
    step step0.

    kp: layout.KernelParams (dt, gravity (2,), skin, records cp, walls, wg, wc); d:
    layout.Discs; pl: Pairs; bd: Bodies; forces: layout.Forces (length 0: not kept); ws:
    WHEEL_STATE record; rec: WHEEL_RECORD rows, one per step (wheel runs). Returns (steps
    done, rebuilds). Stops early with err[ERR_PAIR_CAPACITY] = pairs needed (grow the pair
    list, rebuild, continue), err[ERR_BODY_CAPACITY] (grow the body buffers, redo that step)
    or err[ERR_HIST_OVERFLOW] (fatal). pairs_done: the first step's pair rows were made by
    the call that stopped on ERR_BODY_CAPACITY (redo its body rows only). role: each
    disc's forces.ROLE_* bits in a serial-DDM sub-domain, which pair rows are reloaded
    (length 0: every row, and every disc's history written back at the end; else the
    caller writes back what it needs with sync_history). spans: (m, 2) index ranges
    [first, end): step s of this call advances only discs spans[s] (the shrinking light
    cone of an out-of-core slab, ``engine.sweep.cone_spans``); steps past the m-th, and
    every step when m = 0, advance all discs.

    A pair's contact history lives in its row of the pair list while the steps run
    (read and rewritten by ``produce``, no per-disc lookup); ``load_history`` fills the
    rows from the discs' histories at the start and after each rebuild, ``sync_history``
    writes them back before each rebuild and at the end."""
    n = d.gid.shape[0]
    dt = kp.dt
    skin = kp.skin
    cp = kp.cp
    walls = kp.walls
    wg = kp.wg
    wc = kp.wc
    gy = kp.gravity[AX_Y]
    wheel = wg[0].enabled > 0.5
    nlugs = int(wg[0].nlugs)
    lugdir = np.empty(max(1, nlugs), L.LUG_DIRECTION)   # set by lug_directions before use
    part = np.empty(N_CHUNKS)                            # scratch of gather_integrate
    if rebuild_now:
        npairs = build_pairs(d.pos, d.r, d.gid, n, skin, pl.half_off, pl.pair_b, pl.pair_a,
                             pl.inc_off, pl.inc_k, pl.ref)
        if npairs > pl.pair_b.shape[0]:
            err[ERR_PAIR_CAPACITY] = npairs
            return 0, 0
    every = role[:0]
    if not pairs_done:
        load_history(n, d, pl, every if rebuild_now else role)
    half2 = 0.25 * skin * skin
    rebuilds = 0
    wfxs = 0.0
    wfys = 0.0
    wtqs = 0.0
    for s in range(nsteps):
        t = (step0 + s) * dt
        if wheel:
            apply_wheel_controls(t, ws, wg, wc)
            lug_directions(ws[0].theta, nlugs, lugdir)
        first = 0
        end = n
        if s < spans.shape[0]:
            first = spans[s, 0]
            end = spans[s, 1]
        produce(first, end, d, pl, bd, cp, walls, wg, ws, lugdir, dt, err, pairs_done and s == 0)
        if err[ERR_BODY_CAPACITY] != 0:
            return s, rebuilds
        disp2 = gather_integrate(first, end, d, pl, bd, forces.force, forces.torque, kp.gravity,
                                 dt, part, err)
        if err[ERR_HIST_OVERFLOW] != 0:
            return s, rebuilds
        if wheel:
            wfxs, wfys, wtqs, cnt = wheel_reaction(d.gid, bd)
            record_and_integrate_wheel(rec, s, t, ws, wg, wc, wfxs, wfys, wtqs, cnt, gy, dt)
        if disp2 > half2:
            rebuilds += 1
            sync_history(n, d, pl, err, every, 0)
            npairs = build_pairs(d.pos, d.r, d.gid, n, skin, pl.half_off, pl.pair_b,
                                 pl.pair_a, pl.inc_off, pl.inc_k, pl.ref)
            if npairs > pl.pair_b.shape[0]:
                err[ERR_PAIR_CAPACITY] = npairs
                return s + 1, rebuilds
            load_history(n, d, pl, every)
    if role.shape[0] == 0:
        sync_history(n, d, pl, err, every, 0)
    return nsteps, rebuilds


# the same step on one thread (serial DDM runs its sub-domains side by side)
run_steps_serial = step_twin(run_steps)
