"""Serial DDM in RAM with sub-domains that persist across sweeps.

The sweep of ``SweepEngine`` rebuilds each sub-domain from the epoch every sweep:
gather its discs and halo strips, build a stepper and its neighbour lists, advance,
write the owned discs back. At K = 1 that rebuilding cost several times the
physics. Here every sub-domain keeps its local discs (owned plus halo) and its
``DomainStepper`` from sweep to sweep; all local sets live in one array,
sub-domain d at rows ``off[d]:off[d + 1]``. A sweep is then:

1. refresh: every halo copy is overwritten with its owner's copy. Only the owner
   advanced a disc with all its partners present, and no sub-domain has advanced
   yet this sweep, so the halos hold time-n states (Jacobi, docs/design.md §4);
2. ownership: a disc belongs to the slab holding its x (as in the rebuilding sweep);
3. every sub-domain advances K steps in place with THE per-domain step.

Why the bits equal the rebuilding sweep's (and so the monolithic run's): a local set
here is a superset of the one the rebuilding sweep would gather (x within
halo + ``membership_skin`` of the slab instead of halo), and discs beyond the
K-hop halo cannot reach an owned disc within K steps; forces are gathered per disc
in partner-id order and neighbour lists are complete whatever their build time, so
which extra discs are present, and their order, changes nothing (docs/design.md §3).
The local sets are rebuilt only when some disc has moved more than
``membership_skin`` in x since they were built (a disc outside a set could then be
within the halo), or when the bounds or the wheel's slab change.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

from ..model.decomposition import group_order
from ..physics import layout as L
from ..physics.history import ROLE_SHARED, ROLE_STABLE
from ..physics.layout import AX_X, ERR_BODY_CAPACITY, ERR_PAIR_CAPACITY, WHEEL_RECORD, record
from ..model.state import Particles
from .live_kernels import (
    F_DONE,
    F_PAIRS_DONE,
    F_REBUILD,
    F_REBUILDS,
    SWEEPS_DOMAIN,
    SWEEPS_DONE,
    SWEEPS_OWNERSHIP,
    SWEEPS_WHEEL,
    own_rows,
    refresh_own_pieces,
    row_pieces,
    sweeps_kernel,
    typed_append,
    typed_list_of,
)
from .stepper import N_REC, DomainStepper, EngineError, Model


class LiveDomains:
    """All sub-domains of a serial-DDM run with their halos and steppers, kept in RAM."""

    def __init__(
        self,
        discs: Particles,
        bounds: np.ndarray,
        halo: float,
        membership_skin: float,
        model: Model,
        model_nowheel: Model,
        ws: np.ndarray,
        wslab: int,
        active: np.ndarray | None = None,
        whole_refresh: bool = True,
    ):
        """active: which sub-domains are advanced (default all; an MPI rank's two ghost
        sub-domains, which only hold the neighbour ranks' copies, are not).
        whole_refresh: every halo row is refreshed from its owner's row before each sweep
        (serial DDM; an MPI rank's rows beyond the exchanged strips are not), so one-step
        sweeps may keep every pair row (``live_kernels._run_sweeps``' keep_rows)."""
        self.bounds = np.asarray(bounds, np.float64)
        self.D = len(self.bounds) - 1
        self.n = len(discs)
        self.wslab = wslab
        self.active = np.ones(self.D, np.bool_) if active is None else np.asarray(active, np.bool_).copy()
        self.membership_skin = membership_skin
        self.whole_refresh = whole_refresh
        x = discs.pos[:, AX_X]
        order = np.argsort(x, kind="stable")
        xs = x[order]
        reach = halo + membership_skin
        rows, off = [], [0]
        for d in range(self.D):
            a = int(np.searchsorted(xs, self.bounds[d] - reach, "left"))
            b = int(np.searchsorted(xs, self.bounds[d + 1] + reach, "left"))
            strip = order[a:b]
            # each local set in the groups' cell order (decomposition.group_order): neighbours close
            # in memory; memory order never changes a result
            rows.append(strip[group_order(discs.pos[strip], model.order_cell)])
            off.append(off[-1] + b - a)
        self.p = discs.take(np.concatenate(rows) if rows else np.zeros(0, np.int64))
        self.off = np.asarray(off, np.int64)
        self.x_built = self.p.pos[:, AX_X].copy()
        # slot[row]: the rank of the row's id among the local sets' ids (a table sized by the
        # discs, not by the largest id); owner_row[slot]: the row holding the disc's
        # authoritative copy; owned[row]
        self.uids, slot, counts = np.unique(self.p.id, return_inverse=True, return_counts=True)
        self.slot = slot.astype(np.int64).reshape(-1)
        self.owner_row = np.full(len(self.uids), -1, np.int64)
        self.owned = np.zeros(len(self.p), np.bool_)
        self.owned_before = np.zeros(len(self.p), np.bool_)
        # history.ROLE_* of each row in the compiled sweeps: ROLE_SHARED (the row's disc has
        # a copy in another sub-domain) is fixed for these local sets, the ownership bits
        # are set with the ownership
        self.role = np.zeros(len(self.p), np.int8)
        if len(self.p):
            self.role[counts[self.slot] > 1] = ROLE_SHARED
        # the steppers' neighbour-list references, one array for all (checked by the refresh)
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
        # rows of the advanced sub-domains (fixed for these local sets)
        self._active_rows = np.concatenate(
            [np.arange(self.off[j], self.off[j + 1]) for j in range(self.D) if self.active[j]]
            or [np.zeros(0, np.int64)]
        )
        # the compiled sweeps' per-sub-domain flags, lane plan and rebuild thresholds
        self.flags = [np.zeros(4, np.int64) for _ in range(self.D)]
        self._lane_plan = self._lanes()
        self._rebuild2 = np.array([0.25 * (st.model.skin * st.model.skin) for st in self.steppers])
        # the refresh and the ownership share the rows between the threads in pieces
        self._pieces = row_pieces(self.off)
        self._part = np.zeros((len(self._pieces), 2))
        self._doms: Any = None  # a numba typed List (_domain_list)
        self._doms_key: tuple[tuple[int, int, int], ...] | None = None
        self._entry = (None, None)  # (list of sub-domains, the compiled sweeps for it: _compiled)
        self._swept = False  # a sweep has run on these local sets (run_sweeps' refresh_first)
        self._own()

    def resident(self) -> list[int]:
        return [int(self.off[d + 1] - self.off[d]) for d in range(self.D)]

    def _own(self) -> None:
        """Ownership from x. A row owned before and now keeps ROLE_OWNED_BEFORE, so a pair
        of two such rows keeps its pair row in the compiled sweeps (history.load_history:
        both were computed from their true states; nothing outside the sub-domain writes an
        owned row)."""
        p = self.p
        self._check_owned(
            own_rows(
                self.slot,
                p.pos[:, AX_X],
                self.off,
                self.bounds,
                self.owner_row,
                self.owned,
                self.owned_before,
                self.role,
            )
        )

    def _check_owned(self, total: int) -> None:
        """Every disc owned exactly once (``total`` rows owned of n discs)."""
        if total != self.n:
            raise EngineError(
                f"serial DDM owns {total} of {self.n} discs (bounds {self.bounds.tolist()}): decomposition error"
            )

    def owned_active_rows(self) -> np.ndarray:
        """Rows owned at the start of the last sweep by the advanced sub-domains."""
        return self._active_rows[self.owned[self._active_rows]]

    def owned_rows(self, d: int) -> np.ndarray:
        """Rows of the discs sub-domain d owned at the start of the last sweep."""
        a, b = self.off[d], self.off[d + 1]
        return np.flatnonzero(self.owned[a:b]) + a

    def refresh(self) -> bool:
        """Halo copies <- owners' time-n copies, then ownership from x. False when the
        local sets must be rebuilt instead (a disc moved beyond the membership skin)."""
        p = self.p
        moved, total = refresh_own_pieces(
            self._pieces,
            self.slot,
            self.owner_row,
            p.pos,
            p.vel,
            p.spin,
            p.hist_n,
            p.hist_id,
            p.hist_s,
            p.hist_m,
            self.x_built,
            self.ref,
            self.disp2,
            True,
            self._part,
            self.membership_skin,
            self.bounds,
            self.owned,
            self.owned_before,
            self.role,
        )
        if moved > self.membership_skin:
            return False
        self._check_owned(total)
        # a refreshed disc may have jumped relative to its neighbour-list reference:
        # rebuild that sub-domain's lists when the skin no longer covers it
        for d, st in enumerate(self.steppers):
            if self.disp2[d] > self._rebuild2[d]:
                st._built = False
        return True

    # ------------------------------------------------------- compiled sweeps
    def _lanes(self):
        """Sub-domains per lane (thread), largest first onto the least loaded lane."""
        runs = [j for j in range(self.D) if self.active[j]]
        nl = max(1, min(numba.get_num_threads(), len(runs)))
        load = [0] * nl
        lanes: list[list[int]] = [[] for _ in range(nl)]
        for j in sorted(runs, key=lambda j: -int(self.off[j + 1] - self.off[j])):
            lane = min(range(nl), key=lambda a: load[a])
            lanes[lane].append(j)
            load[lane] += int(self.off[j + 1] - self.off[j])
        flat = np.array([j for ln in lanes for j in ln], np.int64)
        lane_off = np.cumsum([0] + [len(ln) for ln in lanes]).astype(np.int64)
        return flat, lane_off

    def _domain_list(self):
        """The compiled sweeps' typed list of sub-domains: built again only when a stepper's
        buffers were replaced (grown), since making it costs more than a short sweep."""
        key = tuple((id(st.rows), id(st.bodies.rows), id(st.half_off)) for st in self.steppers)
        if self._doms_key == key:
            return self._doms
        doms = None
        for j, (st, fl) in enumerate(zip(self.steppers, self.flags)):
            item = st.kernel_args() + (fl, self.role[self.off[j] : self.off[j + 1]])
            if doms is None:
                doms = typed_list_of(item)
            else:
                typed_append(doms, item)
        self._doms, self._doms_key = doms, key
        return doms

    def _compiled(self, run, doms, args):
        """What to call for the compiled sweeps with these arguments: numba's compiled overload
        for their types, called directly (the function the dispatcher itself calls once it
        has typed them). The dispatcher types every argument on every call, ~75 us here, 35
        of them for the typed list of sub-domains; an MPI rank pays that every block of a few
        steps (~5 % of a paper2008 block of 4). The types cannot change while the list is
        the same (the arrays are the local sets' own, replaced only with the list), so the
        overload is looked up once per list, after the dispatcher has compiled or loaded it
        on the list's first call; the dispatcher stays the callee if numba gives none."""
        held, fn = self._entry
        if held is doms and fn is not None:
            return fn
        if held is not doms:
            self._entry = (doms, None)
            return run
        try:
            cres = run.overloads.get(tuple(numba.typeof(a) for a in args))
        except AttributeError:  # a numba without the overloads table
            cres = None
        self._entry = (doms, run if cres is None else cres.entry_point)
        return self._entry[1]

    def run_sweeps(self, step0: int, nsweeps: int, K: int, refresh_first: bool, wheel_reach: float):
        """Up to nsweeps sweeps of K steps in compiled calls (see ``live_kernels._run_sweeps``);
        returns (wheel records of the steps done, sweeps done, why it stopped: SWEEPS_*).
        refresh_first only after a sweep: fresh local sets hold current states already, and their pair
        lists are not built (a refresh would write springs back from them)."""
        if refresh_first and not self._swept:
            raise EngineError("serial DDM: a refresh asked of local sets that have not been swept")
        if not self.steppers:
            raise EngineError("serial DDM: no sub-domain to sweep")
        run = sweeps_kernel(self.steppers[0].kern)
        recbuf = np.zeros((nsweeps * K, N_REC))
        norec = np.zeros(1, WHEEL_RECORD)
        for st, fl in zip(self.steppers, self.flags):
            fl[F_REBUILD] = 0 if st._built else 1
            fl[F_PAIRS_DONE] = 1 if st._pairs_done else 0
            fl[F_REBUILDS] = 0
        doms = self._domain_list()
        p = self.p
        lanes, lane_off = self._lane_plan
        keep_rows = K == 1 and self.whole_refresh
        all_stable = np.full(max(self.resident(), default=0) if keep_rows else 0, ROLE_STABLE, np.int8)
        done = 0
        status = SWEEPS_DONE
        while done < nsweeps:
            args = (
                nsweeps - done,
                K,
                step0 + done * K,
                refresh_first or done > 0,
                doms,
                lanes,
                lane_off,
                self.wslab,
                record(recbuf[done * K :], WHEEL_RECORD) if self.wslab >= 0 else norec,
                norec,
                self.slot,
                self.owner_row,
                p.pos,
                p.vel,
                p.spin,
                p.hist_n,
                p.hist_id,
                p.hist_s,
                p.hist_m,
                self.x_built,
                self.off,
                self.ref,
                self.disp2,
                self.bounds,
                self.owned,
                self.owned_before,
                self.role,
                self.n,
                self.membership_skin,
                self._rebuild2,
                wheel_reach if self.wslab >= 0 else -1.0,
                self.active,
                keep_rows,
                all_stable,
                self._pieces,
                self._part,
            )
            n_sw, status = self._compiled(run, doms, args)(*args)
            done += n_sw
            if status == SWEEPS_DOMAIN:
                # a sub-domain stopped (a buffer to grow, or an error): finish its block
                # with its own stepper, which grows what it must, then go on
                self._finish_block(step0 + done * K, K, recbuf[done * K : (done + 1) * K])
                done += 1
                doms = self._domain_list()
                if self.wslab >= 0:
                    wx = self.steppers[self.wslab].ws[L.WS_X]
                    lo, hi = self.bounds[self.wslab], self.bounds[self.wslab + 1]
                    if wheel_reach >= 0.0 and not (lo <= wx - wheel_reach and wx + wheel_reach < hi):
                        status = SWEEPS_WHEEL
                        break
                continue
            if status == SWEEPS_OWNERSHIP:
                raise EngineError(
                    f"serial DDM lost ownership of discs at step {step0 + done * K} "
                    f"(bounds {self.bounds.tolist()}): decomposition error"
                )
            break
        self._swept = self._swept or done > 0
        for st, fl in zip(self.steppers, self.flags):
            st._built = fl[F_REBUILD] == 0
            st._pairs_done = False
            st.rebuilds += int(fl[F_REBUILDS])
        # the steppers' checks (one look at every position first: this runs every sweep)
        if any(st.err.any() for st in self.steppers) or not np.isfinite(p.pos).all():
            for st in self.steppers:
                if st.n:
                    st._check(step0 + done * K, K)
        return recbuf[: done * K], done, status

    def _finish_block(self, step0: int, K: int, rec) -> None:
        """The sub-domains a compiled sweep left short of K steps: each continues from where
        it stopped with its own stepper (the same bits: the same step, as DomainStepper
        runs it after growing a buffer)."""
        for j, (st, fl) in enumerate(zip(self.steppers, self.flags)):
            k = int(fl[F_DONE])
            err = st.err
            st.rebuilds += int(fl[F_REBUILDS])
            fl[F_REBUILDS] = 0
            st._built = True
            if err[ERR_PAIR_CAPACITY]:
                st._grow_pairs(int(err[ERR_PAIR_CAPACITY]))
                err[ERR_PAIR_CAPACITY] = 0
                st._built = False
            elif err[ERR_BODY_CAPACITY]:
                st._grow_bodies()
                err[ERR_BODY_CAPACITY] = 0
                st._pairs_done = True
            elif err.any():
                st._check(step0 + k, K)  # fatal (history overflow): raises
            if k < K and st.n:
                r = rec[k:] if j == self.wslab else np.zeros((0, N_REC))
                st._run(K - k, step0 + k, r)
                st._check(step0 + K, K)
            fl[F_DONE] = K
            fl[F_REBUILD] = 0 if st._built else 1
            fl[F_PAIRS_DONE] = 1 if st._pairs_done else 0
            st._pairs_done = False

    @property
    def compiled(self) -> bool:
        """Whole sweeps run in one compiled call (``run_sweeps``: every kernel module has a
        one-thread step); else (no sub-domain) each is advanced by its own stepper
        (``advance``)."""
        return bool(self.steppers)

    def advance(self, step0: int, k: int):
        """Every advanced sub-domain K steps in place, each with its own stepper; returns
        (wheel records, wheel state or None)."""
        rec_wheel = np.zeros((0, N_REC))
        ws = None
        for d, st in enumerate(self.steppers):
            if not self.active[d]:
                continue
            rec = st.advance(step0, k) if st.n else np.zeros((0, N_REC))
            if d == self.wslab:
                rec_wheel = rec
                ws = st.ws.copy()
        self._swept = True
        return rec_wheel, ws
