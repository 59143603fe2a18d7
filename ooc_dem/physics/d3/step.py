"""THE 3D per-domain step (numba): the spec-generic entry points ``run_steps`` and
``spatial_order`` for D = 3 (runs/spec-generic.md).

A step: ``forces.produce`` (one row per contact), ``forces.gather_integrate`` (each
sphere sums its rows in ascending partner-id order and is advanced), then a rebuild
of the half pair list when some sphere has moved half the skin. Error flags and
capacity growth as the 2D ``engine.stepper._run_steps``: it stops early with
err.pair_capacity = pairs needed (grow the list, call again with rebuild_now),
err.body_capacity (grow the wall rows, call again: that step is redone, nothing was
advanced) or err.hist_overflow (fatal). With the wheel (kp.wg.enabled) a step is the
2D one's: the wheel's controls and lug directions first, its rows made by ``produce``
(rim cylinder and lug plates spanning its width, ``forces.produce``), its reaction summed
in ascending sphere id after the gather (the 2D ``wheel_reaction``: x, y and the torque
about the axle; the lateral force goes to the axle), its record and its leapfrog in x and
y (``physics.integrate``, the same controller as in 2D).
"""
import numpy as np
from numba import njit

from .. import layout as L2
from ..forces import lug_directions, wheel_reaction
from ..integrate import apply_wheel_controls, record_and_integrate_wheel
from ..twins import step_twin
from .forces import N_CHUNKS, gather_integrate, load_history, produce, sync_history
from .layout import (
    ERR_BODY_CAPACITY,
    ERR_HIST_OVERFLOW,
    ERR_PAIR_CAPACITY,
)
from .neighbors import build_pairs, spatial_order  # noqa: F401  (spec entry point)


# nogil: an out-of-core sweep reads and writes slabs in other threads while this runs
@njit(cache=True, nogil=True)
def run_steps(nsteps, step0, kp, d, pl, bd, forces, ws, err, rec, rebuild_now, pairs_done=False,
              role=None, spans=None):
    """Advance spheres 0..len(d.r)-1 nsteps from global step step0.

    kp: layout.KernelParams, d: layout.Discs, pl: layout.Pairs, bd: layout.Bodies,
    forces: layout.Forces (length 0 when not kept), ws: WHEEL_STATE record (1,),
    err: ERRORS flags (int64 array), rec: WHEEL_RECORD rows, one per step (wheel runs),
    rebuild_now: build the pair list first; pairs_done: the call that stopped on
    err.body_capacity left the pair rows as they were (``produce`` makes no pair row when
    a wall buffer is full): they are kept, not reloaded, and the step is remade;
    role: serial-DDM roles of the spheres (forces.ROLE_*), as in 2D: None or empty (every
    sphere) reloads every row from the histories at the start and writes every history
    back at the end, so the spheres leave whole; non-empty keeps the rows of pairs of two
    ROLE_STABLE spheres and writes nothing back (the caller does, with sync_history and
    the roles). The pairs' springs live in the pair rows while the steps run.
    spans: the 2D signature's (m, 2) index ranges [first, end) of the spheres step s
    advances (an out-of-core slab's light cone); None, or steps past the m-th: all.
    Returns (steps done, rebuilds)."""
    n = d.r.shape[0]
    wg = kp.wg
    wc = kp.wc
    wheel = wg[0].enabled > 0.5
    nlugs = int(wg[0].nlugs)
    lugdir = np.empty(max(1, nlugs), L2.LUG_DIRECTION)   # set by lug_directions before use
    gy = kp.gravity[1]
    dt = kp.dt
    skin = kp.skin
    part = np.zeros(N_CHUNKS)
    every = np.zeros(0, np.int8)
    roles = every
    if role is not None:
        roles = role
    whole = roles.shape[0] == 0   # the spheres leave whole (no caller-side sync)
    if rebuild_now:
        npairs = build_pairs(d.pos, d.r, d.gid, n, skin, pl.half_off, pl.pair_b, pl.pair_a,
                             pl.inc_off, pl.inc_k, pl.ref)
        if npairs > pl.pair_b.shape[0]:
            err[ERR_PAIR_CAPACITY] = npairs
            return 0, 0
    if not pairs_done:
        load_history(n, d, pl, every if rebuild_now else roles)
    half2 = 0.25 * skin * skin
    rebuilds = 0
    for s in range(nsteps):
        t = (step0 + s) * dt
        if wheel:
            apply_wheel_controls(t, ws, wg, wc)
            lug_directions(ws[0].theta, nlugs, lugdir)
        first = 0
        end = n
        if spans is not None and s < spans.shape[0]:
            first = spans[s, 0]
            end = spans[s, 1]
        produce(first, end, d, pl, bd, kp.cp, kp.walls, wg, ws, lugdir, dt, err)
        if err[ERR_BODY_CAPACITY] != 0:
            # no pair row of this step was made (produce): the rows still hold the springs
            # of the last step, so the sync leaves the spheres whole; nothing was advanced
            if whole:
                sync_history(n, d, pl, err, every, 0)
            return s, rebuilds
        disp2 = gather_integrate(first, end, d, pl, bd, forces.force, forces.torque, kp.gravity, dt,
                                 part, err)
        if err[ERR_HIST_OVERFLOW] != 0:
            # fatal; step s is not done (its wheel is not advanced): as in 2D
            return s, rebuilds
        if wheel:
            wfx, wfy, wtq, cnt = wheel_reaction(d.gid, bd)
            record_and_integrate_wheel(rec, s, t, ws, wg, wc, wfx, wfy, wtq, cnt, gy, dt)
        if disp2 > half2:
            rebuilds += 1
            sync_history(n, d, pl, err, every, 0)
            npairs = build_pairs(d.pos, d.r, d.gid, n, skin, pl.half_off, pl.pair_b,
                                 pl.pair_a, pl.inc_off, pl.inc_k, pl.ref)
            if npairs > pl.pair_b.shape[0]:
                err[ERR_PAIR_CAPACITY] = npairs
                return s + 1, rebuilds
            load_history(n, d, pl, every)
    if whole:
        sync_history(n, d, pl, err, every, 0)
    return nsteps, rebuilds


# the same step on one thread (serial DDM runs its sub-domains side by side,
# engine.live._run_sweeps)
run_steps_serial = step_twin(run_steps)
