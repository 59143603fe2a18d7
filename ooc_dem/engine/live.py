"""Serial DDM in RAM with sub-domains that persist across sweeps.

The sweep of ``SweepEngine`` rebuilds each sub-domain from the epoch every sweep:
gather its discs and halo strips, build a stepper and its neighbour lists, advance,
write the owned discs back. At K = 1 that rebuilding cost several times the
physics. Here every sub-domain keeps its local discs (owned plus halo) and its
``DomainStepper`` from sweep to sweep; all local sets live in one array,
sub-domain d at rows ``off[d]:off[d + 1]``. A sweep is then:

1. refresh: every halo copy is overwritten with its owner's copy. Only the owner
   advanced a disc with all its partners present, and no sub-domain has advanced
   yet this sweep, so the halos hold time-n states (Jacobi, DESIGN section 4);
2. ownership: a disc belongs to the slab holding its x (as in the rebuilding sweep);
3. every sub-domain advances K steps in place with THE per-domain step.

Why the bits equal the rebuilding sweep's (and so the monolithic run's): a local set
here is a superset of the one the rebuilding sweep would gather (x within
halo + ``membership_skin`` of the slab instead of halo), and discs beyond the
K-hop halo cannot reach an owned disc within K steps; forces are gathered per disc
in partner-id order and neighbour lists are complete whatever their build time, so
which extra discs are present, and their order, changes nothing (DESIGN section 3).
The local sets are rebuilt only when some disc has moved more than
``membership_skin`` in x since they were built (a disc outside a set could then be
within the halo), or when the bounds or the wheel's slab change.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..physics.layout import AX_X
from ..state import Particles
from .stepper import N_REC, DomainStepper, EngineError, Model


@njit(cache=True)
def _refresh(ids, owner_row, pos, vel, spin, hist_n, hist_id, hist_s, hist_m, x_built,
             off, ref, disp2):
    """Copy every halo row from its owner's row (what a sweep changes; id, r, mass,
    inertia and mat are fixed per disc). Returns the largest |x - x_built|; disp2[d]
    gets sub-domain d's largest squared displacement from its neighbour-list reference
    (any dimension: the axes of pos, the components of spin and the springs)."""
    cap = hist_id.shape[1]
    dim = pos.shape[1]
    moved = 0.0
    for d in range(len(off) - 1):
        m2 = 0.0
        for r in range(off[d], off[d + 1]):
            s = owner_row[ids[r]]
            if s != r:  # owner rows are never written here, so the sources are all time n
                for a in range(dim):
                    pos[r, a] = pos[s, a]
                    vel[r, a] = vel[s, a]
                for a in range(spin.shape[1]):
                    spin[r, a] = spin[s, a]
                hist_n[r] = hist_n[s]
                for q in range(cap):
                    hist_id[r, q] = hist_id[s, q]
                    for c in range(hist_s.shape[2]):
                        hist_s[r, q, c] = hist_s[s, q, c]
                    for c in range(hist_m.shape[2]):
                        hist_m[r, q, c] = hist_m[s, q, c]
            dx = abs(pos[r, AX_X] - x_built[r])
            if dx > moved:
                moved = dx
            e2 = 0.0
            for a in range(dim):
                e = pos[r, a] - ref[r, a]
                e2 += e * e
            if e2 > m2:
                m2 = e2
        disp2[d] = m2
    return moved


@njit(cache=True)
def _assign_owners(ids, x, off, bounds, owner_row, owned):
    """A disc belongs to the slab holding its x; returns how many rows are owned."""
    count = 0
    for d in range(len(off) - 1):
        lo = bounds[d]
        hi = bounds[d + 1]
        for r in range(off[d], off[d + 1]):
            if x[r] >= lo and x[r] < hi:
                owned[r] = True
                owner_row[ids[r]] = r
                count += 1
            else:
                owned[r] = False
    return count


class LiveDomains:
    """All sub-domains of a serial-DDM run with their halos and steppers, kept in RAM."""

    def __init__(self, discs: Particles, bounds: np.ndarray, halo: float, membership_skin: float,
                 model: Model, model_nowheel: Model, ws: np.ndarray, wslab: int):
        self.bounds = np.asarray(bounds, np.float64)
        self.D = len(self.bounds) - 1
        self.n = len(discs)
        self.wslab = wslab
        self.membership_skin = membership_skin
        x = discs.pos[:, AX_X]
        order = np.argsort(x, kind="stable")
        xs = x[order]
        reach = halo + membership_skin
        rows, off = [], [0]
        for d in range(self.D):
            a = int(np.searchsorted(xs, self.bounds[d] - reach, "left"))
            b = int(np.searchsorted(xs, self.bounds[d + 1] + reach, "left"))
            rows.append(order[a:b])
            off.append(off[-1] + b - a)
        # x-sorted local sets: cache-friendly, and memory order never changes a result
        self.p = discs.take(np.concatenate(rows) if rows else np.zeros(0, np.int64))
        self.off = np.asarray(off, np.int64)
        self.x_built = self.p.pos[:, AX_X].copy()
        # owner_row[id]: the row holding the disc's authoritative copy; owned[row]
        self.owner_row = np.full(int(self.p.id.max()) + 1 if len(self.p) else 0, -1, np.int64)
        self.owned = np.zeros(len(self.p), np.bool_)
        # the steppers' neighbour-list references, one array for all (checked in _refresh)
        self.ref = np.zeros((len(self.p), self.p.dim))
        self.disp2 = np.zeros(self.D)
        self.steppers = []
        arrays = self.p.arrays()
        for d in range(self.D):
            a, b = self.off[d], self.off[d + 1]
            view = Particles(**{k: v[a:b] for k, v in arrays.items()})  # views, not copies
            if d == wslab:
                st = DomainStepper(view, model, ws, reorder=False)
            else:
                st = DomainStepper(view, model_nowheel, None, reorder=False)
            st.ref = self.ref[a:b]
            self.steppers.append(st)
        self._own()

    def resident(self) -> list[int]:
        return [int(self.off[d + 1] - self.off[d]) for d in range(self.D)]

    def _own(self) -> None:
        p = self.p
        total = _assign_owners(p.id, p.pos[:, AX_X], self.off, self.bounds, self.owner_row, self.owned)
        if total != self.n:
            raise EngineError(f"serial DDM owns {total} of {self.n} discs "
                              f"(bounds {self.bounds.tolist()}): decomposition error")

    def owned_rows(self, d: int) -> np.ndarray:
        """Rows of the discs sub-domain d owned at the start of the last sweep."""
        a, b = self.off[d], self.off[d + 1]
        return np.flatnonzero(self.owned[a:b]) + a

    def refresh(self) -> bool:
        """Halo copies <- owners' time-n copies, then ownership from x. False when the
        local sets must be rebuilt instead (a disc moved beyond the membership skin)."""
        p = self.p
        moved = _refresh(p.id, self.owner_row, p.pos, p.vel, p.spin, p.hist_n, p.hist_id,
                         p.hist_s, p.hist_m, self.x_built, self.off, self.ref, self.disp2)
        if moved > self.membership_skin:
            return False
        self._own()
        # a refreshed disc may have jumped relative to its neighbour-list reference:
        # rebuild that sub-domain's lists when the skin no longer covers it
        for d, st in enumerate(self.steppers):
            if self.disp2[d] > 0.25 * st.model.skin ** 2:
                st._built = False
        return True

    def advance(self, step0: int, k: int):
        """Every sub-domain K steps in place; returns (wheel records, wheel state or None)."""
        rec_wheel = np.zeros((0, N_REC))
        ws = None
        for d, st in enumerate(self.steppers):
            rec = st.advance(step0, k) if st.n else np.zeros((0, N_REC))
            if d == self.wslab:
                rec_wheel = rec
                ws = st.ws.copy()
        return rec_wheel, ws
