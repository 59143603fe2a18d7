"""Contact histories between the particles and the pair rows (numba, no I/O; written once,
compiled per dimension by ``physics.step.instantiate``).

While a run's steps go on, a pair's springs live in its row of the pair list (read and
rewritten by ``produce``, no per-particle lookup); between runs they live in the lower
particle's history (``hist_id`` sorted by partner id: its body contacts first, negative
ids, then its pairs). ``load_history`` fills the rows from the histories (at the start of
a run and after each neighbour build), ``sync_history`` writes them back (before each
build and at the end of a run), so the particles always leave a run whole.

A particle's role in a serial-DDM sub-domain (bit flags, ``ROLE_*``) says which rows are
reloaded and which histories written back (engine.live).
"""

from numba import njit, prange

from .chunks import N_CHUNKS, chunk_range
from .layout import ERR_HIST_OVERFLOW
from .twins import slot

# owned in this sweep, owned in the last sweep too, copied in another sub-domain too
ROLE_OWNED, ROLE_OWNED_BEFORE, ROLE_SHARED = 1, 2, 4
ROLE_STABLE = ROLE_OWNED | ROLE_OWNED_BEFORE

# ------------------------------------------------- what each dimension binds (its rows)
springs_from_history = slot(
    "springs_from_history(row, hist_s, hist_m, i, p): the pair row's springs from entry p of particle i's history"
)
pair_springs_to_history = slot(
    "pair_springs_to_history(hist_s, hist_m, i, k, row): entry k of particle i's springs from a pair row"
)


@njit(inline="always", cache=True)
def lookup(hid, i, hn, p, pid):
    """Advance the merge pointer p in particle i's sorted history to partner pid; returns
    (p, found)."""
    while p < hn and hid[i, p] < pid:
        p += 1
    return p, (p < hn and hid[i, p] == pid)


@njit(inline="always", cache=True)
def keeps_every_row(role, n):
    """Whether load_history keeps every pair row of particles 0..n-1: roles are given and
    every particle is ROLE_STABLE (serial DDM's one-step sweeps)."""
    if role.shape[0] == 0:
        return False
    for i in range(n):
        if (role[i] & ROLE_STABLE) != ROLE_STABLE:
            return False
    return True


def load_history(n, d, pl, role):
    """The pair rows' springs from the lower particle's history (after a neighbour build and
    at the start of every run: the histories may have been set from outside, e.g. a
    restart or a serial-DDM halo refresh): on[q] = in contact at the last step. From here
    to ``sync_history`` a particle's own history holds only its body entries (negative
    ids, sorted first). role (length n, or 0 = reload every row): a pair whose two
    particles are both ROLE_STABLE keeps its row (serial DDM: both were owned through the
    last sweep, so the row was made from their true states), and with every particle
    stable nothing is loaded. A row not in contact keeps whatever springs it held:
    ``produce`` reads a row's springs only when on[q]."""
    gid = d.gid
    hist_n, hist_id, hist_s, hist_m = d.hist_n, d.hist_id, d.hist_s, d.hist_m
    half_off, pair_b, on, rows = pl.half_off, pl.pair_b, pl.on, pl.rows
    if keeps_every_row(role, n):
        # a particle's history may then still hold its pairs' springs behind its body
        # entries until the gather rewrites hist_n: produce only looks up body entries
        # (negative ids, sorted first)
        return
    for ch in prange(N_CHUNKS):
        lo, hi = chunk_range(ch, 0, n)
        for i in range(lo, hi):
            hn = hist_n[i]
            p = 0
            stable = role.shape[0] and (role[i] & ROLE_STABLE) == ROLE_STABLE
            for q in range(half_off[i], half_off[i + 1]):
                if stable and (role[pair_b[q]] & ROLE_STABLE) == ROLE_STABLE:
                    continue
                p, found = lookup(hist_id, i, hn, p, gid[pair_b[q]])
                if found:
                    springs_from_history(rows[q], hist_s, hist_m, i, p)
                # in contact at the last step: a sync before the next step (a rebuild on
                # the last step of a call) then writes back exactly the history loaded
                on[q] = 1 if found else 0
            kb = 0
            while kb < hn and hist_id[i, kb] < 0:
                kb += 1
            hist_n[i] = kb


def sync_history(n, d, pl, err, role, need):
    """Each particle's full history, sorted by partner id, from its body entries (kept in
    place by the gather) and its pairs' springs in the rows: partners with lower ids
    through the CSR index, then its own half list. Run before a neighbour rebuild and at
    the end of every run, so the particles always leave the step whole. role (length n,
    or 0 = every particle): only particles with all bits of ``need`` in their role are
    written (serial DDM). Idempotent: a history restarts from its body entries. An
    overflow of the history capacity sets err[ERR_HIST_OVERFLOW] (fatal, never a silent
    drop)."""
    gid = d.gid
    hist_n, hist_id, hist_s, hist_m = d.hist_n, d.hist_id, d.hist_s, d.hist_m
    half_off, pair_b, pair_a = pl.half_off, pl.pair_b, pl.pair_a
    inc_off, inc_k, on, rows = pl.inc_off, pl.inc_k, pl.on, pl.rows
    cap = hist_id.shape[1]
    for ch in prange(N_CHUNKS):
        lo, hi = chunk_range(ch, 0, n)
        over = False
        for i in range(lo, hi):
            if role.shape[0] and (role[i] & need) != need:
                continue
            k = 0
            hn = hist_n[i]
            while k < hn and hist_id[i, k] < 0:
                k += 1
            for e in range(inc_off[i], inc_off[i + 1]):
                q = inc_k[e]
                if on[q]:
                    if k < cap:
                        hist_id[i, k] = gid[pair_a[q]]
                        pair_springs_to_history(hist_s, hist_m, i, k, rows[q])
                    else:
                        over = True
                    k += 1
            for q in range(half_off[i], half_off[i + 1]):
                if on[q]:
                    if k < cap:
                        hist_id[i, k] = gid[pair_b[q]]
                        pair_springs_to_history(hist_s, hist_m, i, k, rows[q])
                    else:
                        over = True
                    k += 1
            hist_n[i] = min(k, cap)
        if over:
            err[ERR_HIST_OVERFLOW] = 1
