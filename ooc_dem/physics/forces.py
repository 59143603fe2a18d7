"""Contacts as data: each contact is evaluated once (numba, no I/O).

A step's forces come in two phases (Nishiura & Sakaguchi 2011, J. Comput. Phys.
230:1923: a pair list with a per-particle pair-index table, Newton's third law
without write conflicts):

1. ``produce`` writes one row per contact. Disc-disc pairs come from the HALF
   neighbour list (``neighbors.build_pairs``: each pair once, stored with its lower
   global id ``a``), so the law is evaluated once per pair in canonical orientation;
   the row (``layout.PAIR_ROW``) holds the force on b, both torque terms and the
   pair's new springs, in the pair's slot of the list. The touching pairs are listed
   in blocks (their law arguments as columns, ``layout.LawIn``) and ``law_block`` runs
   the law on a block in one vectorised loop (SIMD) whose per-pair arithmetic is that
   of a pair evaluated alone: the same bits. Walls and wheel parts
   (``layout.BODY_ROW``, one row per disc-body contact) go to per-chunk buffers in
   disc order. A producer only reads the time-n state and writes rows, so it can be
   rerun (e.g. after growing a buffer) without changing anything.
2. ``gather_integrate``: one pass per disc sums its rows in ascending partner-id
   order -- its body rows (negative ids: lugs -1000 + k, rim -100, right wall -3,
   left -2, bottom -1), then its incoming pairs (partners with lower ids, through
   the CSR index ``inc_off/inc_k`` of pair slots), then its own half-list pairs -- with exactly
   the arithmetic of a disc computing its contacts itself (the higher id adds the
   force and ``r_b ft + M``, the lower subtracts the force and adds ``r_a ft - M``),
   rewrites its history (sorted by partner id) from the rows and advances the disc
   (leapfrog). No atomics, no scatter: every write goes to the disc itself.

``wheel_reaction`` sums the wheel's body rows per disc, then over discs in ascending
id (docs/design.md §3).
"""
import math

import numpy as np
from numba import njit, prange

from .contact import contact
from .layout import (AX_X, AX_Y, ERR_BODY_CAPACITY, HM_R, HS_T, SP_Z, ERR_HIST_OVERFLOW, ERR_NBR_OVERFLOW,  # noqa: F401
                     LAW_BLOCK, LAW_ROW, N_LAW_IN, N_LAW_OUT, N_TYPES, LawIn, LawOut,
                     LawParams,
                     ERR_PAIR_CAPACITY, ID_LUG0, ID_RIM, ID_WALL_BOTTOM, ID_WALL_LEFT,
                     ID_WALL_RIGHT, T_WALL, T_WHEEL, WG_CAP, WG_ENABLED, WG_LUG_IN,
                     WG_LUG_OUT, WG_MASS, WG_NLUGS, WG_R, WG_SIZE, WS_SIZE, WS_THETA, WS_VX,
                     WS_VY, WS_WZ, WS_X, WS_Y)

# a disc's role in a serial-DDM sub-domain (bit flags; load_history / sync_history):
# owned in this sweep, owned in the last sweep too, copied in another sub-domain too
ROLE_OWNED, ROLE_OWNED_BEFORE, ROLE_SHARED = 1, 2, 4
ROLE_STABLE = ROLE_OWNED | ROLE_OWNED_BEFORE

# discs are produced and gathered in N_CHUNKS contiguous chunks (body rows are
# buffered per chunk, in disc order); the chunking never changes a result
N_CHUNKS = 64
# produce runs the chunks in groups, each with its own law-block columns: allocated once
# a group rather than once a chunk (a serial-DDM step makes them for every sub-domain:
# paper2008, D = 6, 20 000 steps took 7.7 s so against 9.8 s with one allocation a chunk)
CHUNKS_PER_GROUP = 4


@njit(inline="always", cache=True)
def chunk_range(c, first, end):
    """Chunk c of discs first..end-1 (N_CHUNKS contiguous pieces)."""
    size = (end - first + N_CHUNKS - 1) // N_CHUNKS
    lo = first + c * size
    hi = min(end, lo + size)
    return lo, max(lo, hi)


@njit(inline="always", cache=True)
def _lookup(hid, hs, hm, i, hn, p, pid):
    """Advance the merge pointer p in i's sorted history to partner pid."""
    while p < hn and hid[i, p] < pid:
        p += 1
    if p < hn and hid[i, p] == pid:
        return p, hs[i, p, HS_T], hm[i, p, HM_R]
    return p, 0.0, 0.0


def law_block(uniform):
    """The pair law (contact.contact) on pairs 0..k-1 of a block: what it needs of them is
    in the LawIn rows of law_in, their pair-row fields go to the LawOut rows of law_out.
    uniform: c0 is the CONTACT_PARAMS record of every pair of the block (one material
    pair), else each pair's parameters are in its LawIn columns (c0 is None).

    One loop with no call and no early exit, so the compiler evaluates several pairs per
    instruction (SIMD); each pair's arithmetic and its order are those of the pair evaluated
    alone (the contact geometry and effective quantities, then contact's law; numba sets no
    fast-math, so no operation is fused or reordered): its bits do not depend on the block."""

    def block(k, law_in, law_out, dt, c0):
        dx_, dy_, vrx_, vry_ = law_in[LawIn.dx], law_in[LawIn.dy], law_in[LawIn.vrx], law_in[LawIn.vry]
        wa_, wb_, ra_, rb_ = law_in[LawIn.wa], law_in[LawIn.wb], law_in[LawIn.ra], law_in[LawIn.rb]
        ma_, mb_, ia_, ib_ = law_in[LawIn.ma], law_in[LawIn.mb], law_in[LawIn.ia], law_in[LawIn.ib]
        s_old_, m_old_ = law_in[LawIn.s_old], law_in[LawIn.m_old]
        kn, ks, zn, zt = law_in[LawIn.kn], law_in[LawIn.ks], law_in[LawIn.zn], law_in[LawIn.zt]
        mu, mur, zr = law_in[LawIn.mu], law_in[LawIn.mur], law_in[LawIn.zr]
        bx_, by_, ta_, tb_ = law_out[LawOut.bx], law_out[LawOut.by], law_out[LawOut.ta], law_out[LawOut.tb]
        s_, m_ = law_out[LawOut.s], law_out[LawOut.m]
        for t in range(k):
            if uniform:   # a constant: one record for the block, or each pair's columns
                c = c0
            else:
                c = LawParams(kn[t], ks[t], zn[t], zt[t], mu[t], mur[t], zr[t])
            dx = dx_[t]
            dy = dy_[t]
            ra = ra_[t]
            rb = rb_[t]
            ma = ma_[t]
            mb = mb_[t]
            ia = ia_[t]
            ib = ib_[t]
            d2 = dx * dx + dy * dy
            rs = ra + rb
            dd = math.sqrt(d2)
            nx = dx / dd
            ny = dy / dd
            fn, ft, s_new, mom, m_new = contact(
                c, nx, ny, rs - dd, vrx_[t], vry_[t], wa_[t], wb_[t], ra, rb, ma * mb / (ma + mb),
                ia * ib / (ia + ib), ra * rb / (ra + rb), s_old_[t], m_old_[t], dt)
            bx_[t] = fn * nx + ft * ny
            by_[t] = fn * ny - ft * nx
            ta_[t] = ra * ft - mom
            tb_[t] = rb * ft + mom
            s_[t] = s_new
            m_[t] = m_new

    # error_model numpy: no division-by-zero test in the loop (it would stop the SIMD; the law
    # never divides by zero: the pairs touch (dd > 0), masses and inertias are positive)
    return njit(error_model="numpy", cache=True)(block)


law_block_one = law_block(True)      # one record for the block
law_block_each = law_block(False)    # each pair's parameters in its columns


@njit(inline="always", cache=True)
def law_rows(k, law_in, law_out, dt, cp, uniform):
    """The block law on a filled block of k pairs (LawIn columns up to the material pair):
    uniform (one material pair, in column 0): its record for the whole block; else each
    pair's parameters are copied into its columns first."""
    k = np.int64(k)   # never a literal: one compiled block law per signature
    if uniform:
        m0 = np.int64(law_in[LawIn.material, 0])
        law_block_one(k, law_in, law_out, dt, cp[m0 // N_TYPES, m0 % N_TYPES])
        return
    copy_pair_params(k, law_in, LawIn.material, LawIn.kn, cp)
    law_block_each(k, law_in, law_out, dt, None)


@njit(inline="always", cache=True)
def copy_pair_params(k, law_in, material_row, first_row, cp):
    """Each of a block's k pairs' parameters into its columns (2D and 3D): the record of its
    material pair (row material_row: type_a * n_types + type_b) of the contact table cp, field
    by field in the record's order from row first_row on."""
    # the table's records as float64 (all their fields are): row a holds records [a, b]
    # one after another
    n_types = cp.shape[1]
    fields = cp.view(np.float64)
    n_fields = fields.shape[1] // n_types
    for t in range(k):
        m = np.int64(law_in[material_row, t])
        a = m // n_types
        at = (m % n_types) * n_fields
        for f in range(n_fields):
            law_in[first_row + f, t] = fields[a, at + f]


@njit(inline="always", cache=True)
def _put_pair_rows(k, slot, law_out, rows, on):
    """The rows of a block's pairs (law_block's results) into their slots; they touch."""
    for t in range(k):
        q = slot[t]
        row = rows[q]
        row.bx = law_out[LawOut.bx, t]
        row.by = law_out[LawOut.by, t]
        row.ta = law_out[LawOut.ta, t]
        row.tb = law_out[LawOut.tb, t]
        row.s = law_out[LawOut.s, t]
        row.m = law_out[LawOut.m, t]
        on[q] = 1


@njit(inline="always", cache=True)
def _body_row(body, at, i, pid, bx, by, tq, s, m, wt):
    row = body[at]
    row.disc = i
    row.pid = pid
    row.bx = bx
    row.by = by
    row.tq = tq
    row.s = s
    row.m = m
    row.wt = wt


@njit(inline="always", cache=True)
def _wheel_row(body, bat, bend, i, pid, fn, ft, s, mom, m, nx, ny, qx, qy, ri):
    """Body row bat of a disc-wheel-part contact (normal n, force fn n - ft t on the disc,
    rolling moment mom): the disc's force and torque, the springs, and the torque on the
    wheel about its centre from the reaction at (qx, qy) off it. Returns (next row, full)."""
    bx = fn * nx + ft * ny
    by = fn * ny - ft * nx
    if bat < bend:
        _body_row(body, bat, i, pid, bx, by, ri * ft + mom, s, m, qx * (-by) - qy * (-bx) - mom)
        return bat + 1, False
    return bat, True


@njit(parallel=True, cache=True)
def produce(first, end, d, pl, bd, cp, walls, wg, ws, lugdir, dt, err, pairs_done):
    """Phase 1: one row per contact of discs first..end-1 at time n (see module doc): the
    rows of their walls and wheel parts, and of their own half lists (pairs whose lower id
    is one of them).

    d: layout Discs, pl: Pairs (half list + rows), bd: Bodies (per-chunk body rows),
    cp: CONTACT_PARAMS table [type_a, type_b], walls: WALLS, wg: WHEEL_GEOMETRY,
    ws: WHEEL_STATE (records of shape (1,)); lugdir: LUG_DIRECTION of each lug.
    Sets err[ERR_BODY_CAPACITY] when a chunk's body buffer is full (grow, rerun)."""
    pos, vel, spin, r = d.pos, d.vel, d.spin, d.r
    mass, inertia, mat = d.mass, d.inertia, d.mat
    hist_n, hist_id, hist_s, hist_m = d.hist_n, d.hist_id, d.hist_s, d.hist_m
    half_off, pair_b, on, rows = pl.half_off, pl.pair_b, pl.on, pl.rows
    body, bcount = bd.rows, bd.count
    bcap = body.shape[0] // N_CHUNKS
    wl = walls[0]
    length = wl.length
    has_left = wl.left > 0.5
    has_right = wl.right > 0.5
    has_bottom = wl.bottom > 0.5
    g = wg[0]
    wheel_on = g.enabled > 0.5
    R = g.radius
    lug_in = g.lug_in
    lug_out = g.lug_out
    cap_r = g.cap
    nlugs = int(g.nlugs)
    wmass = g.mass
    s0 = ws[0]
    X = s0.x
    Y = s0.y
    VX = s0.vx
    VY = s0.vy
    WZ = s0.wz
    reach = lug_out + cap_r
    if R > reach:
        reach = R
    for grp in prange(N_CHUNKS // CHUNKS_PER_GROUP):
        law_in = np.empty((N_LAW_IN, LAW_ROW))
        law_out = np.empty((N_LAW_OUT, LAW_ROW))
        slot = np.empty(LAW_BLOCK, np.int64)
        k = 0
        uniform = True   # the block's pairs so far have one material pair
        for ch in range(grp * CHUNKS_PER_GROUP, (grp + 1) * CHUNKS_PER_GROUP):
            lo, hi = chunk_range(ch, first, end)
            bat = ch * bcap
            bend = bat + bcap
            full = False
            for i in range(lo, hi):
                xi = pos[i, AX_X]
                yi = pos[i, AX_Y]
                vxi = vel[i, AX_X]
                vyi = vel[i, AX_Y]
                wi = spin[i, SP_Z]
                ri = r[i]
                mi = mass[i]
                ii = inertia[i]
                ti = mat[i]
                hn = hist_n[i]
                p = 0
                # ------------------------------------------------------ wheel
                if wheel_on:
                    dxw = xi - X
                    dyw = yi - Y
                    d2 = dxw * dxw + dyw * dyw
                    if d2 < (reach + ri) * (reach + ri):
                        meff = mi * wmass / (mi + wmass)
                        for lug in range(nlugs):
                            ux = lugdir[lug].ux
                            uy = lugdir[lug].uy
                            sproj = lug_axis_offset(dxw, dyw, ux, uy, lug_in, lug_out)
                            px = X + sproj * ux
                            py = Y + sproj * uy
                            ddx = xi - px
                            ddy = yi - py
                            dd = math.sqrt(ddx * ddx + ddy * ddy)
                            delta = cap_r + ri - dd
                            if delta > 0.0 and dd > 0.0:
                                pid = ID_LUG0 + lug
                                p, s_old, m_old = _lookup(hist_id, hist_s, hist_m, i, hn, p, pid)
                                nx = ddx / dd
                                ny = ddy / dd
                                # velocity of the lug point p: V + Wz x (p - C)
                                vax = VX - WZ * (py - Y)
                                vay = VY + WZ * (px - X)
                                fn, ft, s_new, mom, m_new = contact(
                                    cp[T_WHEEL, ti], nx, ny, delta, vxi - vax, vyi - vay, WZ, wi, cap_r,
                                    ri, meff, ii, ri, s_old, m_old, dt)
                                # reaction on the wheel at q = p + cap_r n, about the centre
                                bat, over = _wheel_row(body, bat, bend, i, pid, fn, ft, s_new, mom,
                                                       m_new, nx, ny, px + cap_r * nx - X,
                                                       py + cap_r * ny - Y, ri)
                                full = full or over
                        dw = math.sqrt(d2)
                        delta = R + ri - dw
                        if delta > 0.0 and dw > 0.0:
                            p, s_old, m_old = _lookup(hist_id, hist_s, hist_m, i, hn, p, ID_RIM)
                            nx = dxw / dw
                            ny = dyw / dw
                            fn, ft, s_new, mom, m_new = contact(
                                cp[T_WHEEL, ti], nx, ny, delta, vxi - VX, vyi - VY, WZ, wi, R, ri,
                                meff, ii, ri, s_old, m_old, dt)
                            bat, over = _wheel_row(body, bat, bend, i, ID_RIM, fn, ft, s_new, mom,
                                                   m_new, nx, ny, R * nx, R * ny, ri)
                            full = full or over
                # ------------------------------------------------------ walls
                # most discs touch no wall: test all three overlaps first (ri > t is exactly
                # the walls' own test ri - t > 0, so no contact is skipped or added)
                near_wall = ((has_right and ri > length - xi) or (has_left and ri > xi)
                             or (has_bottom and ri > yi))
                for wall in range(3 if near_wall else 0):
                    # ascending ids: right (-3), left (-2), bottom (-1)
                    if wall == 0:
                        if not has_right:
                            continue
                        delta = ri - (length - xi)
                        nx = -1.0
                        ny = 0.0
                        pid = ID_WALL_RIGHT
                    elif wall == 1:
                        if not has_left:
                            continue
                        delta = ri - xi
                        nx = 1.0
                        ny = 0.0
                        pid = ID_WALL_LEFT
                    else:
                        if not has_bottom:
                            continue
                        delta = ri - yi
                        nx = 0.0
                        ny = 1.0
                        pid = ID_WALL_BOTTOM
                    if delta > 0.0:
                        p, s_old, m_old = _lookup(hist_id, hist_s, hist_m, i, hn, p, pid)
                        fn, ft, s_new, mom, m_new = contact(
                            cp[T_WALL, ti], nx, ny, delta, vxi, vyi, 0.0, wi, 0.0, ri,
                            mi, ii, ri, s_old, m_old, dt)
                        if bat < bend:
                            _body_row(body, bat, i, pid, fn * nx + ft * ny, fn * ny - ft * nx,
                                      ri * ft + mom, s_new, m_new, 0.0)
                            bat += 1
                        else:
                            full = True
                # ------------------------------------------------------ pairs (i = a, lower id)
                if pairs_done:
                    continue   # a rerun after growing the body buffers: the pair rows are made
                # the touching pairs' law arguments are listed in a block; law_rows evaluates a
                # full block at once and puts its rows in place (the order of evaluation never
                # changes a row: each depends only on its own arguments)
                for q in range(half_off[i], half_off[i + 1]):
                    b = np.int64(pair_b[q])
                    dx = pos[b, AX_X] - xi
                    dy = pos[b, AX_Y] - yi
                    rb = r[b]
                    d2 = dx * dx + dy * dy
                    rs = ri + rb
                    if d2 >= rs * rs or d2 == 0.0:
                        # no contact: the pair's springs restart from zero (a row already
                        # off holds zero springs: load_history and this make it so; not
                        # rewriting it keeps its cache line clean)
                        if on[q]:
                            on[q] = 0
                            row = rows[q]
                            row.s = 0.0
                            row.m = 0.0
                        continue
                    # the pair's springs of the last step (its row is its contact history)
                    row = rows[q]
                    law_in[LawIn.s_old, k] = row.s
                    law_in[LawIn.m_old, k] = row.m
                    law_in[LawIn.dx, k] = dx
                    law_in[LawIn.dy, k] = dy
                    law_in[LawIn.vrx, k] = vel[b, AX_X] - vxi
                    law_in[LawIn.vry, k] = vel[b, AX_Y] - vyi
                    law_in[LawIn.wa, k] = wi
                    law_in[LawIn.wb, k] = spin[b, SP_Z]
                    law_in[LawIn.ra, k] = ri
                    law_in[LawIn.rb, k] = rb
                    law_in[LawIn.ma, k] = mi
                    law_in[LawIn.mb, k] = mass[b]
                    law_in[LawIn.ia, k] = ii
                    law_in[LawIn.ib, k] = inertia[b]
                    material = ti * N_TYPES + mat[b]
                    law_in[LawIn.material, k] = material
                    uniform = uniform and material == law_in[LawIn.material, 0]
                    slot[k] = q
                    k += 1
                    if k == LAW_BLOCK:
                        law_rows(k, law_in, law_out, dt, cp, uniform)
                        _put_pair_rows(k, slot, law_out, rows, on)
                        k = 0
                        uniform = True
            bcount[ch] = bat - ch * bcap
            if full:
                err[ERR_BODY_CAPACITY] = 1
        if k > 0:
              law_rows(k, law_in, law_out, dt, cp, uniform)
              _put_pair_rows(k, slot, law_out, rows, on)


@njit(inline="always", cache=True)
def one_material(k, law_in, material_row):
    """Whether a block's k pairs all have one material pair (row material_row of the
    block's columns: type_a * n_types + type_b); law_rows then takes its record once for
    the block (2D and 3D)."""
    m0 = law_in[material_row, 0]
    same = True
    for t in range(1, k):
        same = same & (law_in[material_row, t] == m0)
    return same


@njit(inline="always", cache=True)
def lug_axis_offset(dxw, dyw, ux, uy, lug_in, lug_out):
    """How far along a lug's direction (ux, uy) lies the point of its axis closest to a
    particle at (dxw, dyw) from the axle: the projection, clamped to the lug's extent
    lug_in..lug_out (2D and 3D produce)."""
    s = dxw * ux + dyw * uy
    if s < lug_in:
        s = lug_in
    elif s > lug_out:
        s = lug_out
    return s


@njit(inline="always", cache=True)
def _keep(hist_id, hist_s, hist_m, i, k, cap, pid, s, m):
    """Write history entry k of disc i; returns False on overflow."""
    if k >= cap:
        return False
    hist_id[i, k] = pid
    hist_s[i, k, HS_T] = s
    hist_m[i, k, HM_R] = m
    return True


@njit(parallel=True, cache=True)
def gather_integrate(first, end, d, pl, bd, force, torque, gravity, dt, part, err):
    """Phase 2: per disc of first..end-1 (the span ``produce`` just made rows for: the
    chunks of body rows are the same), sum its rows in ascending partner-id order (module doc),
    rewrite its history from them, then advance it one leapfrog step:
    v_(n+1/2) = v_(n-1/2) + a_n dt, x_(n+1) = x_n + v_(n+1/2) dt.
    force (N, D) / torque (N, R) get the contact forces and torques of time n (unless they
    have length 0); gravity: the (D,) acceleration.
    Returns the largest squared
    displacement since the last neighbour build (a max: order-free); part is scratch
    of N_CHUNKS entries."""
    pos, vel, spin = d.pos, d.vel, d.spin
    mass, inertia = d.mass, d.inertia
    hist_n, hist_id, hist_s, hist_m = d.hist_n, d.hist_id, d.hist_s, d.hist_m
    half_off = pl.half_off
    inc_off, inc_k = pl.inc_off, pl.inc_k
    on, rows, ref = pl.on, pl.rows, pl.ref
    gx = gravity[AX_X]
    gy = gravity[AX_Y]
    body, bcount = bd.rows, bd.count
    bcap = body.shape[0] // N_CHUNKS
    cap = hist_id.shape[1]
    keep = force.shape[0] >= end
    for ch in prange(N_CHUNKS):
        lo, hi = chunk_range(ch, first, end)
        bat = ch * bcap
        bend = bat + bcount[ch]
        over = False
        mx = 0.0
        for i in range(lo, hi):
            sfx = 0.0
            sfy = 0.0
            stq = 0.0
            k = 0
            # walls and wheel parts (negative ids, already in ascending order)
            while bat < bend and body[bat].disc == i:
                brow = body[bat]
                if not _keep(hist_id, hist_s, hist_m, i, k, cap, brow.pid, brow.s, brow.m):
                    over = True
                k += 1
                sfx += brow.bx
                sfy += brow.by
                stq += brow.tq
                bat += 1
            kb = k
            # Every candidate's row is summed, weighted by its contact flag (1.0 or 0.0): no
            # branch on the flag, which is mispredicted whenever candidates that do not
            # touch are common. The same bits as summing only the touching ones: a row
            # holds finite values (made from a finite state, or zeros), so a row that does
            # not touch adds +-0.0, and x +- 0.0 is x for every sum here (each starts at
            # +0.0, so none is ever -0.0).
            # partners with lower ids (i is b): the CSR index, ascending partner id
            for e in range(inc_off[i], inc_off[i + 1]):
                q = inc_k[e]
                row = rows[q]
                k += on[q]
                w = np.float64(on[q])
                sfx += row.bx * w
                sfy += row.by * w
                stq += row.tb * w
            # partners with higher ids (i is a): i's own half list, ascending partner id
            for q in range(half_off[i], half_off[i + 1]):
                row = rows[q]
                k += on[q]
                w = np.float64(on[q])
                sfx -= row.bx * w
                sfy -= row.by * w
                stq += row.ta * w
            # between steps a disc's own history holds its body contacts only: its pairs'
            # springs stay in the pair rows until sync_history writes them back
            hist_n[i] = kb
            if k > cap:
                over = True
            if keep:
                force[i, AX_X] = sfx
                force[i, AX_Y] = sfy
                torque[i, SP_Z] = stq
            vel[i, AX_X] += (sfx / mass[i] + gx) * dt
            vel[i, AX_Y] += (sfy / mass[i] + gy) * dt
            spin[i, SP_Z] += stq / inertia[i] * dt
            pos[i, AX_X] += vel[i, AX_X] * dt
            pos[i, AX_Y] += vel[i, AX_Y] * dt
            ddx = pos[i, AX_X] - ref[i, AX_X]
            ddy = pos[i, AX_Y] - ref[i, AX_Y]
            dd = ddx * ddx + ddy * ddy
            if dd > mx:
                mx = dd
        part[ch] = mx
        if over:
            err[ERR_HIST_OVERFLOW] = 1
    return part.max()


@njit(cache=True)
def lug_directions(theta, nlugs, lugdir):
    """Unit vectors of the lugs at wheel angle theta (lug k at theta + 2 pi k / n);
    lugdir: LUG_DIRECTION records."""
    for k in range(nlugs):
        phi = theta + 2.0 * math.pi * k / nlugs
        lugdir[k].ux = math.cos(phi)
        lugdir[k].uy = math.sin(phi)


@njit(cache=True)
def wheel_reaction(gid, bd):
    """Soil force and torque on the wheel: each disc's wheel rows summed in its row
    order (lugs, then rim), then the discs in ascending id (canonical). Returns
    (fx, fy, torque, number of discs touching the wheel)."""
    body, bcount = bd.rows, bd.count
    bcap = body.shape[0] // N_CHUNKS
    total = 0
    for ch in range(N_CHUNKS):
        total += bcount[ch]
    keys = np.empty(total, np.int64)
    sx = np.empty(total)
    sy = np.empty(total)
    st = np.empty(total)
    cnt = 0
    for ch in range(N_CHUNKS):
        at = ch * bcap
        end = at + bcount[ch]
        while at < end:
            i = body[at].disc
            if body[at].pid > ID_RIM:   # a wall: no wheel rows for this disc
                at += 1
                continue
            wfx_i = 0.0
            wfy_i = 0.0
            wtq_i = 0.0
            while at < end and body[at].disc == i and body[at].pid <= ID_RIM:
                wfx_i -= body[at].bx
                wfy_i -= body[at].by
                wtq_i += body[at].wt
                at += 1
            keys[cnt] = gid[i]
            sx[cnt] = wfx_i
            sy[cnt] = wfy_i
            st[cnt] = wtq_i
            cnt += 1
    if cnt == 0:
        return 0.0, 0.0, 0.0, 0
    order = np.argsort(keys[:cnt], kind="mergesort")
    fxs = 0.0
    fys = 0.0
    tqs = 0.0
    for o in range(cnt):
        k = order[o]
        fxs += sx[k]
        fys += sy[k]
        tqs += st[k]
    return fxs, fys, tqs, cnt


@njit(parallel=True, cache=True)
def sync_history(n, d, pl, err, role, need):
    """Each disc's full contact history, sorted by partner id, from its body entries
    (kept in place by the gather) and its pairs' springs in the pair rows: partners with
    lower ids through the CSR index, then its own half list. Run at the end of every
    advance and before a neighbour rebuild, so the discs always leave a stepper whole.
    role (length n, or 0 = every disc): only discs with all bits of ``need`` in their
    role are written (serial DDM). Idempotent: a disc's history restarts from its body
    entries (negative ids, first)."""
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
                    if not _keep(hist_id, hist_s, hist_m, i, k, cap, gid[pair_a[q]], rows[q].s,
                                 rows[q].m):
                        over = True
                    k += 1
            for q in range(half_off[i], half_off[i + 1]):
                if on[q]:
                    if not _keep(hist_id, hist_s, hist_m, i, k, cap, gid[pair_b[q]], rows[q].s,
                                 rows[q].m):
                        over = True
                    k += 1
            hist_n[i] = min(k, cap)
        if over:
            err[ERR_HIST_OVERFLOW] = 1


@njit(inline="always", cache=True)
def keeps_every_row(role, n):
    """Whether load_history keeps every pair row of particles 0..n-1 (2D and 3D): roles are
    given and every particle is ROLE_STABLE (serial DDM's one-step sweeps)."""
    if role.shape[0] == 0:
        return False
    for i in range(n):
        if (role[i] & ROLE_STABLE) != ROLE_STABLE:
            return False
    return True


@njit(parallel=True, cache=True)
def load_history(n, d, pl, role):
    """The pair rows' springs from the lower disc's history: after a neighbour build, and
    at the start of every advance (the discs' histories may have been set from outside,
    e.g. a serial-DDM halo refresh or a resumed epoch). role (length n, or 0 = reload every
    row): a pair whose two discs are both ROLE_STABLE keeps its row (serial DDM: both were
    owned through the last sweep, so the row was made from their true states)."""
    gid = d.gid
    hist_n, hist_id, hist_s, hist_m = d.hist_n, d.hist_id, d.hist_s, d.hist_m
    half_off, pair_b, on, rows = pl.half_off, pl.pair_b, pl.on, pl.rows
    if keeps_every_row(role, n):
        # nothing is loaded; a disc's own history may then still hold its pairs' springs
        # behind its body entries until the gather rewrites hist_n: produce only looks up
        # body entries (negative ids, sorted first), so they change nothing
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
                pid = gid[pair_b[q]]
                p, s_old, m_old = _lookup(hist_id, hist_s, hist_m, i, hn, p, pid)
                rows[q].s = s_old
                rows[q].m = m_old
                # in contact at the last step: a sync before the next step (a rebuild on
                # the last step of a call) then writes back exactly the history loaded
                on[q] = 1 if p < hn and hist_id[i, p] == pid else 0
            # from here to sync_history the disc's own history holds only its body
            # contacts (negative ids, sorted first); its pairs are in the rows
            kb = 0
            while kb < hn and hist_id[i, kb] < 0:
                kb += 1
            hist_n[i] = kb


# serial twins (physics.twins): one sub-domain's step on one thread
from .twins import serial_twin  # noqa: E402

produce_serial = serial_twin(produce, "produce_serial")
gather_integrate_serial = serial_twin(gather_integrate, "gather_integrate_serial")
sync_history_serial = serial_twin(sync_history, "sync_history_serial")
load_history_serial = serial_twin(load_history, "load_history_serial")
