"""The 3D contact rows (numba, no I/O): the sphere-pair law on blocks of pairs, and what
the step machinery (``physics.produce``, ``gather``, ``history``) reads and writes of a 3D
row.

A pair row (``layout.pair_row_layout``) holds the force on b (bx, by, bz), the lever-free
torque n x Ft (cx, cy, cz: a's torque is r_a c - M and b's r_b c + M, from each
sphere's own radius, the same arithmetic as in the law, so the bits do not depend on
where it is done), the rolling moment on b (mox, moy, moz) and the pair's new
tangential (s*) and rolling (m*) springs, 3-vectors; without rolling resistance in the
contact table the row leaves the rolling parts out (PAIR_ROW_SLIDING) and the kernels
read them as zeros. A body row (``layout.BODY_ROW``) holds the force and torque on the
sphere and its springs. A sphere's sums are (fx, fy, fz, tx, ty, tz).
"""

import math

import numpy as np
from numba import njit, types
from numba.extending import overload

from ..layout import AX_X, AX_Y, AX_Z
from ..produce import copy_pair_params, effective
from .contact import contact
from .layout import (
    LAW_BLOCK,  # noqa: F401
    LAW_HERTZ,
    LAW_LINEAR,
    LAW_ROW,  # noqa: F401
    N_TYPES,  # noqa: F401
    LawIn,
    LawOut,
    LawParams,
)

# the LawIn rows of the spheres' spins (three components each)
LAW_IN_WA = LawIn.wax
LAW_IN_WB = LawIn.wbx
# produce gives each chunk its own law-block columns (one chunk a group: 64 parallel
# pieces of pairs)
CHUNKS_PER_GROUP = 1


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


LAW_MIXED = -1  # law_block's law when a block's pairs do not all have one law


def law_block(fixed, uniform):
    """The block law compiled for one law and one source of the parameters: the pair law
    (contact.contact) on pairs 0..k-1 of a block: what it needs of them is in the LawIn
    rows of law_in, their pair-row fields go to the LawOut rows of law_out (force on b,
    n x Ft, new springs, and the rolling parts when the layout of rows has them).
    fixed: LAW_LINEAR or LAW_HERTZ when every pair of the block has that law (the other
    law's arithmetic is compiled out), else LAW_MIXED; uniform: c0 is the CONTACT_PARAMS
    record of every pair of the block (one material pair), else each pair's parameters
    are in its LawIn columns (c0 is None).

    A loop the compiler runs on several pairs per instruction (SIMD), each pair's arithmetic
    that of the pair evaluated alone, as the 2D one (d2.forces.law_block). Each variant is one dispatcher, compiled once per signature and cached (an @overload's
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
        beta, no_tension, kc = law_in[LawIn.beta], law_in[LawIn.no_tension], law_in[LawIn.kc]
        for t in range(k):
            if uniform:  # a constant: one record for the block, or each pair's columns
                c = LawParams(
                    c0.law if fixed == LAW_MIXED else fixed,
                    c0.kn,
                    c0.ks,
                    c0.zn,
                    c0.zt,
                    c0.mu,
                    c0.mur,
                    c0.zr,
                    c0.estar,
                    c0.gstar,
                    c0.beta,
                    c0.no_tension,
                    c0.kc,
                )
            else:
                c = LawParams(
                    law_[t] if fixed == LAW_MIXED else fixed,
                    kn[t],
                    ks[t],
                    zn[t],
                    zt[t],
                    mu[t],
                    mur[t],
                    zr[t],
                    estar[t],
                    gstar[t],
                    beta[t],
                    no_tension[t],
                    kc[t],
                )
            # the contact geometry and effective quantities (produce's distance test made d2)
            dx = dx_[t]
            dy = dy_[t]
            dz = dz_[t]
            ra = ra_[t]
            rb = rb_[t]
            d2 = dx * dx + dy * dy + dz * dz
            rs = ra + rb
            dd = math.sqrt(d2)
            nx = dx / dd
            ny = dy / dd
            nz = dz / dd
            meff, ieff, reff = effective(ma_[t], mb_[t], ia_[t], ib_[t], ra, rb)
            (fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz) = contact(
                c,
                nx,
                ny,
                nz,
                rs - dd,
                vrx_[t],
                vry_[t],
                vrz_[t],
                wax_[t],
                way_[t],
                waz_[t],
                wbx_[t],
                wby_[t],
                wbz_[t],
                ra,
                rb,
                meff,
                ieff,
                reff,
                s_x_[t],
                s_y_[t],
                s_z_[t],
                m_x_[t],
                m_y_[t],
                m_z_[t],
                dt,
            )
            bx[t] = fn * nx - ftx
            by[t] = fn * ny - fty
            bz[t] = fn * nz - ftz
            cx[t] = ny * ftz - nz * fty
            cy[t] = nz * ftx - nx * ftz
            cz[t] = nx * fty - ny * ftx
            sx_[t] = snx
            sy_[t] = sny
            sz_[t] = snz
            if rolling:  # a constant: without rolling parts the rolling law is compiled out
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
law_block_linear_one = law_block(LAW_LINEAR, True)  # one record for the block
law_block_hertz_one = law_block(LAW_HERTZ, True)


@njit(inline="always", cache=True)
def law_rows(k, law_in, law_out, dt, rows, cp, uniform):
    """The block law on a filled block of k pairs (LawIn columns up to the material pair):
    uniform (one material pair, in column 0): its record for the whole block; else each
    pair's parameters are copied into its columns first. Either way the block's one law
    is compiled alone when it has one."""
    k = np.int64(k)  # never a literal: one compiled block law per signature
    if uniform:
        m0 = np.int64(law_in[LawIn.material, 0])
        c0 = cp[m0 // N_TYPES, m0 % N_TYPES]
        if c0.law == LAW_HERTZ:  # as contact.contact decides: any other law is linear
            law_block_hertz_one(k, law_in, law_out, dt, rows, c0)
        else:
            law_block_linear_one(k, law_in, law_out, dt, rows, c0)
        return
    # LawIn has the record's fields in their order from LawIn.law on
    copy_pair_params(k, law_in, LawIn.material, LawIn.law, cp)
    laws = 0  # the laws of the block's pairs, a bit set (1 << law)
    for t in range(k):
        laws |= 1 << np.int64(law_in[LawIn.law, t])
    if laws == 1 << LAW_LINEAR:
        law_block_linear(k, law_in, law_out, dt, rows, None)
    elif laws == 1 << LAW_HERTZ:
        law_block_hertz(k, law_in, law_out, dt, rows, None)
    else:
        law_block_mixed(k, law_in, law_out, dt, rows, None)


@njit(inline="always", cache=True)
def put_pair_rows(k, slot, law_out, rows):
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
        put_rolling(
            row,
            law_out[LawOut.mox, t],
            law_out[LawOut.moy, t],
            law_out[LawOut.moz, t],
            law_out[LawOut.mx, t],
            law_out[LawOut.my, t],
            law_out[LawOut.mz, t],
        )


@njit(inline="always", cache=True)
def block_law(k, law_in, law_out, dt, rows, cp, uniform):
    """law_rows as the step machinery calls it."""
    law_rows(k, law_in, law_out, dt, rows, cp, uniform)


@njit(inline="always", cache=True)
def springs_into_block(law_in, t, row, on_last):
    """Pair t's springs of the last step: its row's when it was in contact, else zero
    (read whatever the row holds, keep it only if the pair touched: a select, not a
    branch)."""
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


# ---------------------------------------------------- rows <-> the spheres' histories
@njit(inline="always", cache=True)
def springs_from_history(row, hist_s, hist_m, i, p):
    """A pair row's springs from entry p of sphere i's history."""
    row.sx = hist_s[i, p, AX_X]
    row.sy = hist_s[i, p, AX_Y]
    row.sz = hist_s[i, p, AX_Z]
    put_rolling(row, 0.0, 0.0, 0.0, hist_m[i, p, AX_X], hist_m[i, p, AX_Y], hist_m[i, p, AX_Z])


@njit(inline="always", cache=True)
def pair_springs_to_history(hist_s, hist_m, i, k, row):
    """Entry k of sphere i's springs from a pair row (zero rolling spring without the
    rolling parts)."""
    hist_s[i, k, AX_X] = row.sx
    hist_s[i, k, AX_Y] = row.sy
    hist_s[i, k, AX_Z] = row.sz
    _, _, _, mx, my, mz = rolling_of(row)
    hist_m[i, k, AX_X] = mx
    hist_m[i, k, AX_Y] = my
    hist_m[i, k, AX_Z] = mz


@njit(inline="always", cache=True)
def body_springs_to_history(hist_s, hist_m, i, k, row):
    """Entry k of sphere i's springs from a body row."""
    hist_s[i, k, AX_X] = row.sx
    hist_s[i, k, AX_Y] = row.sy
    hist_s[i, k, AX_Z] = row.sz
    hist_m[i, k, AX_X] = row.mx
    hist_m[i, k, AX_Y] = row.my
    hist_m[i, k, AX_Z] = row.mz


# ------------------------------------------------------- a sphere's sums of its rows
@njit(inline="always", cache=True)
def no_force():
    """(fx, fy, fz, tx, ty, tz) at zero."""
    return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


@njit(inline="always", cache=True)
def add_body_row(s, row):
    """The sums plus a body row's force and torque on the sphere."""
    return (s[0] + row.bx, s[1] + row.by, s[2] + row.bz, s[3] + row.tx, s[4] + row.ty, s[5] + row.tz)


@njit(inline="always", cache=True)
def _add_pair(s, row, w, side, r):
    """The sums plus a pair row weighted by w (its contact flag): side 1.0 for b (+force,
    r_b c + M), -1.0 for a (-force, r_a c - M). x + (-1.0 * y) is x - y, exactly."""
    mox, moy, moz, _, _, _ = rolling_of(row)
    return (
        s[0] + side * row.bx * w,
        s[1] + side * row.by * w,
        s[2] + side * row.bz * w,
        s[3] + (r * row.cx + side * mox) * w,
        s[4] + (r * row.cy + side * moy) * w,
        s[5] + (r * row.cz + side * moz) * w,
    )


@njit(inline="always", cache=True)
def add_pair_as_b(s, row, w, r):
    """The sums plus a pair row weighted by w, the sphere its b."""
    return _add_pair(s, row, w, 1.0, r)


@njit(inline="always", cache=True)
def add_pair_as_a(s, row, w, r):
    """The sums plus a pair row weighted by w, the sphere its a."""
    return _add_pair(s, row, w, -1.0, r)
