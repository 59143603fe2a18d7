"""Contacts as data for spheres: each contact is evaluated once (numba, no I/O).

The 3D twin of ``ooc_dem.physics.forces`` (read its module doc). Two phases:

1. ``produce`` writes one row per contact at time n: sphere-sphere pairs from the
   HALF list (each pair once, canonical orientation: a = lower global id), one
   pair row in the pair's slot (``layout.pair_row_layout``: force on b, n x Ft, the
   rolling moment and the new springs); walls (``layout.BODY_ROW``) go to per-chunk buffers in sphere order,
   walls in ascending id (-5 .. -1). The wall rows are made first; when a buffer is
   full no pair row is made, so the step can be rerun after growing it. The touching
   pairs are not evaluated one by one: each chunk lists them in blocks (what the law
   needs of each pair, as columns: ``layout.LawIn``) and ``law_block`` runs the law on a
   block in one vectorised loop (SIMD), whose per-pair arithmetic is that of a pair
   evaluated alone, so the bits are the same.
2. ``gather_integrate``: one pass per sphere sums its rows in ascending partner-id
   order -- its wall rows, then its incoming pairs (lower-id partners, CSR index),
   then its own half-list pairs (the higher id adds the force and tb, the lower
   subtracts the force and adds ta) -- rewrites its wall entries in its history (the
   pairs' springs are held in the rows while a run goes on, as in 2D: ``load_history`` /
   ``sync_history`` move them between the spheres' histories and the rows around a run
   and a neighbour rebuild) and advances it (leapfrog:
   v(n+1/2) = v(n-1/2) + a_n dt, x(n+1) = x_n + v(n+1/2) dt, spin += torque / inertia dt). Every write goes to the sphere itself: no atomics.
"""
import math

import numpy as np
from numba import njit, prange, types
from numba.extending import overload

from ..forces import (ROLE_STABLE, copy_pair_params, keeps_every_row, lug_axis_offset,
                      one_material)
from .contact import contact
from .layout import (
    N_LAW_IN,
    N_LAW_OUT,
    LawIn,
    LawOut,
    LAW_HERTZ,
    LAW_LINEAR,
    N_TYPES,
    LawParams,
    ERR_BODY_CAPACITY,
    ERR_HIST_OVERFLOW,
    ID_WALL_BACK,
    ID_WALL_BOTTOM,
    ID_WALL_FRONT,
    ID_WALL_LEFT,
    ID_WALL_RIGHT,
    ID_LUG0,
    ID_RIM,
    T_WALL,
    T_WHEEL,
)

# a wall's or the wheel's contact: a few a step, so one compiled call instead of a copy of
# the law inlined at each of produce's three sites (a smaller produce compiles faster);
# the same arithmetic, so the same bits
# (contact is a plain function under NUMBA_DISABLE_JIT)
body_contact = njit(cache=True)(getattr(contact, "py_func", contact))

# spheres are produced and gathered in N_CHUNKS contiguous chunks (wall rows are
# buffered per chunk); the chunking never changes a result
N_CHUNKS = 64
# touching pairs per law block (law_block): a thread's block columns (~50 rows of LAW_ROW
# doubles, ~110 KB) stay in its core's L2; 128 measured no different at 100k
LAW_BLOCK = 256
# the block arrays' rows are padded by a cache line: with rows 2 KiB apart a pair's ~50
# fields would all fall in two sets of the L1 cache and evict each other
LAW_ROW = LAW_BLOCK + 8


# ---------------------------------------------------------- the row's rolling parts
# PAIR_ROW_ROLLING carries the rolling moment and spring, PAIR_ROW_SLIDING does not (its
# contact table has no rolling resistance, so both are exactly zero): these helpers are
# resolved at compile time from the row's record type, so one kernel source serves both
# layouts and the sliding one neither stores nor loads the zeros.
def has_rolling(row):
    """True when the pair-row record (or array of them) carries the rolling parts (compile-time)."""


def put_rolling(row, mox, moy, moz, mnx, mny, mnz):
    """Store the rolling moment and new rolling spring in the row (if it has them)."""


def rolling_of(row):
    """(mox, moy, moz, mx, my, mz) of the row: zeros when it has no rolling parts."""


def _rolling_type(row):
    """Whether a pair-row record type (or an array of them) has the rolling fields."""
    rec = row.dtype if isinstance(row, types.Array) else row
    return any(name == "mox" for name, _ in rec.members)


@overload(has_rolling, inline="always")
def _has_rolling(row):
    flag = _rolling_type(row)
    return lambda row: flag


@overload(put_rolling, inline="always")
def _put_rolling(row, mox, moy, moz, mnx, mny, mnz):
    if _rolling_type(row):
        def impl(row, mox, moy, moz, mnx, mny, mnz):
            row.mox = mox
            row.moy = moy
            row.moz = moz
            row.mx = mnx
            row.my = mny
            row.mz = mnz
        return impl
    return lambda row, mox, moy, moz, mnx, mny, mnz: None


@overload(rolling_of, inline="always")
def _rolling_of(row):
    if _rolling_type(row):
        return lambda row: (row.mox, row.moy, row.moz, row.mx, row.my, row.mz)
    return lambda row: (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit(inline="always", cache=True)
def chunk_range(c, first, end):
    """Chunk c of spheres first..end-1 (N_CHUNKS contiguous pieces)."""
    size = (end - first + N_CHUNKS - 1) // N_CHUNKS
    lo = first + c * size
    hi = min(end, lo + size)
    return lo, max(lo, hi)


@njit(inline="always", cache=True)
def _lookup(hid, i, hn, p, pid):
    """Advance the merge pointer p in i's sorted history to partner pid; returns
    (p, found)."""
    while p < hn and hid[i, p] < pid:
        p += 1
    return p, (p < hn and hid[i, p] == pid)


@njit(inline="always", cache=True)
def _body_springs(hist_id, hist_s, hist_m, i, hn, p, pid):
    """Sphere i's springs with body pid (a wall or a wheel part) from its history (zero for a
    new contact); returns (p, sx, sy, sz, mx, my, mz), p the advanced merge pointer."""
    p, found = _lookup(hist_id, i, hn, p, pid)
    if found:
        return (p, hist_s[i, p, 0], hist_s[i, p, 1], hist_s[i, p, 2], hist_m[i, p, 0],
                hist_m[i, p, 1], hist_m[i, p, 2])
    return p, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


@njit(inline="always", cache=True)
def _wall(wall):
    """(pid, nx, ny, nz) of wall k = 0..4 in ascending id order (the normal points into
    the box): back z=width, front z=0, right x=length, left x=0, bottom y=0."""
    if wall == 0:
        return ID_WALL_BACK, 0.0, 0.0, -1.0
    elif wall == 1:
        return ID_WALL_FRONT, 0.0, 0.0, 1.0
    elif wall == 2:
        return ID_WALL_RIGHT, -1.0, 0.0, 0.0
    elif wall == 3:
        return ID_WALL_LEFT, 1.0, 0.0, 0.0
    return ID_WALL_BOTTOM, 0.0, 1.0, 0.0


@njit(inline="always", cache=True)
def _body_row(body, bat, i, pid, fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny,
              mnz, nx, ny, nz, ri):
    """Body row of a sphere's wall or wheel contact: force and torque on the sphere, its
    new springs, no wheel torque."""
    row = body[bat]
    row.disc = i
    row.pid = pid
    bx = fn * nx - ftx
    by = fn * ny - fty
    row.bx = bx
    row.by = by
    row.bz = fn * nz - ftz
    row.tx = ri * (ny * ftz - nz * fty) + mox
    row.ty = ri * (nz * ftx - nx * ftz) + moy
    row.tz = ri * (nx * fty - ny * ftx) + moz
    row.sx = snx
    row.sy = sny
    row.sz = snz
    row.mx = mnx
    row.my = mny
    row.mz = mnz
    row.wt = 0.0


@njit(inline="always", cache=True)
def _wheel_row(body, bat, i, pid, fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny,
               mnz, nx, ny, nz, ri, qx, qy):
    """Body row of a sphere-wheel-part contact (``_body_row``) with the torque on the wheel
    about its axle from the reaction at q (relative to the axle point (X, Y)) minus the
    rolling moment's z part."""
    _body_row(body, bat, i, pid, fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny,
              mnz, nx, ny, nz, ri)
    row = body[bat]
    row.wt = qx * (-row.by) - qy * (-row.bx) - moz


@njit(inline="always", cache=True)
def _wheel_contact(body, bat, bend, i, pid, hist_id, hist_s, hist_m, hn, p, cpw, nx, ny, nz,
                   delta, qx, qy, VX, VY, WZ, vxi, vyi, vzi, wxi, wyi, wzi, ri, meff, ii, dt):
    """Sphere i's contact with wheel part pid (a lug or the rim) at normal n, overlap delta
    and contact point q (relative to the axle point): its springs from the history (p: the
    history cursor), the law, and its body row at bat when bat < bend. Returns (p, the rows
    written: 1, or 0 when the buffer is full)."""
    p, s0x, s0y, s0z, m0x, m0y, m0z = _body_springs(hist_id, hist_s, hist_m, i, hn, p, pid)
    (fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz) = body_contact(
        cpw, nx, ny, nz, delta, vxi - (VX - WZ * qy), vyi - (VY + WZ * qx), vzi, 0.0, 0.0, WZ,
        wxi, wyi, wzi, 0.0, ri, meff, ii, ri, s0x, s0y, s0z, m0x, m0y, m0z, dt)
    if bat < bend:
        _wheel_row(body, bat, i, pid, fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny,
                   mnz, nx, ny, nz, ri, qx, qy)
        return p, 1
    return p, 0


LAW_MIXED = -1   # law_block's law when a block's pairs do not all have one law


def law_block(fixed, uniform):
    """The block law compiled for one law and one source of the parameters: the pair law
    (contact.contact) on pairs 0..k-1 of a block: what it needs of them is in the LawIn
    rows of law_in, their pair-row fields go to the LawOut rows of law_out (force on b,
    n x Ft, new springs, and the rolling parts when the layout of rows has them).
    fixed: LAW_LINEAR or LAW_HERTZ when every pair of the block has that law (the other
    law's arithmetic is compiled out), else LAW_MIXED; uniform: c0 is the CONTACT_PARAMS
    record of every pair of the block (one material pair), else each pair's parameters
    are in its LawIn columns (c0 is None).

    One loop with no call and no early exit, so the compiler evaluates several pairs per
    instruction (SIMD); each pair's arithmetic and its order are those of a pair evaluated
    alone (the contact geometry and effective quantities as produce computed them, then
    contact's law; no fused or reordered operation), so its bits do not depend on the block.
    Each variant is one dispatcher, compiled once per signature and cached (an @overload's
    implementation is compiled again for each typing context of its caller)."""

    def block(k, law_in, law_out, dt, rows, c0):
        rolling = has_rolling(rows)
        dx_, dy_, dz_ = law_in[LawIn.dx], law_in[LawIn.dy], law_in[LawIn.dz]
        vrx_, vry_, vrz_ = law_in[LawIn.vrx], law_in[LawIn.vry], law_in[LawIn.vrz]
        wax_, way_, waz_ = law_in[LawIn.wax], law_in[LawIn.way], law_in[LawIn.waz]
        wbx_, wby_, wbz_ = law_in[LawIn.wbx], law_in[LawIn.wby], law_in[LawIn.wbz]
        ra_, rb_ = law_in[LawIn.ra], law_in[LawIn.rb]
        ma_, mb_, ia_, ib_ = law_in[LawIn.ma], law_in[LawIn.mb], law_in[LawIn.ia], law_in[LawIn.ib]
        s_x_, s_y_, s_z_ = law_in[LawIn.s_x], law_in[LawIn.s_y], law_in[LawIn.s_z]
        m_x_, m_y_, m_z_ = law_in[LawIn.m_x], law_in[LawIn.m_y], law_in[LawIn.m_z]
        bx, by, bz = law_out[LawOut.bx], law_out[LawOut.by], law_out[LawOut.bz]
        cx, cy, cz = law_out[LawOut.cx], law_out[LawOut.cy], law_out[LawOut.cz]
        mox_, moy_, moz_ = law_out[LawOut.mox], law_out[LawOut.moy], law_out[LawOut.moz]
        sx_, sy_, sz_ = law_out[LawOut.sx], law_out[LawOut.sy], law_out[LawOut.sz]
        mx_, my_, mz_ = law_out[LawOut.mx], law_out[LawOut.my], law_out[LawOut.mz]
        law_, kn, ks = law_in[LawIn.law], law_in[LawIn.kn], law_in[LawIn.ks]
        zn, zt, mu, mur = law_in[LawIn.zn], law_in[LawIn.zt], law_in[LawIn.mu], law_in[LawIn.mur]
        zr, estar, gstar = law_in[LawIn.zr], law_in[LawIn.estar], law_in[LawIn.gstar]
        beta, no_tension = law_in[LawIn.beta], law_in[LawIn.no_tension]
        for t in range(k):
            if uniform:   # a constant: one record for the block, or each pair's columns
                c = LawParams(c0.law if fixed == LAW_MIXED else fixed, c0.kn, c0.ks, c0.zn,
                              c0.zt, c0.mu, c0.mur, c0.zr, c0.estar, c0.gstar, c0.beta,
                              c0.no_tension)
            else:
                c = LawParams(law_[t] if fixed == LAW_MIXED else fixed, kn[t], ks[t], zn[t],
                              zt[t], mu[t], mur[t], zr[t], estar[t], gstar[t], beta[t],
                              no_tension[t])
            # the contact geometry and effective quantities (produce's distance test made d2)
            dx = dx_[t]
            dy = dy_[t]
            dz = dz_[t]
            ra = ra_[t]
            rb = rb_[t]
            ma = ma_[t]
            mb = mb_[t]
            ia = ia_[t]
            ib = ib_[t]
            d2 = dx * dx + dy * dy + dz * dz
            rs = ra + rb
            dd = math.sqrt(d2)
            nx = dx / dd
            ny = dy / dd
            nz = dz / dd
            (fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz) = contact(
                c, nx, ny, nz, rs - dd, vrx_[t], vry_[t], vrz_[t], wax_[t], way_[t], waz_[t],
                wbx_[t], wby_[t], wbz_[t], ra, rb, ma * mb / (ma + mb), ia * ib / (ia + ib),
                ra * rb / (ra + rb), s_x_[t], s_y_[t], s_z_[t], m_x_[t], m_y_[t], m_z_[t], dt)
            bx[t] = fn * nx - ftx
            by[t] = fn * ny - fty
            bz[t] = fn * nz - ftz
            cx[t] = ny * ftz - nz * fty
            cy[t] = nz * ftx - nx * ftz
            cz[t] = nx * fty - ny * ftx
            sx_[t] = snx
            sy_[t] = sny
            sz_[t] = snz
            if rolling:   # a constant: without rolling parts the rolling law is compiled out
                mox_[t] = mox
                moy_[t] = moy
                moz_[t] = moz
                mx_[t] = mnx
                my_[t] = mny
                mz_[t] = mnz

    # error_model numpy: no division-by-zero test in the loop (it would stop the SIMD; the law
    # never divides by zero: the pairs touch (dd > 0), its other divisors are tested first,
    # masses and inertias are positive)
    return njit(error_model="numpy", cache=True)(block)


law_block_linear = law_block(LAW_LINEAR, False)
law_block_hertz = law_block(LAW_HERTZ, False)
law_block_mixed = law_block(LAW_MIXED, False)
law_block_linear_one = law_block(LAW_LINEAR, True)   # one record for the block
law_block_hertz_one = law_block(LAW_HERTZ, True)


@njit(inline="always", cache=True)
def law_rows(k, law_in, law_out, dt, rows, cp, uniform):
    """The block law on a filled block of k pairs (LawIn columns up to the material pair):
    uniform (one material pair, in column 0): its record for the whole block; else each
    pair's parameters are copied into its columns first. Either way the block's one law
    is compiled alone when it has one."""
    k = np.int64(k)   # never a literal: one compiled block law per signature
    if uniform:
        m0 = np.int64(law_in[LawIn.material, 0])
        c0 = cp[m0 // N_TYPES, m0 % N_TYPES]
        if c0.law == LAW_HERTZ:   # as contact.contact decides: any other law is linear
            law_block_hertz_one(k, law_in, law_out, dt, rows, c0)
        else:
            law_block_linear_one(k, law_in, law_out, dt, rows, c0)
        return
    # LawIn has the record's fields in their order from LawIn.law on
    copy_pair_params(k, law_in, LawIn.material, LawIn.law, cp)
    laws = 0   # the laws of the block's pairs, a bit set (1 << law)
    for t in range(k):
        laws |= 1 << np.int64(law_in[LawIn.law, t])
    if laws == 1 << LAW_LINEAR:
        law_block_linear(k, law_in, law_out, dt, rows, None)
    elif laws == 1 << LAW_HERTZ:
        law_block_hertz(k, law_in, law_out, dt, rows, None)
    else:
        law_block_mixed(k, law_in, law_out, dt, rows, None)


@njit(inline="always", cache=True)
def _put_pair_rows(k, slot, law_out, rows):
    """The rows of a block's pairs (law_block's results) into their slots."""
    for t in range(k):
        q = slot[t]
        row = rows[q]
        row.bx = law_out[LawOut.bx, t]
        row.by = law_out[LawOut.by, t]
        row.bz = law_out[LawOut.bz, t]
        row.cx = law_out[LawOut.cx, t]
        row.cy = law_out[LawOut.cy, t]
        row.cz = law_out[LawOut.cz, t]
        row.sx = law_out[LawOut.sx, t]
        row.sy = law_out[LawOut.sy, t]
        row.sz = law_out[LawOut.sz, t]
        put_rolling(row, law_out[LawOut.mox, t], law_out[LawOut.moy, t], law_out[LawOut.moz, t],
                    law_out[LawOut.mx, t], law_out[LawOut.my, t], law_out[LawOut.mz, t])


@njit(parallel=True, cache=True)
def produce(first, end, d, pl, bd, cp, walls, wg, ws, lugdir, dt, err):
    """Phase 1: one row per contact of spheres first..end-1 at time n (module doc): their
    wall and wheel rows and the rows of their own half lists.

    d: layout.Discs, pl: layout.Pairs, bd: layout.Bodies, cp: CONTACT_PARAMS table
    [type_a, type_b], walls: WALLS record (1,); wg / ws: WHEEL_GEOMETRY / WHEEL_STATE
    records (1,), lugdir: LUG_DIRECTION of each lug at the wheel's angle. The wheel (when
    wg.enabled): a rim cylinder of radius wg.radius about the axle (X, Y) along z, spanning
    z0 -+ width/2 (its end faces included: the closest point on the solid cylinder), and
    nlugs plates: the points within wg.cap of the rectangle X + s u (s in lug_in..lug_out)
    times that z span; each sphere's wheel rows (lugs ascending, then the rim) come before
    its wall rows (ascending ids). The wheel's contact point q moves with V + W x (q - C),
    W = (0, 0, wz); the law sees the wheel as body a with lever arm 0 and spin W.
    Sets err[ERR_BODY_CAPACITY] when a
    chunk's wall buffer is full (grow, rerun): the wall rows are made first, in a pass of
    their own, and then no pair row is made, so a rerun gives the same rows. The pairs'
    springs are held in the pair rows (``load_history``: a pair was in contact at the last
    step iff on[q], its springs are the row's; each row is read and rewritten in place)."""
    pos, vel, spin, r = d.pos, d.vel, d.spin, d.r
    mass, inertia, mat = d.mass, d.inertia, d.mat
    hist_n, hist_id, hist_s, hist_m = d.hist_n, d.hist_id, d.hist_s, d.hist_m
    half_off, pair_a, pair_b, on, rows = pl.half_off, pl.pair_a, pl.pair_b, pl.on, pl.rows
    body, bcount = bd.rows, bd.count
    bcap = body.shape[0] // N_CHUNKS
    wl = walls[0]
    length = wl.length
    width = wl.width
    any_full = np.zeros(1, np.bool_)
    flags = np.array([wl.back > 0.5, wl.front > 0.5, wl.right > 0.5, wl.left > 0.5,
                      wl.bottom > 0.5])
    g = wg[0]
    wheel_on = g.enabled > 0.5
    R = g.radius
    lug_in = g.lug_in
    lug_out = g.lug_out
    cap_r = g.cap
    nlugs = int(g.nlugs)
    wmass = g.mass
    zlo = g.z0 - 0.5 * g.width
    zhi = g.z0 + 0.5 * g.width
    w0 = ws[0]
    X = w0.x
    Y = w0.y
    VX = w0.vx
    VY = w0.vy
    WZ = w0.wz
    reach = lug_out + cap_r
    if R > reach:
        reach = R
    for ch in prange(N_CHUNKS):
        lo, hi = chunk_range(ch, first, end)
        bat = ch * bcap
        bend = bat + bcap
        full = False
        for i in range(lo, hi):
            xi = pos[i, 0]
            yi = pos[i, 1]
            zi = pos[i, 2]
            ri = r[i]
            # most spheres touch neither a wall nor the wheel: test that on the position
            # first (ri > t is exactly a wall's own test ri - t > 0, and the wheel's test
            # is the one below, so no contact is skipped or added)
            near_wall = ((flags[0] and ri > width - zi) or (flags[1] and ri > zi)
                         or (flags[2] and ri > length - xi) or (flags[3] and ri > xi)
                         or (flags[4] and ri > yi))
            dxw = xi - X
            dyw = yi - Y
            d2 = dxw * dxw + dyw * dyw
            zm = cap_r + ri
            near_wheel = (wheel_on and d2 < (reach + ri) * (reach + ri) and zi > zlo - zm
                          and zi < zhi + zm)
            if not (near_wall or near_wheel):
                continue
            vxi = vel[i, 0]
            vyi = vel[i, 1]
            vzi = vel[i, 2]
            wxi = spin[i, 0]
            wyi = spin[i, 1]
            wzi = spin[i, 2]
            mi = mass[i]
            ii = inertia[i]
            ti = mat[i]
            hn = hist_n[i]
            p = 0
            # ------------------------------------------------------ wheel
            if near_wheel:
                meff = mi * wmass / (mi + wmass)
                zc = min(max(zi, zlo), zhi)
                for lug in range(nlugs):
                    ux = lugdir[lug].ux
                    uy = lugdir[lug].uy
                    sproj = lug_axis_offset(dxw, dyw, ux, uy, lug_in, lug_out)
                    px = sproj * ux        # the lug's closest axis point, relative to C
                    py = sproj * uy
                    ddx = dxw - px
                    ddy = dyw - py
                    ddz = zi - zc
                    dd = math.sqrt(ddx * ddx + ddy * ddy + ddz * ddz)
                    delta = cap_r + ri - dd
                    if delta > 0.0 and dd > 0.0:
                        nx = ddx / dd
                        ny = ddy / dd
                        nz = ddz / dd
                        p, wrote = _wheel_contact(
                            body, bat, bend, i, ID_LUG0 + lug, hist_id, hist_s, hist_m, hn, p,
                            cp[T_WHEEL, ti], nx, ny, nz, delta, px + cap_r * nx,
                            py + cap_r * ny, VX, VY, WZ, vxi, vyi, vzi, wxi, wyi, wzi, ri,
                            meff, ii, dt)
                        bat += wrote
                        full = full or wrote == 0
                # the rim: the closest point of the solid cylinder
                rho = math.sqrt(d2)
                delta = -1.0
                nx = ny = nz = qx = qy = 0.0
                if zi >= zlo and zi <= zhi:
                    if rho > 0.0:         # the curved surface (radial normal)
                        nx = dxw / rho
                        ny = dyw / rho
                        delta = R + ri - rho
                        qx = R * nx
                        qy = R * ny
                elif rho <= R:            # an end face
                    nz = 1.0 if zi > zhi else -1.0
                    delta = ri - abs(zi - zc)
                    qx = dxw
                    qy = dyw
                else:                     # an end face's edge circle
                    qx = R * dxw / rho
                    qy = R * dyw / rho
                    ex = dxw - qx
                    ey = dyw - qy
                    ez = zi - zc
                    de = math.sqrt(ex * ex + ey * ey + ez * ez)
                    if de > 0.0:
                        nx = ex / de
                        ny = ey / de
                        nz = ez / de
                        delta = ri - de
                if delta > 0.0:
                    p, wrote = _wheel_contact(
                        body, bat, bend, i, ID_RIM, hist_id, hist_s, hist_m, hn, p,
                        cp[T_WHEEL, ti], nx, ny, nz, delta, qx, qy, VX, VY, WZ, vxi, vyi, vzi,
                        wxi, wyi, wzi, ri, meff, ii, dt)
                    bat += wrote
                    full = full or wrote == 0
            # ------------------------------------------------------ walls
            for wall in range(5 if near_wall else 0):
                if not flags[wall]:
                    continue
                pid, nx, ny, nz = _wall(wall)
                if wall == 0:
                    delta = ri - (width - zi)
                elif wall == 1:
                    delta = ri - zi
                elif wall == 2:
                    delta = ri - (length - xi)
                elif wall == 3:
                    delta = ri - xi
                else:
                    delta = ri - yi
                if delta <= 0.0:
                    continue
                p, s0x, s0y, s0z, m0x, m0y, m0z = _body_springs(hist_id, hist_s, hist_m, i, hn, p,
                                                                pid)
                (fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz) = body_contact(
                    cp[T_WALL, ti], nx, ny, nz, delta, vxi, vyi, vzi, 0.0, 0.0, 0.0,
                    wxi, wyi, wzi, 0.0, ri, mi, ii, ri, s0x, s0y, s0z, m0x, m0y, m0z, dt)
                if bat < bend:
                    _body_row(body, bat, i, pid, fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz,
                              mnx, mny, mnz, nx, ny, nz, ri)
                    bat += 1
                else:
                    full = True
        bcount[ch] = bat - ch * bcap
        if full:
            err[ERR_BODY_CAPACITY] = 1
            any_full[0] = True
    if any_full[0]:
        return   # no pair row made: rerunnable after growing the wall rows
    # ---------------------------------------------------------- pairs (i = a, lower id)
    # each chunk lists its touching pairs in blocks of law arguments (columns); law_block
    # evaluates a full block at once and its rows are put in place (the order of
    # evaluation never changes a row: each depends only on its own arguments). Listing
    # is two passes: the distance test writes every candidate to the block's next column
    # and moves on by one only when the pair touches (about half of a settled bed's
    # candidates do: a branch on it would be mispredicted every other pair), then
    # _fill_block reads what the law needs of the touching ones.
    for ch in prange(N_CHUNKS):
        lo, hi = chunk_range(ch, first, end)
        law_in = np.empty((N_LAW_IN, LAW_ROW))
        law_out = np.empty((N_LAW_OUT, LAW_ROW))
        slot = np.empty(LAW_ROW, np.int64)      # the pair's slot in the list
        side_a = np.empty(LAW_ROW, np.int64)    # its spheres a and b
        side_b = np.empty(LAW_ROW, np.int64)
        was_on = np.empty(LAW_ROW, np.uint8)    # in contact at the last step
        k = 0
        # the chunk's pairs in one loop (a loop per sphere would end at a count that
        # varies from sphere to sphere, another mispredicted branch)
        # (a chunk past the span's end is empty: lo == hi may exceed it, so no index)
        for q in range(half_off[lo] if lo < hi else 0, half_off[hi] if lo < hi else 0):
            i = np.int64(pair_a[q])
            b = np.int64(pair_b[q])
            ri = r[i]
            dx = pos[b, 0] - pos[i, 0]
            dy = pos[b, 1] - pos[i, 1]
            dz = pos[b, 2] - pos[i, 2]
            rb = r[b]
            d2 = dx * dx + dy * dy + dz * dz
            rs = ri + rb
            # the test "d2 >= rs^2 or d2 == 0: no contact", as one flag
            touch = np.uint8(not d2 >= rs * rs) & np.uint8(d2 != 0.0)
            law_in[LawIn.dx, k] = dx
            law_in[LawIn.dy, k] = dy
            law_in[LawIn.dz, k] = dz
            law_in[LawIn.ra, k] = ri
            law_in[LawIn.rb, k] = rb
            slot[k] = q
            side_a[k] = i
            side_b[k] = b
            was_on[k] = on[q]
            on[q] = touch
            k += touch
            if k == LAW_BLOCK:
                _fill_block(k, law_in, slot, side_a, side_b, was_on, d, rows)
                law_rows(k, law_in, law_out, dt, rows, cp, one_material(k, law_in, LawIn.material))
                _put_pair_rows(k, slot, law_out, rows)
                k = 0
        if k > 0:
            _fill_block(k, law_in, slot, side_a, side_b, was_on, d, rows)
            law_rows(k, law_in, law_out, dt, rows, cp, one_material(k, law_in, LawIn.material))
            _put_pair_rows(k, slot, law_out, rows)


@njit(inline="always", cache=True)
def _fill_block(k, law_in, slot, side_a, side_b, was_on, d, rows):
    """The law arguments of a block's k touching pairs besides their offsets and radii
    (the distance test wrote those): relative velocity, spins, masses, inertias, their
    material pair and their springs of the last step: the pair's row's (zero for a new
    contact)."""
    vel, spin, mass, inertia, mat = d.vel, d.spin, d.mass, d.inertia, d.mat
    for t in range(k):
        a = side_a[t]
        b = side_b[t]
        law_in[LawIn.vrx, t] = vel[b, 0] - vel[a, 0]
        law_in[LawIn.vry, t] = vel[b, 1] - vel[a, 1]
        law_in[LawIn.vrz, t] = vel[b, 2] - vel[a, 2]
        law_in[LawIn.wax, t] = spin[a, 0]
        law_in[LawIn.way, t] = spin[a, 1]
        law_in[LawIn.waz, t] = spin[a, 2]
        law_in[LawIn.wbx, t] = spin[b, 0]
        law_in[LawIn.wby, t] = spin[b, 1]
        law_in[LawIn.wbz, t] = spin[b, 2]
        law_in[LawIn.ma, t] = mass[a]
        law_in[LawIn.mb, t] = mass[b]
        law_in[LawIn.ia, t] = inertia[a]
        law_in[LawIn.ib, t] = inertia[b]
        law_in[LawIn.material, t] = mat[a] * N_TYPES + mat[b]
        # read whatever the row holds, keep it only if the pair touched (a select, not a
        # branch)
        row = rows[slot[t]]
        on_last = was_on[t] != 0
        s0x = row.sx if on_last else 0.0
        s0y = row.sy if on_last else 0.0
        s0z = row.sz if on_last else 0.0
        _, _, _, m0x_, m0y_, m0z_ = rolling_of(row)
        m0x = m0x_ if on_last else 0.0
        m0y = m0y_ if on_last else 0.0
        m0z = m0z_ if on_last else 0.0
        law_in[LawIn.s_x, t] = s0x
        law_in[LawIn.s_y, t] = s0y
        law_in[LawIn.s_z, t] = s0z
        law_in[LawIn.m_x, t] = m0x
        law_in[LawIn.m_y, t] = m0y
        law_in[LawIn.m_z, t] = m0z


@njit(inline="always", cache=True)
def _keep_pair(hist_id, hist_s, hist_m, i, k, cap, pid, row):
    """Write history entry k of sphere i from a pair row; returns False on overflow."""
    if k >= cap:
        return False
    hist_id[i, k] = pid
    hist_s[i, k, 0] = row.sx
    hist_s[i, k, 1] = row.sy
    hist_s[i, k, 2] = row.sz
    _, _, _, mx, my, mz = rolling_of(row)
    hist_m[i, k, 0] = mx
    hist_m[i, k, 1] = my
    hist_m[i, k, 2] = mz
    return True


@njit(inline="always", cache=True)
def _keep(hist_id, hist_s, hist_m, i, k, cap, pid, row):
    """Write history entry k of sphere i from a row; returns False on overflow."""
    if k >= cap:
        return False
    hist_id[i, k] = pid
    hist_s[i, k, 0] = row.sx
    hist_s[i, k, 1] = row.sy
    hist_s[i, k, 2] = row.sz
    hist_m[i, k, 0] = row.mx
    hist_m[i, k, 1] = row.my
    hist_m[i, k, 2] = row.mz
    return True


@njit(inline="always", cache=True)
def _add_row(row, w, side, ri, fx, fy, fz, tx, ty, tz):
    """A sphere's sums plus a pair row weighted by w (its contact flag): side 1.0 for b
    (+force, r_b c + M), -1.0 for a (-force, r_a c - M). x + (-1.0 * y) is x - y, exactly."""
    mox, moy, moz, _, _, _ = rolling_of(row)
    return (fx + side * row.bx * w, fy + side * row.by * w, fz + side * row.bz * w,
            tx + (ri * row.cx + side * mox) * w, ty + (ri * row.cy + side * moy) * w,
            tz + (ri * row.cz + side * moz) * w)


@njit(parallel=True, cache=True)
def gather_integrate(first, end, d, pl, bd, force, torque, gravity, dt, part, err):
    """Phase 2: per sphere of first..end-1 (the span ``produce`` made rows for), sum its rows in ascending partner-id order (module doc),
    rewrite its history from them (an overflow of the history capacity sets
    err[ERR_HIST_OVERFLOW]: fatal, never a silent drop), then advance it one leapfrog
    step. force/torque (N, 3) get the contact force and torque of time n (unless they
    have length 0). Returns the largest squared displacement since the last neighbour
    build (a max: order-free); part is scratch of N_CHUNKS entries. The pairs' springs are
    held in the rows (``produce``): only the wall entries are written to the history (the
    pairs' are written back by ``sync_history``); the capacity is checked on the sphere's
    full contact count."""
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
    gx = gravity[0]
    gy = gravity[1]
    gz = gravity[2]
    for ch in prange(N_CHUNKS):
        lo, hi = chunk_range(ch, first, end)
        bat = ch * bcap
        bend = bat + bcount[ch]
        over = False
        mx = 0.0
        for i in range(lo, hi):
            ri = r[i]   # this sphere's lever arm: a's r_a c - M, b's r_b c + M
            fx = 0.0
            fy = 0.0
            fz = 0.0
            tx = 0.0
            ty = 0.0
            tz = 0.0
            k = 0
            # walls (negative ids, already ascending)
            while bat < bend and body[bat].disc == i:
                brow = body[bat]
                if not _keep(hist_id, hist_s, hist_m, i, k, cap, brow.pid, brow):
                    over = True
                k += 1
                fx += brow.bx
                fy += brow.by
                fz += brow.bz
                tx += brow.tx
                ty += brow.ty
                tz += brow.tz
                bat += 1
            kw = k   # wall entries
            # Every candidate's row is summed, weighted by its contact flag (1.0 or 0.0):
            # about half the candidates touch, and a branch on the flag would be
            # mispredicted every other pair (paid ~10 ns a sphere at 100k, 2 threads). The
            # same bits as summing only the touching ones: a row holds finite values (made
            # from a finite state, or zeros), so a row that does not touch adds +-0.0, and
            # x +- 0.0 is x for every sum here (each starts at +0.0, so none is ever -0.0).
            # partners with lower ids (i is b): the CSR index, ascending partner id
            for e in range(inc_off[i], inc_off[i + 1]):
                q = inc_k[e]
                touch = on[q]
                row = rows[q]
                k += touch
                fx, fy, fz, tx, ty, tz = _add_row(row, np.float64(touch), 1.0, ri, fx, fy, fz,
                                                  tx, ty, tz)
            # partners with higher ids (i is a): its own half list, ascending partner id
            for q in range(half_off[i], half_off[i + 1]):
                touch = on[q]
                row = rows[q]
                k += touch
                fx, fy, fz, tx, ty, tz = _add_row(row, np.float64(touch), -1.0, ri, fx, fy, fz,
                                                  tx, ty, tz)
            if k > cap:
                over = True
            hist_n[i] = min(kw, cap)
            if keep:
                force[i, 0] = fx
                force[i, 1] = fy
                force[i, 2] = fz
                torque[i, 0] = tx
                torque[i, 1] = ty
                torque[i, 2] = tz
            m = mass[i]
            vel[i, 0] += (fx / m + gx) * dt
            vel[i, 1] += (fy / m + gy) * dt
            vel[i, 2] += (fz / m + gz) * dt
            inert = inertia[i]
            spin[i, 0] += tx / inert * dt
            spin[i, 1] += ty / inert * dt
            spin[i, 2] += tz / inert * dt
            pos[i, 0] += vel[i, 0] * dt
            pos[i, 1] += vel[i, 1] * dt
            pos[i, 2] += vel[i, 2] * dt
            ddx = pos[i, 0] - ref[i, 0]
            ddy = pos[i, 1] - ref[i, 1]
            ddz = pos[i, 2] - ref[i, 2]
            dd = ddx * ddx + ddy * ddy + ddz * ddz
            mx = max(mx, dd)
        part[ch] = mx
        if over:
            err[ERR_HIST_OVERFLOW] = 1
    return part.max()


@njit(parallel=True, cache=True)
def load_history(n, d, pl, role):
    """The pair rows' springs from the lower sphere's history (after a neighbour build and
    at the start of every run: the histories may have been set from outside, e.g. a
    restart or a serial-DDM halo refresh): on[q] = in contact at the last step. From here
    to ``sync_history`` a sphere's own history holds only its wall entries (negative ids,
    sorted first). role (length n, or 0 = reload every row): as in 2D
    (physics.forces.load_history), a pair whose two spheres are both ROLE_STABLE keeps its
    row, and with every sphere stable nothing is loaded."""
    gid = d.gid
    hist_n, hist_id, hist_s, hist_m = d.hist_n, d.hist_id, d.hist_s, d.hist_m
    half_off, pair_b, on, rows = pl.half_off, pl.pair_b, pl.on, pl.rows
    if keeps_every_row(role, n):
        # a sphere's history may then still hold its pairs' springs behind its wall entries
        # until the gather rewrites hist_n: produce only looks up wall entries (negative
        # ids, sorted first)
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
                p, found = _lookup(hist_id, i, hn, p, gid[pair_b[q]])
                row = rows[q]
                if found:
                    row.sx = hist_s[i, p, 0]
                    row.sy = hist_s[i, p, 1]
                    row.sz = hist_s[i, p, 2]
                    put_rolling(row, 0.0, 0.0, 0.0, hist_m[i, p, 0], hist_m[i, p, 1],
                                hist_m[i, p, 2])
                on[q] = 1 if found else 0
            kw = 0
            while kw < hn and hist_id[i, kw] < 0:
                kw += 1
            hist_n[i] = kw


@njit(parallel=True, cache=True)
def sync_history(n, d, pl, err, role, need):
    """Each sphere's full history, sorted by partner id, from its wall entries (kept by
    the gather) and its pairs' springs in the rows: lower-id partners through the CSR
    index, then its own half list. Run before a neighbour rebuild and at the end of every held run, so the spheres always leave the
    step whole. role (length n, or 0 = every sphere): only spheres with all bits of
    ``need`` in their role are written (serial DDM, as in 2D). Idempotent."""
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
                    if not _keep_pair(hist_id, hist_s, hist_m, i, k, cap, gid[pair_a[q]], rows[q]):
                        over = True
                    k += 1
            for q in range(half_off[i], half_off[i + 1]):
                if on[q]:
                    if not _keep_pair(hist_id, hist_s, hist_m, i, k, cap, gid[pair_b[q]], rows[q]):
                        over = True
                    k += 1
            hist_n[i] = min(k, cap)
        if over:
            err[ERR_HIST_OVERFLOW] = 1


# the one-thread twins (physics.twins): serial DDM runs its sub-domains side by side
from ..twins import serial_twin  # noqa: E402

produce_serial = serial_twin(produce, "produce_serial")
gather_integrate_serial = serial_twin(gather_integrate, "gather_integrate_serial")
sync_history_serial = serial_twin(sync_history, "sync_history_serial")
load_history_serial = serial_twin(load_history, "load_history_serial")
