"""The 2D contact rows (numba, no I/O): the disc-pair law on blocks of pairs, and what the
step machinery (``physics.produce``, ``gather``, ``history``) reads and writes of a 2D
row.

A pair row (``layout.PAIR_ROW``) holds the force on b (bx, by), the torque terms of a
and b (ta = r_a ft - M, tb = r_b ft + M) and the pair's new springs (s, m: scalars, the
tangential spring force and the rolling spring moment); a body row
(``layout.BODY_ROW``) the force and torque on the disc and its springs. A disc's sums
are (fx, fy, torque about z).
"""

import math

import numpy as np
from numba import njit

from ..layout import HM_R, HS_T
from ..produce import copy_pair_params, effective
from .contact import contact
from .layout import N_TYPES, LawIn, LawOut, LawParams

# the LawIn rows of the discs' spins (one component each)
LAW_IN_WA = LawIn.wa
LAW_IN_WB = LawIn.wb
# produce runs the chunks in groups, each with its own law-block columns: allocated once
# a group rather than once a chunk (a serial-DDM step makes them for every sub-domain:
# paper2008, D = 6, 20 000 steps took 7.7 s so against 9.8 s with one allocation a chunk)
CHUNKS_PER_GROUP = 4


def law_block(uniform):
    """The pair law (contact.contact) on pairs 0..k-1 of a block: what it needs of them is
    in the LawIn rows of law_in, their pair-row fields go to the LawOut rows of law_out.
    uniform: c0 is the CONTACT_PARAMS record of every pair of the block (one material
    pair), else each pair's parameters are in its LawIn columns (c0 is None).

    One loop with no early exit and no call left after inlining, so the compiler
    evaluates several pairs per instruction (SIMD); each pair's arithmetic and its order
    are those of the pair evaluated alone (numba sets no fast-math, so no operation is
    fused or reordered): its bits do not depend on the block."""

    def block(k, law_in, law_out, dt, c0):
        dx_, dy_, vrx_, vry_ = law_in[LawIn.dx], law_in[LawIn.dy], law_in[LawIn.vrx], law_in[LawIn.vry]
        wa_, wb_, ra_, rb_ = law_in[LawIn.wa], law_in[LawIn.wb], law_in[LawIn.ra], law_in[LawIn.rb]
        ma_, mb_, ia_, ib_ = law_in[LawIn.ma], law_in[LawIn.mb], law_in[LawIn.ia], law_in[LawIn.ib]
        s_old_, m_old_ = law_in[LawIn.s_old], law_in[LawIn.m_old]
        kn, ks, zn, zt = law_in[LawIn.kn], law_in[LawIn.ks], law_in[LawIn.zn], law_in[LawIn.zt]
        mu, mur, zr = law_in[LawIn.mu], law_in[LawIn.mur], law_in[LawIn.zr]
        no_tension, kc = law_in[LawIn.no_tension], law_in[LawIn.kc]
        bx_, by_, ta_, tb_ = law_out[LawOut.bx], law_out[LawOut.by], law_out[LawOut.ta], law_out[LawOut.tb]
        s_, m_ = law_out[LawOut.s], law_out[LawOut.m]
        for t in range(k):
            if uniform:  # a constant: one record for the block, or each pair's columns
                c = c0
            else:
                c = LawParams(kn[t], ks[t], zn[t], zt[t], mu[t], mur[t], zr[t], no_tension[t], kc[t])
            dx = dx_[t]
            dy = dy_[t]
            ra = ra_[t]
            rb = rb_[t]
            d2 = dx * dx + dy * dy
            rs = ra + rb
            dd = math.sqrt(d2)
            nx = dx / dd
            ny = dy / dd
            meff, ieff, reff = effective(ma_[t], mb_[t], ia_[t], ib_[t], ra, rb)
            fn, ft, s_new, mom, m_new = contact(
                c, nx, ny, rs - dd, vrx_[t], vry_[t], wa_[t], wb_[t], ra, rb, meff, ieff, reff, s_old_[t], m_old_[t], dt
            )
            bx_[t] = fn * nx + ft * ny
            by_[t] = fn * ny - ft * nx
            ta_[t] = ra * ft - mom
            tb_[t] = rb * ft + mom
            s_[t] = s_new
            m_[t] = m_new

    # error_model numpy: no division-by-zero test in the loop (it would stop the SIMD; the law
    # never divides by zero: the pairs touch (dd > 0), masses and inertias are positive)
    return njit(error_model="numpy", cache=True)(block)


law_block_one = law_block(True)  # one record for the block
law_block_each = law_block(False)  # each pair's parameters in its columns


@njit(inline="always", cache=True)
def law_rows(k, law_in, law_out, dt, cp, uniform):
    """The block law on a filled block of k pairs (LawIn columns up to the material pair):
    uniform (one material pair, in column 0): its record for the whole block; else each
    pair's parameters are copied into its columns first."""
    k = np.int64(k)  # never a literal: one compiled block law per signature
    if uniform:
        m0 = np.int64(law_in[LawIn.material, 0])
        law_block_one(k, law_in, law_out, dt, cp[m0 // N_TYPES, m0 % N_TYPES])
        return
    copy_pair_params(k, law_in, LawIn.material, LawIn.kn, cp)
    law_block_each(k, law_in, law_out, dt, None)


@njit(inline="always", cache=True)
def block_law(k, law_in, law_out, dt, rows, cp, uniform):
    """law_rows as the step machinery calls it (one pair-row layout: rows unused)."""
    law_rows(k, law_in, law_out, dt, cp, uniform)


@njit(inline="always", cache=True)
def put_pair_rows(k, slot, law_out, rows):
    """The rows of a block's pairs (law_block's results) into their slots."""
    for t in range(k):
        row = rows[slot[t]]
        row.bx = law_out[LawOut.bx, t]
        row.by = law_out[LawOut.by, t]
        row.ta = law_out[LawOut.ta, t]
        row.tb = law_out[LawOut.tb, t]
        row.s = law_out[LawOut.s, t]
        row.m = law_out[LawOut.m, t]


@njit(inline="always", cache=True)
def springs_into_block(law_in, t, row, on_last):
    """Pair t's springs of the last step: its row's when it was in contact, else zero (a
    select, not a branch)."""
    law_in[LawIn.s_old, t] = row.s if on_last else 0.0
    law_in[LawIn.m_old, t] = row.m if on_last else 0.0


# ------------------------------------------------------ rows <-> the discs' histories
@njit(inline="always", cache=True)
def springs_from_history(row, hist_s, hist_m, i, p):
    """A pair row's springs from entry p of disc i's history."""
    row.s = hist_s[i, p, HS_T]
    row.m = hist_m[i, p, HM_R]


@njit(inline="always", cache=True)
def springs_to_history(hist_s, hist_m, i, k, row):
    """Entry k of disc i's springs from a pair row or a body row (both hold s and m)."""
    hist_s[i, k, HS_T] = row.s
    hist_m[i, k, HM_R] = row.m


body_springs_to_history = springs_to_history
pair_springs_to_history = springs_to_history


# --------------------------------------------------------- a disc's sums of its rows
@njit(inline="always", cache=True)
def no_force():
    """(fx, fy, torque) at zero."""
    return 0.0, 0.0, 0.0


@njit(inline="always", cache=True)
def add_body_row(s, row):
    """The sums plus a body row's force and torque on the disc."""
    return s[0] + row.bx, s[1] + row.by, s[2] + row.tq


@njit(inline="always", cache=True)
def add_pair_as_b(s, row, w, r):
    """The sums plus a pair row weighted by w, the disc its b: the force and r_b ft + M."""
    return s[0] + row.bx * w, s[1] + row.by * w, s[2] + row.tb * w


@njit(inline="always", cache=True)
def add_pair_as_a(s, row, w, r):
    """The sums plus a pair row weighted by w, the disc its a: minus the force, r_a ft - M."""
    return s[0] - row.bx * w, s[1] - row.by * w, s[2] + row.ta * w
