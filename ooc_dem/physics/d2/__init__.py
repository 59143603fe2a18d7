"""The 2D step kernels (discs in the x-y plane, spin about z): the per-dimension entry
points the engine calls (``physics.kernels(dim)``), ``run_steps`` and ``spatial_order``.

A step (``run_steps``): wheel controls, ``forces.produce`` (one row per contact),
``forces.gather_integrate`` (each disc sums its rows in ascending partner-id order
and is advanced), the wheel's reaction summed in ascending disc id, the wheel's
leapfrog, and a rebuild of the half pair list when some disc has moved half the skin.
"""
import numpy as np
from numba import njit

from .. import layout as L
from ..forces import N_CHUNKS, gather_integrate, lug_directions, produce, wheel_reaction
from ..integrate import apply_wheel_controls, drawbar_force, integrate_wheel
from ..layout import AX_Y, ERR_BODY_CAPACITY, ERR_HIST_OVERFLOW, ERR_PAIR_CAPACITY
from ..neighbors import build_pairs
from ..neighbors import spatial_order  # noqa: F401  (the entry point: spatial_order(pos, n, cell))

DIM = 2


@njit(cache=True)
def run_steps(nsteps, step0, kp, d, pl, bd, forces, ws, err, rec, rebuild_now):
    """Advance discs 0..len(d.gid)-1 (and the wheel when kp.wg.enabled) nsteps from global
    step step0.

    kp: layout.KernelParams (dt, gravity (2,), skin, records cp, walls, wg, wc); d:
    layout.Discs; pl: Pairs; bd: Bodies; forces: layout.Forces (length 0: not kept); ws:
    WHEEL_STATE record; rec: WHEEL_RECORD rows, one per step (wheel runs). Returns (steps
    done, rebuilds). Stops early with err[ERR_PAIR_CAPACITY] = pairs needed (grow the pair
    list, rebuild, continue), err[ERR_BODY_CAPACITY] (grow the body buffers, redo that step)
    or err[ERR_HIST_OVERFLOW] (fatal)."""
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
    lugdir = np.zeros(max(1, nlugs), L.LUG_DIRECTION)
    part = np.zeros(N_CHUNKS)
    if rebuild_now:
        npairs = build_pairs(d.pos, d.r, d.gid, n, skin, pl.half_off, pl.pair_b, pl.pair_a,
                             pl.inc_off, pl.inc_k, pl.ref)
        if npairs > pl.pair_b.shape[0]:
            err[ERR_PAIR_CAPACITY] = npairs
            return 0, 0
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
        produce(n, d, pl, bd, cp, walls, wg, ws, lugdir, dt, err)
        if err[ERR_BODY_CAPACITY] != 0:
            return s, rebuilds
        disp2 = gather_integrate(n, d, pl, bd, forces.force, forces.torque, kp.gravity, dt, part,
                                 err)
        if err[ERR_HIST_OVERFLOW] != 0:
            return s, rebuilds
        if wheel:
            wfxs, wfys, wtqs, cnt = wheel_reaction(d.gid, bd)
            w0 = ws[0]
            r0 = rec[s]
            r0.t = t
            r0.x = w0.x
            r0.y = w0.y
            r0.vx = w0.vx
            r0.vy = w0.vy
            r0.wz = w0.wz
            r0.theta = w0.theta
            r0.fx = wfxs
            r0.fy = wfys
            r0.torque = wtqs
            r0.drawbar = drawbar_force(t, wc)
            r0.contacts = cnt
            integrate_wheel(t, ws, wg, wc, wfxs, wfys, gy, dt)
        if disp2 > half2:
            rebuilds += 1
            npairs = build_pairs(d.pos, d.r, d.gid, n, skin, pl.half_off, pl.pair_b,
                                 pl.pair_a, pl.inc_off, pl.inc_k, pl.ref)
            if npairs > pl.pair_b.shape[0]:
                err[ERR_PAIR_CAPACITY] = npairs
                return s + 1, rebuilds
    return nsteps, rebuilds
