"""THE per-domain step, shared by every execution mode.

``DomainStepper`` holds one set of discs (the whole bin in monolithic mode; a
sub-domain plus its halo in DDM and out-of-core) and advances all of them K
steps in place. Monolithic, DDM and out-of-core only differ in which discs they
hand it and where the results go, so they cannot drift apart.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numba import njit

from ..physics.contact import N_FIELDS, KN, KS, ZN, ZT, MU, MUR, ZR
from ..physics.forces import (ERR_HIST_OVERFLOW, ERR_NBR_OVERFLOW, WG_CAP, WG_ENABLED,
                              WG_LUG_IN, WG_LUG_OUT, WG_MASS, WG_NLUGS, WG_R, WG_SIZE,
                              WS_THETA, WS_VX, WS_VY, WS_WZ, WS_X, WS_Y, compute_forces,
                              lug_directions, make_scratch, wheel_reaction)
from ..physics.integrate import (N_CHUNKS, WC_DRAWBAR, WC_OMEGA, WC_RAMP, WC_SETTLE, WC_SIZE, WC_SLIP,
                                 WC_SLIPMODE, apply_wheel_controls, drawbar_force,
                                 integrate_discs, integrate_wheel)
from ..physics.neighbors import build_neighbors, spatial_order
from ..state import Particles

NBR_CAP = 24
SERIAL_BELOW = 3000  # discs; below this a domain runs on one thread

# per-step wheel record columns
REC_COLUMNS = ("t", "x", "y", "vx", "vy", "wz", "theta", "fx", "fy", "torque", "drawbar", "contacts")
REC_T, REC_X, REC_Y, REC_VX, REC_VY, REC_WZ, REC_THETA, REC_FX, REC_FY, REC_TQ, REC_DB, REC_NC = range(12)
N_REC = len(REC_COLUMNS)


class EngineError(RuntimeError):
    """A run cannot continue (capacity overflow, unstable state)."""


@dataclass
class Model:
    """Everything the kernels need from a scenario, as flat arrays."""
    dt: float
    gx: float
    gy: float
    skin: float
    cp: np.ndarray        # contact parameters [type_a, type_b, field]; types: soil 0, wall 1, wheel 2
    walls: np.ndarray     # [length, left, right, bottom]
    wg: np.ndarray        # wheel geometry
    wc: np.ndarray        # wheel controls
    wheel_enabled: bool
    r_max: float

    @classmethod
    def from_scenario(cls, sc) -> "Model":
        nt = 3
        cp = np.zeros((nt, nt, N_FIELDS))

        def put(a, b, pair):
            vals = np.zeros(N_FIELDS)
            vals[KN], vals[KS] = pair.kn, pair.ks
            vals[ZN], vals[ZT] = pair.damping_n, pair.damping_t
            vals[MU], vals[MUR], vals[ZR] = pair.friction, pair.rolling_friction, pair.rolling_damping
            cp[a, b] = vals
            cp[b, a] = vals

        put(0, 0, sc.contact.soil_soil)
        put(1, 0, sc.contact.soil_wall)
        put(2, 0, sc.contact.soil_wheel)
        walls = np.array([sc.bin.length, 1.0, 1.0, 1.0])
        wg = np.zeros(WG_SIZE)
        wc = np.zeros(WC_SIZE)
        w = sc.wheel
        if w.enabled:
            wg[WG_ENABLED] = 1.0
            wg[WG_R] = w.radius
            wg[WG_CAP] = 0.5 * w.lug_thickness
            wg[WG_LUG_IN] = w.radius
            wg[WG_LUG_OUT] = max(w.radius, w.lug_tip_radius - 0.5 * w.lug_thickness)
            wg[WG_NLUGS] = w.n_lugs
            wg[WG_MASS] = w.load / sc.physics.gravity
            wc[WC_SETTLE] = w.settle_time
            wc[WC_OMEGA] = w.omega
            wc[WC_SLIPMODE] = 1.0 if w.control == "slip" else 0.0
            wc[WC_DRAWBAR] = w.drawbar_load
            wc[WC_RAMP] = w.drawbar_ramp
            wc[WC_SLIP] = w.slip
        gx, gy = sc.gravity_vector
        return cls(dt=sc.physics.dt, gx=gx, gy=gy, skin=sc.bed.skin, cp=cp, walls=walls, wg=wg,
                   wc=wc, wheel_enabled=w.enabled, r_max=sc.soil.r_max)

    def without_wheel(self) -> "Model":
        wg = self.wg.copy()
        wg[WG_ENABLED] = 0.0
        return Model(self.dt, self.gx, self.gy, self.skin, self.cp, self.walls, wg, self.wc,
                     False, self.r_max)


@njit(cache=True)
def _run_steps(nsteps, step0, dt, gx, gy, skin, n, x, y, vx, vy, w, r, mass, inertia, mat, gid,
               nbr, nbr_n, xref, yref, hist_n, hist_id, hist_ft, hist_mr, fx, fy, tq,
               cp, walls, wg, ws, wc, wfx, wfy, wtq, wcount, sid, sf, err, rec, rebuild_now):
    wheel = wg[0] > 0.5
    lugdir = np.zeros((max(1, int(wg[WG_NLUGS])), 2))
    part = np.zeros(N_CHUNKS)
    if rebuild_now:
        build_neighbors(x, y, r, gid, n, skin, nbr, nbr_n, xref, yref, err)
    half2 = 0.25 * skin * skin
    rebuilds = 0
    wfxs = 0.0
    wfys = 0.0
    wtqs = 0.0
    for s in range(nsteps):
        t = (step0 + s) * dt
        if wheel:
            apply_wheel_controls(t, ws, wg, wc)
            lug_directions(ws[WS_THETA], int(wg[WG_NLUGS]), lugdir)
        compute_forces(n, x, y, vx, vy, w, r, mass, inertia, mat, gid, nbr, nbr_n,
                       hist_n, hist_id, hist_ft, hist_mr, fx, fy, tq, cp, walls, wg, ws,
                       wfx, wfy, wtq, wcount, lugdir, sid, sf, dt, err)
        if err[0] != 0 or err[1] != 0:
            return s, rebuilds
        if wheel:
            wfxs, wfys, wtqs, cnt = wheel_reaction(n, gid, wfx, wfy, wtq, wcount)
            rec[s, 0] = t
            rec[s, 1] = ws[0]
            rec[s, 2] = ws[1]
            rec[s, 3] = ws[2]
            rec[s, 4] = ws[3]
            rec[s, 5] = ws[5]
            rec[s, 6] = ws[4]
            rec[s, 7] = wfxs
            rec[s, 8] = wfys
            rec[s, 9] = wtqs
            rec[s, 10] = drawbar_force(t, wc)
            rec[s, 11] = cnt
        disp2 = integrate_discs(n, x, y, vx, vy, w, mass, inertia, fx, fy, tq, gx, gy, dt,
                                xref, yref, part)
        if wheel:
            integrate_wheel(t, ws, wg, wc, wfxs, wfys, gy, dt)
        if disp2 > half2:
            build_neighbors(x, y, r, gid, n, skin, nbr, nbr_n, xref, yref, err)
            rebuilds += 1
            if err[1] != 0:
                return s + 1, rebuilds
    return nsteps, rebuilds


class DomainStepper:
    """Advances one set of discs (and optionally the wheel) in place, K steps at a time."""

    def __init__(self, particles: Particles, model: Model, wheel_state: np.ndarray | None = None,
                 reorder: bool = True):
        if reorder and len(particles) > 1:
            perm = spatial_order(particles.x, particles.y, len(particles), 2 * model.r_max + model.skin)
            particles.permute_inplace(perm)  # the caller's discs, reordered: no second copy
        self.p = particles
        self.model = model
        self.n = len(particles)
        n = self.n
        self.ws = np.zeros(6) if wheel_state is None else np.array(wheel_state, dtype=np.float64)
        self.nbr = np.zeros((n, NBR_CAP), np.int32)
        self.nbr_n = np.zeros(n, np.int32)
        self.xref = np.zeros(n)
        self.yref = np.zeros(n)
        self.fx = np.zeros(n)
        self.fy = np.zeros(n)
        self.tq = np.zeros(n)
        self.wfx = np.zeros(n)
        self.wfy = np.zeros(n)
        self.wtq = np.zeros(n)
        self.wcount = np.zeros(n, np.int32)
        self.sid, self.sf = make_scratch(self.p.hist_id.shape[1])
        self.err = np.zeros(2, np.int64)
        self._built = False
        self.rebuilds = 0

    def advance(self, step0: int, nsteps: int) -> np.ndarray:
        """Advance nsteps from global step step0; returns the per-step wheel records."""
        m, p = self.model, self.p
        rec = np.zeros((nsteps if m.wheel_enabled else 0, N_REC))
        # small domains run on one thread: a parallel launch costs more than it saves
        # there, and the result is the same whatever the thread count (DESIGN section 3)
        threads = numba.get_num_threads()
        serial = self.n < SERIAL_BELOW and threads > 1
        if serial:
            numba.set_num_threads(1)
        try:
            done, rb = self._run(nsteps, step0, rec)
        finally:
            if serial:
                numba.set_num_threads(threads)
        self._built = True
        self.rebuilds += rb
        self._check(step0 + done, nsteps)
        return rec

    def _run(self, nsteps, step0, rec):
        m, p = self.model, self.p
        return _run_steps(nsteps, step0, m.dt, m.gx, m.gy, m.skin, self.n, p.x, p.y, p.vx, p.vy,
                              p.w, p.r, p.mass, p.inertia, p.mat, p.id, self.nbr, self.nbr_n,
                              self.xref, self.yref, p.hist_n, p.hist_id, p.hist_ft, p.hist_mr,
                              self.fx, self.fy, self.tq, m.cp, m.walls, m.wg, self.ws, m.wc,
                              self.wfx, self.wfy, self.wtq, self.wcount, self.sid, self.sf,
                          self.err, rec, not self._built)

    def _check(self, at, nsteps):
        p = self.p
        if self.err[ERR_HIST_OVERFLOW]:
            raise EngineError(f"contact history overflow at step {at}: a disc has more than "
                              f"{p.hist_id.shape[1]} contacts (overlaps too large: check dt, kn, or the bed)")
        if self.err[ERR_NBR_OVERFLOW]:
            raise EngineError(f"neighbour list overflow at step {at}: more than {NBR_CAP} "
                              f"discs within reach of one disc (bed too dense or exploded)")
        if not np.isfinite(p.x).all():
            raise EngineError(f"non-finite position at step {at}: the run is unstable")
