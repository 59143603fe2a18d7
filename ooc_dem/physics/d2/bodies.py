"""A disc's contacts with the bodies (numba, no I/O): the bin's walls (floor y = 0, end
walls x = 0 and x = length, each with an on-flag), the wheel's rim (a circle of radius R
about the axle) and lugs (capsules of radius cap along each lug's direction from lug_in
to lug_out), and the plates (``physics.plates``: segments along x or y with one active
side), made into body rows (``layout.BODY_ROW``) for ``physics.produce``.

A wheel given as an outline (``physics.outline``) replaces the rim and lugs: its one row
a disc, of id ID_RIM, is ``outline_rows``' (the built-in parts are then off in the scene).

Each is evaluated once, the body as a (the lower id: lugs ID_LUG0 + k, rim ID_RIM,
plates ID_PLATE0 + k, right wall -3, left -2, bottom -1; a disc's rows in that ascending
order), with the disc's springs from its history (zero for a new contact). A wheel row
also holds the torque on the wheel about its centre (the wheel's force is (-bx, -by)).
"""

import math

from numba import njit

from ..history import lookup
from ..layout import (
    AX_X,
    AX_Y,
    HM_R,
    HS_T,
    ID_LUG0,
    ID_PLATE0,
    ID_RIM,
    ID_WALL_BOTTOM,
    ID_WALL_LEFT,
    ID_WALL_RIGHT,
    SP_Z,
    T_WALL,
    T_WHEEL,
)
from ..outline import nearest_point
from ..wheel import lug_axis_offset
from .contact import contact


@njit(inline="always", cache=True)
def _springs(hist_id, hist_s, hist_m, i, hn, p, pid):
    """Disc i's springs with body pid from its history (zero for a new contact); returns
    (p, s, m), p the advanced merge pointer."""
    p, found = lookup(hist_id, i, hn, p, pid)
    if found:
        return p, hist_s[i, p, HS_T], hist_m[i, p, HM_R]
    return p, 0.0, 0.0


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


@njit(cache=True)
def plate_rows(i, d, cp, plates, body, bat, bend, p, dt):
    """Disc i's rows with the plates (physics.plates: the centre in front of the face within
    the radius, its projection within the extent) from body row bat on, p its history cursor.
    Returns (the next row, p, whether a row did not fit). A call of its own, not inlined: the
    few discs near a plate take it, the others' loop stays as small as without plates."""
    xi = d.pos[i, AX_X]
    yi = d.pos[i, AX_Y]
    ri = d.r[i]
    vxi = d.vel[i, AX_X]
    vyi = d.vel[i, AX_Y]
    wi = d.spin[i, SP_Z]
    mi = d.mass[i]
    ii = d.inertia[i]
    ti = d.mat[i]
    hn = d.hist_n[i]
    full = False
    for k in range(plates.shape[0]):
        pk = plates[k]
        if pk.axis == AX_X:  # the face's normal along x, its extent along y
            h = (xi - pk.pos) * pk.side
            along = yi
            nx = pk.side
            ny = 0.0
        else:
            h = (yi - pk.pos) * pk.side
            along = xi
            nx = 0.0
            ny = pk.side
        delta = ri - h
        if delta > 0.0 and h > 0.0 and along >= pk.lo1 and along <= pk.hi1:
            pid = ID_PLATE0 + k
            p, s_old, m_old = _springs(d.hist_id, d.hist_s, d.hist_m, i, hn, p, pid)
            fn, ft, s_new, mom, m_new = contact(
                cp[T_WALL, ti], nx, ny, delta, vxi - pk.vx, vyi - pk.vy, 0.0, wi, 0.0, ri, mi, ii, ri, s_old, m_old, dt
            )
            if bat < bend:
                _body_row(body, bat, i, pid, fn * nx + ft * ny, fn * ny - ft * nx, ri * ft + mom, s_new, m_new, 0.0)
                bat += 1
            else:
                full = True
    return bat, p, full


@njit(cache=True)
def outline_rows(i, d, cp, oscene, ol, body, bat, bend, dt):
    """Disc i's row with a wheel given as an outline (``physics.outline``; oscene:
    ``outline.outline_scene``) from body row bat on: one contact at the outline's point q
    nearest the centre, of partner id ID_RIM, the disc's velocity taken relative to q's,
    V + W x (q - C), the reaction's torque about the axle. Returns (the next row, whether
    the row did not fit). A call of its own: only a wheel with an outline takes it."""
    on, X, Y, VX, VY, WZ, c, sn, wmass = oscene
    if not on:
        return bat, False
    xi = d.pos[i, AX_X]
    yi = d.pos[i, AX_Y]
    ri = d.r[i]
    dxw = xi - X
    dyw = yi - Y
    reach = ol.reach[0] + ri
    if dxw * dxw + dyw * dyw >= reach * reach:
        return bat, False
    # the centre in the body frame (rotated by -theta)
    lx = c * dxw + sn * dyw
    ly = c * dyw - sn * dxw
    k, qx, qy, dist, inside = nearest_point(ol, lx, ly, ri)
    if k < 0:
        return bat, False
    if dist > 0.0:
        nbx = (lx - qx) / dist
        nby = (ly - qy) / dist
        if inside:
            nbx = -nbx
            nby = -nby
    else:  # on the outline: the segment's outward normal
        nv = ol.vert.shape[0]
        j = k + 1 if k + 1 < nv else 0
        ex = ol.vert[j, 0] - ol.vert[k, 0]
        ey = ol.vert[j, 1] - ol.vert[k, 1]
        el = math.sqrt(ex * ex + ey * ey)
        nbx = ey / el
        nby = -ex / el
    delta = ri + dist if inside else ri - dist
    if not delta > 0.0:
        return bat, False
    # back to the world frame: the normal, and q's offset from the axle
    nx = c * nbx - sn * nby
    ny = sn * nbx + c * nby
    rqx = c * qx - sn * qy
    rqy = sn * qx + c * qy
    vqx = VX - WZ * rqy
    vqy = VY + WZ * rqx
    mi = d.mass[i]
    hn = d.hist_n[i]
    ti = d.mat[i]
    _, s_old, m_old = _springs(d.hist_id, d.hist_s, d.hist_m, i, hn, 0, ID_RIM)
    fn, ft, s_new, mom, m_new = contact(
        cp[T_WHEEL, ti],
        nx,
        ny,
        delta,
        d.vel[i, AX_X] - vqx,
        d.vel[i, AX_Y] - vqy,
        WZ,
        d.spin[i, SP_Z],
        0.0,
        ri,
        mi * wmass / (mi + wmass),
        d.inertia[i],
        ri,
        s_old,
        m_old,
        dt,
    )
    return _wheel_row(body, bat, bend, i, ID_RIM, fn, ft, s_new, mom, m_new, nx, ny, rqx, rqy, ri)


@njit(inline="always", cache=True)
def body_force(row):
    """A body row's force on its disc as (fx, fy, fz) (physics.plates; fz = 0)."""
    return row.bx, row.by, 0.0


@njit(inline="always", cache=True)
def body_scene(walls, wg, ws):
    """The walls' and the wheel's geometry this step (body_rows' scene): the bin's length
    and which walls there are; whether there is a wheel, its radius, lugs, mass, centre,
    velocity and spin, and its reach (the farthest point of a lug or the rim)."""
    wl = walls[0]
    g = wg[0]
    s0 = ws[0]
    R = g.radius
    reach = g.lug_out + g.cap
    if R > reach:
        reach = R
    return (
        wl.length,
        wl.left > 0.5,
        wl.right > 0.5,
        wl.bottom > 0.5,
        g.enabled > 0.5,
        R,
        g.lug_in,
        g.lug_out,
        g.cap,
        int(g.nlugs),
        g.mass,
        s0.x,
        s0.y,
        s0.vx,
        s0.vy,
        s0.wz,
        reach,
    )


@njit(inline="always", cache=True)
def body_rows(i, d, cp, scene, with_plates, pscene, lugdir, mesh, body, bat, bend, dt):
    """Disc i's rows with the wheel's lugs and rim, then the plates (with_plates: a
    constant; pscene: ``plates.plate_scene``), then the walls, from body row bat on (bend:
    its chunk's end; mesh: unused, a 2D wheel has no mesh). Returns (the next row, whether
    a row did not fit)."""
    (
        length,
        has_left,
        has_right,
        has_bottom,
        wheel_on,
        R,
        lug_in,
        lug_out,
        cap_r,
        nlugs,
        wmass,
        X,
        Y,
        VX,
        VY,
        WZ,
        reach,
    ) = scene
    pos = d.pos
    xi = pos[i, AX_X]
    yi = pos[i, AX_Y]
    ri = d.r[i]
    # most discs touch neither a wall nor the wheel: test that on the position first
    # (ri > t is exactly a wall's own test ri - t > 0, and the wheel's test is the one
    # below, so no contact is skipped or added)
    near_wall = (has_right and ri > length - xi) or (has_left and ri > xi) or (has_bottom and ri > yi)
    dxw = xi - X
    dyw = yi - Y
    d2 = dxw * dxw + dyw * dyw
    near_wheel = wheel_on and d2 < (reach + ri) * (reach + ri)
    near_plate = False
    if with_plates:
        _, x_lo, x_hi, y_lo, y_hi, z_lo, z_hi = pscene
        near_plate = xi + ri > x_lo and xi - ri < x_hi and yi + ri > y_lo and yi - ri < y_hi
    full = False
    if not (near_wall or near_wheel or near_plate):
        return bat, full
    vxi = d.vel[i, AX_X]
    vyi = d.vel[i, AX_Y]
    wi = d.spin[i, SP_Z]
    mi = d.mass[i]
    ii = d.inertia[i]
    ti = d.mat[i]
    hist_id, hist_s, hist_m = d.hist_id, d.hist_s, d.hist_m
    hn = d.hist_n[i]
    p = 0
    # ------------------------------------------------------ wheel
    if near_wheel:
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
                p, s_old, m_old = _springs(hist_id, hist_s, hist_m, i, hn, p, pid)
                nx = ddx / dd
                ny = ddy / dd
                # velocity of the lug point p: V + Wz x (p - C)
                vax = VX - WZ * (py - Y)
                vay = VY + WZ * (px - X)
                fn, ft, s_new, mom, m_new = contact(
                    cp[T_WHEEL, ti],
                    nx,
                    ny,
                    delta,
                    vxi - vax,
                    vyi - vay,
                    WZ,
                    wi,
                    cap_r,
                    ri,
                    meff,
                    ii,
                    ri,
                    s_old,
                    m_old,
                    dt,
                )
                # reaction on the wheel at q = p + cap_r n, about the centre
                bat, over = _wheel_row(
                    body,
                    bat,
                    bend,
                    i,
                    pid,
                    fn,
                    ft,
                    s_new,
                    mom,
                    m_new,
                    nx,
                    ny,
                    px + cap_r * nx - X,
                    py + cap_r * ny - Y,
                    ri,
                )
                full = full or over
        dw = math.sqrt(d2)
        delta = R + ri - dw
        if delta > 0.0 and dw > 0.0:
            p, s_old, m_old = _springs(hist_id, hist_s, hist_m, i, hn, p, ID_RIM)
            nx = dxw / dw
            ny = dyw / dw
            fn, ft, s_new, mom, m_new = contact(
                cp[T_WHEEL, ti], nx, ny, delta, vxi - VX, vyi - VY, WZ, wi, R, ri, meff, ii, ri, s_old, m_old, dt
            )
            bat, over = _wheel_row(body, bat, bend, i, ID_RIM, fn, ft, s_new, mom, m_new, nx, ny, R * nx, R * ny, ri)
            full = full or over
    # ------------------------------------------------------ plates
    if near_plate:
        bat, p, over = plate_rows(i, d, cp, pscene[0], body, bat, bend, p, dt)
        full = full or over
    # ------------------------------------------------------ walls
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
            p, s_old, m_old = _springs(hist_id, hist_s, hist_m, i, hn, p, pid)
            fn, ft, s_new, mom, m_new = contact(
                cp[T_WALL, ti], nx, ny, delta, vxi, vyi, 0.0, wi, 0.0, ri, mi, ii, ri, s_old, m_old, dt
            )
            if bat < bend:
                _body_row(body, bat, i, pid, fn * nx + ft * ny, fn * ny - ft * nx, ri * ft + mom, s_new, m_new, 0.0)
                bat += 1
            else:
                full = True
    return bat, full
