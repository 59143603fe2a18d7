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
from numba import njit, prange
from numba.typed import List

from ..model.decomposition import group_order
from ..physics import layout as L
from ..physics.history import ROLE_OWNED, ROLE_OWNED_BEFORE, ROLE_SHARED, ROLE_STABLE
from ..physics.layout import (
    AX_X,
    ERR_BODY_CAPACITY,
    ERR_PAIR_CAPACITY,
    PLATE,
    PLATE_RECORD,
    WHEEL_RECORD,
    Plates,
    record,
)
from ..physics.twins import serial_twin, slot
from ..model.state import Particles
from .stepper import N_REC, DomainStepper, EngineError, Model


@njit(cache=True)
def _refresh_rows(lo, hi, ids, owner_row, pos, vel, spin, hist_n, hist_id, hist_s, hist_m, x_built, ref, with_hist):
    """Rows lo..hi-1 of the halo refresh (``refresh_own_pieces``): every halo row copied
    from its owner's row (what a sweep changes; id, r, mass, inertia and mat are fixed per
    disc), its contact history too unless with_hist is False (K = 1: see ``_run_sweeps``);
    returns
    (their largest |x - x_built|, the largest squared displacement from ref of the halo
    rows). An owner row is not measured: the refresh does not move it, and the step that
    moved it rebuilt its sub-domain's lists if it went beyond the threshold (run_steps
    checks every row after its gather), so it is within it."""
    cap = hist_id.shape[1]
    dim = pos.shape[1]
    moved = 0.0
    m2 = 0.0
    for r in range(lo, hi):
        s = owner_row[ids[r]]
        if s != r:  # owner rows are never written here, so the sources are all time n
            for a in range(dim):
                pos[r, a] = pos[s, a]
                vel[r, a] = vel[s, a]
            for a in range(spin.shape[1]):
                spin[r, a] = spin[s, a]
            if with_hist:
                hist_n[r] = hist_n[s]
                for q in range(cap):
                    hist_id[r, q] = hist_id[s, q]
                    for c in range(hist_s.shape[2]):
                        hist_s[r, q, c] = hist_s[s, q, c]
                    for c in range(hist_m.shape[2]):
                        hist_m[r, q, c] = hist_m[s, q, c]
            e2 = 0.0
            for a in range(dim):
                e = pos[r, a] - ref[r, a]
                e2 += e * e
            if e2 > m2:
                m2 = e2
        dx = abs(pos[r, AX_X] - x_built[r])
        if dx > moved:
            moved = dx
    return moved, m2


@njit(cache=True)
def _own_range(lo, hi, x_lo, x_hi, ids, x, owner_row, owned, owned_before, role):
    """Rows lo..hi-1 of one sub-domain (slab x_lo <= x < x_hi): the last ownership kept in
    owned_before, ownership from x (owner_row of the owned discs set), each row's
    history.ROLE_* bits from the two (its ROLE_SHARED bit, fixed for the local sets, kept);
    returns how many are owned."""
    count = 0
    for r in range(lo, hi):
        before = owned[r]
        owned_before[r] = before
        now = x[r] >= x_lo and x[r] < x_hi
        owned[r] = now
        if now:
            owner_row[ids[r]] = r
            count += 1
        role[r] = (ROLE_OWNED if now else 0) | (ROLE_OWNED_BEFORE if before else 0) | (role[r] & ROLE_SHARED)
    return count


@njit(cache=True)
def _own_rows(ids, x, off, bounds, owner_row, owned, owned_before, role):
    """A disc belongs to the slab holding its x (``_own_range`` over every sub-domain);
    returns how many rows are owned."""
    count = 0
    for d in range(len(off) - 1):
        count += _own_range(off[d], off[d + 1], bounds[d], bounds[d + 1], ids, x, owner_row, owned, owned_before, role)
    return count


def row_pieces(off, size: int = 256) -> np.ndarray:
    """The rows of every sub-domain cut into pieces of at most `size` rows: (n, 3) rows
    (first row, end row, sub-domain), so that a parallel loop over the pieces shares the
    rows evenly between the threads whatever the sub-domains' sizes."""
    pieces = [
        (a, min(a + size, int(off[d + 1])), d)
        for d in range(len(off) - 1)
        for a in range(int(off[d]), int(off[d + 1]), size)
    ]
    return np.array(pieces, np.int64).reshape(-1, 3)


@njit(cache=True, parallel=True)
def refresh_own_pieces(
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
    with_hist,
    part,
    membership_skin,
    bounds,
    owned,
    owned_before,
    role,
):
    """The halo refresh (``_refresh_rows``; disp2[d]: the largest squared displacement from
    its neighbour-list reference of sub-domain d's refreshed rows), then ownership from x
    (``_own_range``), the rows shared between the threads: two parallel loops over
    ``row_pieces``, since every halo copy must be made before any owner row moves in
    owner_row. Each row is written by one piece only, and every value is the one a serial
    pass gives (copies, maxima, counts). Returns (largest |x - x_built|, rows owned; -1
    when the motion exceeds membership_skin: ownership is then left as it was)."""
    n = pieces.shape[0]
    for t in prange(n):
        part[t, 0], part[t, 1] = _refresh_rows(
            pieces[t, 0],
            pieces[t, 1],
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
            with_hist,
        )
    moved = 0.0
    disp2[:] = 0.0
    for t in range(n):
        moved = max(moved, part[t, 0])
        d = pieces[t, 2]
        disp2[d] = max(disp2[d], part[t, 1])
    if moved > membership_skin:
        return moved, -1
    x = pos[:, AX_X]
    for t in prange(n):
        d = pieces[t, 2]
        part[t, 0] = _own_range(
            pieces[t, 0], pieces[t, 1], bounds[d], bounds[d + 1], ids, x, owner_row, owned, owned_before, role
        )
    count = np.int64(0)
    for t in range(n):
        count += np.int64(part[t, 0])  # a count of at most `size` rows: exact as a float
    return moved, count


# per-sub-domain flags of the compiled sweeps (one int64 array per sub-domain)
F_DONE, F_REBUILD, F_PAIRS_DONE, F_REBUILDS = range(4)
# how run_sweeps stopped
SWEEPS_DONE, SWEEPS_REBUILD, SWEEPS_WHEEL, SWEEPS_DOMAIN, SWEEPS_OWNERSHIP = range(5)

# the dimension's one-thread step and write-back: sweeps_kernel binds them in each compiled
# twin of _run_sweeps (physics.twins)
run_steps_serial = slot("the dimension's one-thread run_steps (physics.KernelModule)")
sync_history_serial = slot("the dimension's one-thread sync_history (physics.KernelModule)")


def _run_sweeps(
    nsweeps,
    K,
    step0,
    refresh_first,
    doms,
    lanes,
    lane_off,
    wslab,
    recbuf,
    norec,
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
    off,
    ref,
    disp2,
    bounds,
    owned,
    owned_before,
    role,
    n_total,
    membership_skin,
    rebuild2,
    wheel_reach,
    active,
    keep_rows,
    all_stable,
    pieces,
    part,
):
    """Serial DDM, whole sweeps in one compiled call: per sweep, (1) every halo copy from
    its owner and ownership from x (skipped before the first sweep of a fresh build),
    (2) every sub-domain K steps with the one-thread step, the sub-domains side by side on
    the lanes (a lane is one thread; each runs its sub-domains one after another:
    Jacobi, so the order and the lanes never change a result), (3) the wheel's slab check
    for the next sweep. Returns (sweeps done, how it stopped).

    doms[j] = (kernel params, Discs, Pairs, Bodies, Forces, wheel state, errors, flags,
    roles) of sub-domain j (views of the local sets: rows off[j]:off[j + 1]); recbuf: the
    wheel records of every step (WHEEL_RECORD, nsweeps * K rows), written by sub-domain
    wslab; wheel_reach: < 0 for no wheel check, else the wheel's reach plus margin (the
    sweep stops when it leaves its slab, for a re-decomposition); active[j]: sub-domain j
    is advanced (an MPI rank's ghost sub-domains are not: they only hold copies; the
    lanes never list them, and their discs' histories are never written from their
    steppers' empty pair lists).

    Contact histories: between sweeps a pair's springs live in its sub-domain's pair row
    (physics.history: load_history / sync_history). role[r] (history.ROLE_* bits) says
    which rows are reloaded (a pair of two discs owned through two sweeps keeps its row: both were
    computed from their true states) and which discs' histories are written back: after
    each sweep only the owned discs another sub-domain has copies of (ROLE_SHARED: the
    next refresh copies them), and all owned discs on return.

    keep_rows (K = 1, and every halo row refreshed from its owner here): every pair row
    is kept from sweep to sweep and no history is copied or written back between sweeps.
    Why exact: at the start of each one-step sweep every disc of a local set holds its
    true time-n state, so every row made in the sweep is the true one (the law reads
    only the pair's two states and the row's springs, true by the same argument the
    sweep before); a halo disc's wrong position after its step is overwritten by the
    next refresh, and its own wall and wheel springs were made from its true state. A
    rebuild of a pair list reloads its rows from the discs' histories: all of the
    sub-domain's discs are written back from its rows first (their partners outside the
    local set have no rows). all_stable: history.ROLE_STABLE for every row (the roles
    that make load_history keep every row). pieces, part: the rows in pieces for the
    parallel refresh and ownership (``row_pieces``) and their scratch (len(pieces), 2)."""
    status = SWEEPS_DONE
    done = nsweeps
    every_disc = np.zeros((0, 2), np.int64)  # run_steps' spans: each step advances every disc
    no_plates = Plates(np.empty(0, PLATE), np.empty(0, PLATE_RECORD))  # plates: DomainStepper only
    for sw in range(nsweeps):
        if sw > 0 or refresh_first:
            moved, count = refresh_own_pieces(
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
                not keep_rows,
                part,
                membership_skin,
                bounds,
                owned,
                owned_before,
                role,
            )
            if moved > membership_skin:
                status = SWEEPS_REBUILD
                done = sw
                break
            if count != n_total:
                status = SWEEPS_OWNERSHIP
                done = sw
                break
            for j in range(len(doms)):
                if active[j] and disp2[j] > rebuild2[j]:
                    # the rebuild reloads every row from the discs: write the rows back first
                    kp, d, pl, bd, forces, ws, err, flags, roles = doms[j]
                    sync_history_serial(d.gid.shape[0], d, pl, err, roles, 0 if keep_rows else ROLE_OWNED_BEFORE)
                    flags[F_REBUILD] = 1
        s0 = step0 + sw * K
        for lane in prange(len(lane_off) - 1):
            for t in range(lane_off[lane], lane_off[lane + 1]):
                j = lanes[t]
                kp, d, pl, bd, forces, ws, err, flags, roles = doms[j]
                n = d.gid.shape[0]
                if n == 0:
                    flags[F_DONE] = K
                    continue
                rec = recbuf[sw * K :] if j == wslab else norec
                k, rb = run_steps_serial(
                    K,
                    s0,
                    kp,
                    d,
                    pl,
                    bd,
                    forces,
                    ws,
                    no_plates,
                    err,
                    rec,
                    flags[F_REBUILD] != 0,
                    flags[F_PAIRS_DONE] != 0,
                    all_stable[:n] if keep_rows else roles,
                    every_disc,
                )
                flags[F_DONE] = k
                flags[F_REBUILDS] += rb
                flags[F_REBUILD] = 0
                flags[F_PAIRS_DONE] = 0
                if k == K and not err.any() and not keep_rows:
                    # the next refresh copies every owned disc that has copies elsewhere
                    sync_history_serial(n, d, pl, err, roles, ROLE_OWNED | ROLE_SHARED)
        stop = False
        for j in range(len(doms)):
            if active[j] and (doms[j][7][F_DONE] < K or doms[j][6].any()):
                stop = True
        if stop:
            status = SWEEPS_DOMAIN
            done = sw
            break
        if wheel_reach >= 0.0:
            wx = doms[wslab][5][0].x
            if not (bounds[wslab] <= wx - wheel_reach and wx + wheel_reach < bounds[wslab + 1]):
                status = SWEEPS_WHEEL
                done = sw + 1
                break
    # every owned disc leaves whole (commits, rebuilds and the one-call step read them);
    # not a sub-domain whose pair list failed to build (its rows are not made)
    for j in range(len(doms)):
        kp, d, pl, bd, forces, ws, err, flags, roles = doms[j]
        if active[j] and err[ERR_PAIR_CAPACITY] == 0 and d.gid.shape[0]:
            sync_history_serial(d.gid.shape[0], d, pl, err, roles, ROLE_OWNED)
    return done, status


@njit(cache=True)
def _list_of(item):
    """A typed List holding item. Built in compiled code so that the list's methods are
    compiled with this function and cached with it: made from Python, numba compiles
    them afresh in every process (~3 s, more than a short run's physics)."""
    out = List()
    out.append(item)
    return out


@njit(cache=True)
def _append(items, item):
    items.append(item)


_SWEEPS: dict[str, Any] = {}  # the compiled sweeps by kernel module (numba dispatchers)


def sweeps_kernel(kern):
    """The compiled sweeps for one dimension's step kernels (a physics.KernelModule): its
    one-thread step, and its write-back of the rows' springs (``sync_history_serial``)."""
    if kern.__name__ not in _SWEEPS:
        name = "run_sweeps_" + kern.__name__.rsplit(".", 1)[-1]
        _SWEEPS[kern.__name__] = serial_twin(
            _run_sweeps,
            name,
            parallel=True,
            run_steps_serial=kern.run_steps_serial,
            sync_history_serial=kern.sync_history_serial,
        )
    return _SWEEPS[kern.__name__]


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
        sweeps may keep every pair row (``_run_sweeps``' keep_rows)."""
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
        self._rebuild2 = np.array([0.25 * st.model.skin**2 for st in self.steppers])
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
            _own_rows(
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
                doms = _list_of(item)
            else:
                _append(doms, item)
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
        """Up to nsweeps sweeps of K steps in compiled calls (see ``_run_sweeps``); returns
        (wheel records of the steps done, sweeps done, why it stopped: SWEEPS_*). refresh_first
        only after a sweep: fresh local sets hold current states already, and their pair
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
