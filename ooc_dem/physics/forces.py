"""Per-particle force gather (numba, no I/O).

Each disc computes every one of its contacts itself (no scatter, no atomics) and
sums them in ascending partner-id order: wheel lugs (ids -1000 + k), wheel rim
(-100), right wall (-3), left wall (-2), bottom wall (-1), then discs by global
id. Its contact history (partner id, tangential spring, rolling spring) is kept
sorted by partner id and rewritten from the contacts that exist now; a pair's
two copies evolve identically because both are computed in canonical
orientation (physics.contact).
"""
import math

import numba
import numpy as np
from numba import njit, prange

from .contact import KN, KS, MU, MUR, ZN, ZR, ZT, contact_force

ID_LUG0 = -1000
ID_RIM = -100
ID_WALL_RIGHT = -3
ID_WALL_LEFT = -2
ID_WALL_BOTTOM = -1

# wheel geometry vector wg[...]
WG_ENABLED, WG_R, WG_LUG_IN, WG_LUG_OUT, WG_CAP, WG_NLUGS, WG_MASS = range(7)
WG_SIZE = 7
# wheel state vector ws[...]
WS_X, WS_Y, WS_VX, WS_VY, WS_THETA, WS_WZ = range(6)
WS_SIZE = 6

ERR_HIST_OVERFLOW = 0
ERR_NBR_OVERFLOW = 1


@njit(inline="always", cache=True)
def _lookup(hid, hft, hmr, i, hn, p, pid):
    """Advance the merge pointer p in i's sorted history to partner pid."""
    while p < hn and hid[i, p] < pid:
        p += 1
    if p < hn and hid[i, p] == pid:
        return p, hft[i, p], hmr[i, p]
    return p, 0.0, 0.0


@njit(parallel=True, cache=True)
def compute_forces(n, x, y, vx, vy, w, r, mass, inertia, mat, gid,
                   nbr, nbr_n, hist_n, hist_id, hist_ft, hist_mr,
                   fx, fy, tq, cp, walls, wg, ws,
                   wfx, wfy, wtq, wcount, lugdir, scratch_id, scratch_f, dt, err):
    """Forces and torques on discs 0..n-1 at time n; rewrites their history.

    walls = [length, has_left, has_right, has_bottom]. Wheel reactions of disc i
    (force and torque on the wheel about its centre) go to wfx/wfy/wtq[i] with
    wcount[i] the number of wheel contacts, for a canonical sum by the caller.
    lugdir[k] = (cos, sin) of lug k's direction (see lug_directions).
    """
    cap = hist_id.shape[1]
    t_wall = cp.shape[0] - 2
    t_wheel = cp.shape[0] - 1
    length = walls[0]
    wheel_on = wg[WG_ENABLED] > 0.5
    R = wg[WG_R]
    lug_in = wg[WG_LUG_IN]
    lug_out = wg[WG_LUG_OUT]
    cap_r = wg[WG_CAP]
    nlugs = int(wg[WG_NLUGS])
    wmass = wg[WG_MASS]
    X = ws[WS_X]
    Y = ws[WS_Y]
    VX = ws[WS_VX]
    VY = ws[WS_VY]
    theta = ws[WS_THETA]
    WZ = ws[WS_WZ]
    reach = lug_out + cap_r
    if R > reach:
        reach = R
    for i in prange(n):
        tid = numba.get_thread_id()
        xi = x[i]
        yi = y[i]
        vxi = vx[i]
        vyi = vy[i]
        wi = w[i]
        ri = r[i]
        mi = mass[i]
        ii = inertia[i]
        ti = mat[i]
        gi = gid[i]
        hn = hist_n[i]
        p = 0
        k = 0
        sfx = 0.0
        sfy = 0.0
        stq = 0.0
        # ---------------------------------------------------------- wheel
        wfx_i = 0.0
        wfy_i = 0.0
        wtq_i = 0.0
        wc = 0
        if wheel_on:
            dxw = xi - X
            dyw = yi - Y
            d2 = dxw * dxw + dyw * dyw
            if d2 < (reach + ri) * (reach + ri):
                c = cp[t_wheel, ti]
                meff = mi * wmass / (mi + wmass)
                for lug in range(nlugs):
                    ux = lugdir[lug, 0]
                    uy = lugdir[lug, 1]
                    sproj = dxw * ux + dyw * uy
                    if sproj < lug_in:
                        sproj = lug_in
                    elif sproj > lug_out:
                        sproj = lug_out
                    px = X + sproj * ux
                    py = Y + sproj * uy
                    ddx = xi - px
                    ddy = yi - py
                    dd = math.sqrt(ddx * ddx + ddy * ddy)
                    delta = cap_r + ri - dd
                    if delta > 0.0 and dd > 0.0:
                        pid = ID_LUG0 + lug
                        p, s_old, m_old = _lookup(hist_id, hist_ft, hist_mr, i, hn, p, pid)
                        nx = ddx / dd
                        ny = ddy / dd
                        # velocity of the lug point p: V + Wz x (p - C)
                        vax = VX - WZ * (py - Y)
                        vay = VY + WZ * (px - X)
                        fn, ft, s_new, mom, m_new = contact_force(
                            nx, ny, delta, vxi - vax, vyi - vay, WZ, wi, cap_r, ri,
                            meff, ii, ri, s_old, m_old, c[KN], c[KS], c[ZN], c[ZT],
                            c[MU], c[MUR], c[ZR], dt)
                        if k >= cap:
                            err[0] = 1
                            break
                        scratch_id[tid, k] = pid
                        scratch_f[tid, 0, k] = s_new
                        scratch_f[tid, 1, k] = m_new
                        k += 1
                        bx = fn * nx + ft * ny
                        by = fn * ny - ft * nx
                        sfx += bx
                        sfy += by
                        stq += ri * ft + mom
                        # reaction on the wheel at q = p + cap_r n, about the centre
                        qx = px + cap_r * nx - X
                        qy = py + cap_r * ny - Y
                        wfx_i -= bx
                        wfy_i -= by
                        wtq_i += qx * (-by) - qy * (-bx) - mom
                        wc += 1
                d = math.sqrt(d2)
                delta = R + ri - d
                if delta > 0.0 and d > 0.0:
                    p, s_old, m_old = _lookup(hist_id, hist_ft, hist_mr, i, hn, p, ID_RIM)
                    nx = dxw / d
                    ny = dyw / d
                    fn, ft, s_new, mom, m_new = contact_force(
                        nx, ny, delta, vxi - VX, vyi - VY, WZ, wi, R, ri,
                        meff, ii, ri, s_old, m_old, c[KN], c[KS], c[ZN], c[ZT],
                        c[MU], c[MUR], c[ZR], dt)
                    if k >= cap:
                        err[0] = 1
                    else:
                        scratch_id[tid, k] = ID_RIM
                        scratch_f[tid, 0, k] = s_new
                        scratch_f[tid, 1, k] = m_new
                        k += 1
                    bx = fn * nx + ft * ny
                    by = fn * ny - ft * nx
                    sfx += bx
                    sfy += by
                    stq += ri * ft + mom
                    qx = R * nx
                    qy = R * ny
                    wfx_i -= bx
                    wfy_i -= by
                    wtq_i += qx * (-by) - qy * (-bx) - mom
                    wc += 1
        wfx[i] = wfx_i
        wfy[i] = wfy_i
        wtq[i] = wtq_i
        wcount[i] = wc
        # ---------------------------------------------------------- walls
        c = cp[t_wall, ti]
        for wall in range(3):
            # ascending ids: right (-3), left (-2), bottom (-1)
            if wall == 0:
                if walls[2] < 0.5:
                    continue
                delta = ri - (length - xi)
                nx = -1.0
                ny = 0.0
                pid = ID_WALL_RIGHT
            elif wall == 1:
                if walls[1] < 0.5:
                    continue
                delta = ri - xi
                nx = 1.0
                ny = 0.0
                pid = ID_WALL_LEFT
            else:
                if walls[3] < 0.5:
                    continue
                delta = ri - yi
                nx = 0.0
                ny = 1.0
                pid = ID_WALL_BOTTOM
            if delta > 0.0:
                p, s_old, m_old = _lookup(hist_id, hist_ft, hist_mr, i, hn, p, pid)
                fn, ft, s_new, mom, m_new = contact_force(
                    nx, ny, delta, vxi, vyi, 0.0, wi, 0.0, ri,
                    mi, ii, ri, s_old, m_old, c[KN], c[KS], c[ZN], c[ZT],
                    c[MU], c[MUR], c[ZR], dt)
                if k >= cap:
                    err[0] = 1
                else:
                    scratch_id[tid, k] = pid
                    scratch_f[tid, 0, k] = s_new
                    scratch_f[tid, 1, k] = m_new
                    k += 1
                sfx += fn * nx + ft * ny
                sfy += fn * ny - ft * nx
                stq += ri * ft + mom
        # ---------------------------------------------------------- discs
        for q in range(nbr_n[i]):
            j = np.int64(nbr[i, q])
            gj = gid[j]
            # canonical orientation: a has the lower id
            # (i is the unsigned prange index; keep a and b both int64)
            if gi < gj:
                a = np.int64(i)
                b = j
            else:
                a = j
                b = np.int64(i)
            dx = x[b] - x[a]
            dy = y[b] - y[a]
            ra = r[a]
            rb = r[b]
            d2 = dx * dx + dy * dy
            rs = ra + rb
            if d2 >= rs * rs:
                continue
            d = math.sqrt(d2)
            if d == 0.0:
                continue
            delta = rs - d
            p, s_old, m_old = _lookup(hist_id, hist_ft, hist_mr, i, hn, p, gj)
            nx = dx / d
            ny = dy / d
            ta = mat[a]
            tb = mat[b]
            ma = mass[a]
            mb = mass[b]
            ia = inertia[a]
            ib = inertia[b]
            fn, ft, s_new, mom, m_new = contact_force(
                nx, ny, delta, vx[b] - vx[a], vy[b] - vy[a], w[a], w[b], ra, rb,
                ma * mb / (ma + mb), ia * ib / (ia + ib), ra * rb / (ra + rb),
                s_old, m_old, cp[ta, tb, KN], cp[ta, tb, KS], cp[ta, tb, ZN], cp[ta, tb, ZT],
                cp[ta, tb, MU], cp[ta, tb, MUR], cp[ta, tb, ZR], dt)
            if k >= cap:
                err[0] = 1
                break
            scratch_id[tid, k] = gj
            scratch_f[tid, 0, k] = s_new
            scratch_f[tid, 1, k] = m_new
            k += 1
            bx = fn * nx + ft * ny
            by = fn * ny - ft * nx
            if gi > gj:
                sfx += bx
                sfy += by
                stq += ri * ft + mom
            else:
                sfx -= bx
                sfy -= by
                stq += ri * ft - mom
        fx[i] = sfx
        fy[i] = sfy
        tq[i] = stq
        for q in range(k):
            hist_id[i, q] = scratch_id[tid, q]
            hist_ft[i, q] = scratch_f[tid, 0, q]
            hist_mr[i, q] = scratch_f[tid, 1, q]
        hist_n[i] = k


@njit(cache=True)
def lug_directions(theta, nlugs, lugdir):
    """Unit vectors of the lugs at wheel angle theta (lug k at theta + 2 pi k / n)."""
    for k in range(nlugs):
        phi = theta + 2.0 * math.pi * k / nlugs
        lugdir[k, 0] = math.cos(phi)
        lugdir[k, 1] = math.sin(phi)


@njit(cache=True)
def wheel_reaction(n, gid, wfx, wfy, wtq, wcount):
    """Soil force and torque on the wheel summed in ascending disc id (canonical)."""
    cnt = 0
    for i in range(n):
        if wcount[i] > 0:
            cnt += 1
    if cnt == 0:
        return 0.0, 0.0, 0.0, 0
    idx = np.empty(cnt, np.int64)
    c = 0
    for i in range(n):
        if wcount[i] > 0:
            idx[c] = i
            c += 1
    keys = gid[idx]
    order = np.argsort(keys, kind="mergesort")
    fxs = 0.0
    fys = 0.0
    tqs = 0.0
    for o in range(cnt):
        i = idx[order[o]]
        fxs += wfx[i]
        fys += wfy[i]
        tqs += wtq[i]
    return fxs, fys, tqs, cnt


def make_scratch(cap):
    nt = numba.config.NUMBA_NUM_THREADS
    return np.zeros((nt, cap), np.int64), np.zeros((nt, 2, cap), np.float64)
