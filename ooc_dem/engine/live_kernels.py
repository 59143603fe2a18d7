"""The compiled kernels of serial DDM's live sub-domains (``live.LiveDomains``).

The halo refresh and the ownership from x, over the rows of all local sets cut into pieces
shared between the threads (``row_pieces``, ``refresh_own_pieces``), and whole sweeps in one
compiled call (``_run_sweeps``, compiled once per dimension by ``sweeps_kernel``). Every
value they compute is the one a serial pass gives (copies, maxima, counts): the threads
never change a bit (docs/design.md §3, §4).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit, prange
from numba.typed import List

from ..physics.history import ROLE_OWNED, ROLE_OWNED_BEFORE, ROLE_SHARED
from ..physics.layout import AX_X, ERR_PAIR_CAPACITY, PLATE, PLATE_RECORD, Plates
from ..physics.twins import serial_twin, slot


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
def own_rows(ids, x, off, bounds, owner_row, owned, owned_before, role):
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
def typed_list_of(item):
    """A typed List holding item. Built in compiled code so that the list's methods are
    compiled with this function and cached with it: made from Python, numba compiles
    them afresh in every process (~3 s, more than a short run's physics)."""
    out = List()
    out.append(item)
    return out


@njit(cache=True)
def typed_append(items, item):
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
