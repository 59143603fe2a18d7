"""A thin Python driver of the 3D kernels for tests: sphere arrays with the spec-generic
field names, ``run_steps`` in blocks, capacity growth, error flags turned into the
engine's exception (``engine.stepper.EngineError``)."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numba
import numpy as np

from ooc_dem.engine.stepper import EngineError
from ooc_dem.physics import d3
from ooc_dem.physics.d3 import N_CHUNKS
from ooc_dem.physics.layout import EVERY_PARTICLE, NO_CONE, index_dtype, no_mesh, no_plates
from ooc_dem.physics.d3.layout import (
    BODY_ROW,
    ERR_BODY_CAPACITY,
    ERR_HIST_OVERFLOW,
    ERR_PAIR_CAPACITY,
    M_WIDTH,
    N_ERR,
    pair_row_layout,
    S_WIDTH,
    WHEEL_CONTROLS,
    WHEEL_GEOMETRY,
    WHEEL_RECORD,
    WHEEL_STATE,
    Bodies,
    Discs,
    Forces,
    KernelParams,
    Pairs,
)

SERIAL_BELOW = 3000  # spheres; below this the driver runs on one thread (same bits)
PAIR_HEADROOM = 1.05


@dataclass
class Spheres:
    """Per-sphere state (spec-generic names; every array C-contiguous)."""

    id: np.ndarray  # (N,) <i8 global id
    pos: np.ndarray  # (N, 3) at step n
    vel: np.ndarray  # (N, 3) at n - 1/2
    spin: np.ndarray  # (N, 3) angular velocity
    r: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    mat: np.ndarray  # (N,) <i4
    hist_n: np.ndarray  # (N,) <i4
    hist_id: np.ndarray  # (N, C) <i8, ascending
    hist_s: np.ndarray  # (N, C, 3) tangential spring force
    hist_m: np.ndarray  # (N, C, 3) rolling spring moment

    def __len__(self):
        return len(self.id)

    def discs(self) -> Discs:
        return Discs(
            self.pos,
            self.vel,
            self.spin,
            self.r,
            self.mass,
            self.inertia,
            self.mat,
            self.id,
            self.hist_n,
            self.hist_id,
            self.hist_s,
            self.hist_m,
        )

    def take(self, idx) -> Spheres:
        return Spheres(**{f.name: np.ascontiguousarray(getattr(self, f.name)[idx]) for f in fields(self)})

    def sorted_by_id(self) -> Spheres:
        return self.take(np.argsort(self.id, kind="stable"))

    def arrays(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def make_spheres(pos, r, density=None, mass=None, vel=None, spin=None, mat=0, ids=None, hist_cap=16) -> Spheres:
    """N solid spheres (I = 2/5 m r^2) at pos (N, 3) with radii r; mass from density
    unless given."""
    pos = np.array(pos, np.float64).reshape(-1, 3)
    n = len(pos)
    r = np.broadcast_to(np.asarray(r, np.float64), (n,)).copy()
    if mass is None:
        mass = density * 4.0 / 3.0 * np.pi * r**3
    mass = np.broadcast_to(np.asarray(mass, np.float64), (n,)).copy()
    z3 = np.zeros((n, 3))
    return Spheres(
        id=np.arange(n, dtype=np.int64) if ids is None else np.asarray(ids, np.int64).copy(),
        pos=pos.copy(),
        vel=z3.copy() if vel is None else np.array(vel, np.float64).reshape(n, 3),
        spin=z3.copy() if spin is None else np.array(spin, np.float64).reshape(n, 3),
        r=r,
        mass=mass,
        inertia=0.4 * mass * r * r,
        mat=np.broadcast_to(np.asarray(mat, np.int32), (n,)).copy(),
        hist_n=np.zeros(n, np.int32),
        hist_id=np.zeros((n, hist_cap), np.int64),
        hist_s=np.zeros((n, hist_cap, S_WIDTH)),
        hist_m=np.zeros((n, hist_cap, M_WIDTH)),
    )


class Sim:
    """Advances a Spheres set in place (no wheel)."""

    def __init__(
        self, spheres: Spheres, cp, walls, dt, gravity=(0.0, -9.81, 0.0), skin=None, keep_forces=False, reorder=False
    ):
        """cp: CONTACT_PARAMS table [N_TYPES, N_TYPES]; walls: WALLS record (1,);
        skin defaults to 0.2 r_max; reorder: sort the spheres spatially first."""
        n = len(spheres)
        if skin is None:
            skin = 0.2 * float(spheres.r.max()) if n else 0.0
        if reorder and n > 1:
            perm = d3.spatial_order(spheres.pos, n, 2 * spheres.r.max() + skin)
            for f in fields(spheres):
                getattr(spheres, f.name)[...] = getattr(spheres, f.name)[perm]
        self.s = spheres
        self.n = n
        self.step = 0
        self.kp = KernelParams(
            float(dt),
            np.array(gravity, np.float64),
            float(skin),
            np.ascontiguousarray(cp),
            np.ascontiguousarray(walls),
            np.zeros(1, WHEEL_GEOMETRY),
            np.zeros(1, WHEEL_CONTROLS),
            no_mesh(),
        )
        self.ws = np.zeros(1, WHEEL_STATE)
        self.rec = np.zeros(1, WHEEL_RECORD)
        self._idx = index_dtype(n)  # the engine's: the same kernel signatures
        self.half_off = np.zeros(n + 1, self._idx)
        self.inc_off = np.zeros(n + 1, self._idx)
        self.ref = np.zeros((n, 3))
        self._grow_pairs(0)
        nf = n if keep_forces else 0
        self.forces = Forces(np.zeros((nf, 3)), np.zeros((nf, 3)))
        self.bodies = Bodies(np.zeros(N_CHUNKS * 8, BODY_ROW), np.zeros(N_CHUNKS, np.int64))
        self.err = np.zeros(N_ERR, np.int64)
        self._built = False
        self.rebuilds = 0

    def _grow_pairs(self, npairs):
        cap = int(npairs * PAIR_HEADROOM) + 64
        self.pair_b = np.zeros(cap, self._idx)
        self.pair_a = np.zeros(cap, self._idx)
        self.inc_k = np.zeros(cap, self._idx)
        self.on = np.zeros(cap, np.uint8)
        self.rows = np.zeros(cap, pair_row_layout(self.kp.cp))

    def advance(self, nsteps: int) -> None:
        threads = numba.get_num_threads()
        serial = self.n < SERIAL_BELOW and threads > 1
        if serial:
            numba.set_num_threads(1)
        try:
            self._run(nsteps)
        finally:
            if serial:
                numba.set_num_threads(threads)
        if self.err[ERR_HIST_OVERFLOW]:
            raise EngineError(
                f"contact history overflow at step {self.step}: a sphere has more "
                f"than {self.s.hist_id.shape[1]} contacts"
            )
        if not np.isfinite(self.s.pos).all():
            raise EngineError(f"non-finite position at step {self.step}: the run is unstable")

    def _run(self, nsteps):
        d = self.s.discs()
        done = 0
        while True:
            pl = Pairs(self.half_off, self.pair_b, self.pair_a, self.inc_off, self.inc_k, self.ref, self.on, self.rows)
            k, rb = d3.run_steps(
                nsteps - done,
                self.step,
                self.kp,
                d,
                pl,
                self.bodies,
                self.forces,
                self.ws,
                no_plates(),
                self.err,
                self.rec,
                not self._built,
                False,
                EVERY_PARTICLE,
                NO_CONE,
            )
            done += k
            self.step += k
            self.rebuilds += rb
            self._built = True
            if self.err[ERR_HIST_OVERFLOW]:
                return
            if self.err[ERR_PAIR_CAPACITY]:
                self._grow_pairs(int(self.err[ERR_PAIR_CAPACITY]))
                self.err[ERR_PAIR_CAPACITY] = 0
                self._built = False
            elif self.err[ERR_BODY_CAPACITY]:
                self.bodies = Bodies(np.zeros(2 * self.bodies.rows.shape[0], BODY_ROW), self.bodies.count)
                self.err[ERR_BODY_CAPACITY] = 0
            else:
                return
            if done >= nsteps:
                return
