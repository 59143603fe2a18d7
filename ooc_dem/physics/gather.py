"""Phase 2 of a step: each particle gathers its contact rows and is advanced (numba, no
I/O; written once, compiled per dimension by ``physics.step.instantiate``).

One pass per particle sums its rows in ascending partner-id order -- its body rows
(negative ids: lugs -1000 + k, rim -100, walls -5 .. -1), then its incoming pairs
(partners with lower ids, through the CSR index ``inc_off/inc_k`` of pair slots), then
its own half-list pairs -- with exactly the arithmetic of a particle computing its
contacts itself (the higher id adds the force on b and its torque term, the lower
subtracts the force and adds its own term), rewrites its body entries in its history
from the rows and advances the particle (leapfrog). No atomics, no scatter: every write
goes to the particle itself. What a row holds and how it adds to the sums is the
dimension's (its row layouts); the pass, the order and the integration are the same in
every dimension.
"""

import numpy as np
from numba import prange

from .axes import DIM, SPIN, vec
from .chunks import N_CHUNKS, chunk_range
from .layout import AX_X, ERR_HIST_OVERFLOW
from .twins import slot

# ------------------------------------------------ what each dimension binds (its rows)
no_force = slot("no_force(): a particle's sums at zero: D force components, then R torque components (a tuple)")
add_body_row = slot("add_body_row(sums, row): the sums plus a body row's force and torque")
add_pair_as_b = slot(
    "add_pair_as_b(sums, row, w, r): the sums plus a pair row weighted by w "
    "(its contact flag), the particle its b (the higher id) of lever arm r"
)
add_pair_as_a = slot("add_pair_as_a(sums, row, w, r): the same for the particle as a (the lower id)")
body_springs_to_history = slot(
    "body_springs_to_history(hist_s, hist_m, i, k, row): entry k of particle i's springs from a body row"
)


def advance(i, s, pos, vel, spin, mass, inertia, g, dt, ref, force, torque, keep):
    """Leapfrog of particle i from its sums s (no_force's layout) and gravity g (a tuple):
    v(n+1/2) = v(n-1/2) + a_n dt, x(n+1) = x_n + v(n+1/2) dt, spin += torque / inertia dt;
    the sums go to force / torque when keep. Returns its squared displacement from ref."""
    m = mass[i]
    inert = inertia[i]
    if keep:
        for a in range(DIM):
            force[i, a] = s[a]
        for a in range(SPIN):
            torque[i, a] = s[DIM + a]
    for a in range(DIM):
        vel[i, a] += (s[a] / m + g[a]) * dt
    for a in range(SPIN):
        spin[i, a] += s[DIM + a] / inert * dt
    for a in range(DIM):
        pos[i, a] += vel[i, a] * dt
    e = pos[i, AX_X] - ref[i, AX_X]
    dd = e * e
    for a in range(AX_X + 1, DIM):
        e = pos[i, a] - ref[i, a]
        dd += e * e
    return dd


def gather_integrate(first, end, d, pl, bd, force, torque, gravity, dt, part, err):
    """Phase 2: per particle of first..end-1 (the span ``produce`` just made rows for: the
    chunks of body rows are the same), sum its rows in ascending partner-id order (module
    doc), rewrite its body entries in its history from them, then advance it one leapfrog
    step. force (N, D) / torque (N, R) get the contact forces and torques of time n
    (unless they have length 0); gravity: the (D,) acceleration. Returns the largest
    squared displacement since the last neighbour build (a max: order-free); part is
    scratch of N_CHUNKS entries. The pairs' springs stay in the pair rows (written back
    by ``sync_history``); the history capacity is checked on the particle's full contact
    count (an overflow sets err[ERR_HIST_OVERFLOW]: fatal, never a silent drop)."""
    pos, vel, spin, r = d.pos, d.vel, d.spin, d.r
    mass, inertia = d.mass, d.inertia
    hist_n, hist_id, hist_s, hist_m = d.hist_n, d.hist_id, d.hist_s, d.hist_m
    half_off = pl.half_off
    inc_off, inc_k = pl.inc_off, pl.inc_k
    on, rows, ref = pl.on, pl.rows, pl.ref
    body, bcount = bd.rows, bd.count
    bcap = body.shape[0] // N_CHUNKS
    cap = hist_id.shape[1]
    keep = force.shape[0] >= end
    g = vec(gravity)
    for ch in prange(N_CHUNKS):
        lo, hi = chunk_range(ch, first, end)
        bat = ch * bcap
        bend = bat + bcount[ch]
        over = False
        mx = 0.0
        for i in range(lo, hi):
            ri = r[i]  # this particle's lever arm
            s = no_force()
            k = 0
            # walls and wheel parts (negative ids, already in ascending order)
            while bat < bend and body[bat].disc == i:
                brow = body[bat]
                if k < cap:
                    hist_id[i, k] = brow.pid
                    body_springs_to_history(hist_s, hist_m, i, k, brow)
                else:
                    over = True
                k += 1
                s = add_body_row(s, brow)
                bat += 1
            kb = k
            # Every candidate's row is summed, weighted by its contact flag (1.0 or 0.0):
            # about half the candidates touch, and a branch on the flag would be
            # mispredicted every other pair. The same bits as summing only the touching
            # ones: a row holds finite values (made from a finite state, or zeros), so a
            # row that does not touch adds +-0.0, and x +- 0.0 is x for every sum here
            # (each starts at +0.0, so none is ever -0.0).
            # partners with lower ids (i is b): the CSR index, ascending partner id
            for e in range(inc_off[i], inc_off[i + 1]):
                q = inc_k[e]
                touch = on[q]
                k += touch
                s = add_pair_as_b(s, rows[q], np.float64(touch), ri)
            # partners with higher ids (i is a): its own half list, ascending partner id
            for q in range(half_off[i], half_off[i + 1]):
                touch = on[q]
                k += touch
                s = add_pair_as_a(s, rows[q], np.float64(touch), ri)
            # between steps a particle's own history holds its body contacts only: its
            # pairs' springs stay in the pair rows until sync_history writes them back
            hist_n[i] = min(kb, cap)
            if k > cap:
                over = True
            dd = advance(i, s, pos, vel, spin, mass, inertia, g, dt, ref, force, torque, keep)
            if dd > mx:
                mx = dd
        part[ch] = mx
        if over:
            err[ERR_HIST_OVERFLOW] = 1
    return part.max()
