"""A sphere's contacts with the bodies (numba, no I/O): the box's walls (floor y = 0,
end walls x = 0 and x = length, side walls z = 0 and z = width, each with an on-flag),
the wheel (axle along z, spanning z0 -+ width/2: a rim cylinder of radius R, its
end faces included, and nlugs plates: the points within cap of the rectangle
X + s u (s in lug_in..lug_out) times that z span) and the plates (``physics.plates``:
axis-aligned rectangles with one active face), made into body rows
(``layout.BODY_ROW``) for ``physics.produce``. A wheel given as a triangle mesh
(``physics.mesh``) replaces the rim and the lugs: one contact with each part of its
surface (a connected piece: the rim, a grouser), id ID_LUG0 + part (``mesh_rows``).

Each is evaluated once, the body as a (the lower id: lugs ID_LUG0 + k, rim ID_RIM, the
plates ID_PLATE0 + k, then the walls back -5, front -4, right -3, left -2, bottom -1; a
sphere's rows in that ascending order), with the sphere's springs from its history (zero for a new contact).
The wheel's contact point q moves with V + W x (q - C), W = (0, 0, wz); the law sees the
wheel as body a with lever arm 0 and spin W. A wheel row also holds the torque on the
wheel about its axle (the wheel's force is (-bx, -by); its z force goes to the axle).
"""

import math

import numpy as np
from numba import njit

from ..detmath import det_cos, det_sin
from ..history import lookup
from ..mesh import mesh_contact
from ..layout import AX_X, AX_Y, AX_Z, ID_PLATE0, SP_X3, SP_Y3, SP_Z3
from ..plates import other_axes
from ..wheel import lug_axis_offset
from .contact import contact
from .layout import (
    ID_LUG0,
    ID_RIM,
    ID_WALL_BACK,
    ID_WALL_BOTTOM,
    ID_WALL_FRONT,
    ID_WALL_LEFT,
    ID_WALL_RIGHT,
    T_WALL,
    T_WHEEL,
)

# a wall's or the wheel's contact: a few a step, so one compiled call instead of a copy of
# the law inlined at each of body_rows' three sites (a smaller produce compiles faster);
# the same arithmetic, so the same bits
# (contact is a plain function under NUMBA_DISABLE_JIT)
body_contact = njit(cache=True)(getattr(contact, "py_func", contact))


@njit(inline="always", cache=True)
def _body_springs(hist_id, hist_s, hist_m, i, hn, p, pid):
    """Sphere i's springs with body pid (a wall or a wheel part) from its history (zero for a
    new contact); returns (p, sx, sy, sz, mx, my, mz), p the advanced merge pointer."""
    p, found = lookup(hist_id, i, hn, p, pid)
    if found:
        return (
            p,
            hist_s[i, p, AX_X],
            hist_s[i, p, AX_Y],
            hist_s[i, p, AX_Z],
            hist_m[i, p, AX_X],
            hist_m[i, p, AX_Y],
            hist_m[i, p, AX_Z],
        )
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
def _body_row(body, bat, i, pid, fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz, nx, ny, nz, ri):
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
def _wheel_row(
    body, bat, i, pid, fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz, nx, ny, nz, ri, qx, qy
):
    """Body row of a sphere-wheel-part contact (``_body_row``) with the torque on the wheel
    about its axle from the reaction at q (relative to the axle point (X, Y)) minus the
    rolling moment's z part."""
    _body_row(body, bat, i, pid, fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz, nx, ny, nz, ri)
    row = body[bat]
    row.wt = qx * (-row.by) - qy * (-row.bx) - moz


@njit(inline="always", cache=True)
def _wheel_contact(
    body,
    bat,
    bend,
    i,
    pid,
    hist_id,
    hist_s,
    hist_m,
    hn,
    p,
    cpw,
    nx,
    ny,
    nz,
    delta,
    qx,
    qy,
    VX,
    VY,
    WZ,
    vxi,
    vyi,
    vzi,
    wxi,
    wyi,
    wzi,
    ri,
    meff,
    ii,
    dt,
):
    """Sphere i's contact with wheel part pid (a lug or the rim) at normal n, overlap delta
    and contact point q (relative to the axle point): its springs from the history (p: the
    history cursor), the law, and its body row at bat when bat < bend. Returns (p, the rows
    written: 1, or 0 when the buffer is full)."""
    p, s0x, s0y, s0z, m0x, m0y, m0z = _body_springs(hist_id, hist_s, hist_m, i, hn, p, pid)
    (fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz) = body_contact(
        cpw,
        nx,
        ny,
        nz,
        delta,
        vxi - (VX - WZ * qy),
        vyi - (VY + WZ * qx),
        vzi,
        0.0,
        0.0,
        WZ,
        wxi,
        wyi,
        wzi,
        0.0,
        ri,
        meff,
        ii,
        ri,
        s0x,
        s0y,
        s0z,
        m0x,
        m0y,
        m0z,
        dt,
    )
    if bat < bend:
        _wheel_row(
            body, bat, i, pid, fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz, nx, ny, nz, ri, qx, qy
        )
        return p, 1
    return p, 0


@njit(cache=True)
def plate_rows(i, d, cp, plates, body, bat, bend, p, dt):
    """Sphere i's rows with the plates (physics.plates: the centre in front of the face
    within the radius, its projection within the extent) from body row bat on, p its history
    cursor. Returns (the next row, p, whether a row did not fit). A call of its own, not
    inlined: the few spheres near a plate take it, the others' loop stays as without plates."""
    xi = d.pos[i, AX_X]
    yi = d.pos[i, AX_Y]
    zi = d.pos[i, AX_Z]
    ri = d.r[i]
    vxi = d.vel[i, AX_X]
    vyi = d.vel[i, AX_Y]
    vzi = d.vel[i, AX_Z]
    wxi = d.spin[i, SP_X3]
    wyi = d.spin[i, SP_Y3]
    wzi = d.spin[i, SP_Z3]
    mi = d.mass[i]
    ii = d.inertia[i]
    ti = d.mat[i]
    hist_id, hist_s, hist_m = d.hist_id, d.hist_s, d.hist_m
    hn = d.hist_n[i]
    full = False
    for k in range(plates.shape[0]):
        pk = plates[k]
        a = int(pk.axis)
        o1, o2 = other_axes(a)
        h = (_component(a, xi, yi, zi) - pk.pos) * pk.side
        along1 = _component(o1, xi, yi, zi)
        along2 = _component(o2, xi, yi, zi)
        delta = ri - h
        if not (delta > 0.0 and h > 0.0 and along1 >= pk.lo1 and along1 <= pk.hi1):
            continue
        if not (along2 >= pk.lo2 and along2 <= pk.hi2):
            continue
        pid = ID_PLATE0 + k
        nx = pk.side if a == AX_X else 0.0
        ny = pk.side if a == AX_Y else 0.0
        nz = pk.side if a == AX_Z else 0.0
        p, s0x, s0y, s0z, m0x, m0y, m0z = _body_springs(hist_id, hist_s, hist_m, i, hn, p, pid)
        (fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz) = body_contact(
            cp[T_WALL, ti],
            nx,
            ny,
            nz,
            delta,
            vxi - pk.vx,
            vyi - pk.vy,
            vzi - pk.vz,
            0.0,
            0.0,
            0.0,
            wxi,
            wyi,
            wzi,
            0.0,
            ri,
            mi,
            ii,
            ri,
            s0x,
            s0y,
            s0z,
            m0x,
            m0y,
            m0z,
            dt,
        )
        if bat < bend:
            _body_row(body, bat, i, pid, fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz, nx, ny, nz, ri)
            bat += 1
        else:
            full = True
    return bat, p, full


@njit(cache=True)
def mesh_rows(i, d, cp, mesh, dxw, dyw, dzw, theta, VX, VY, WZ, wmass, body, bat, bend, p, dt):
    """Sphere i's rows with a wheel given as a triangle mesh (physics.mesh: one contact a
    part of the surface, at the part's closest point, partner id ID_LUG0 + part, in
    ascending part) from body row bat on, p its history cursor; (dxw, dyw, dzw): its
    centre from the axle point (X, Y, z0). The centre goes into the wheel's body frame
    (turned by -theta about the axle), each contact's normal and point back. Returns (the
    next row, p, whether a row did not fit). A call of its own, like ``plate_rows``."""
    ri = d.r[i]
    # the lugs' deterministic cos/sin: libm's may round otherwise on another machine
    c = det_cos(theta)
    s = det_sin(theta)
    bx = c * dxw + s * dyw
    by = c * dyw - s * dxw
    mi = d.mass[i]
    after = -1
    while True:
        found, part, qbx, qby, qbz, dist, more = mesh_contact(mesh, bx, by, dzw, ri, after)
        if found:
            # the normal from the closest point to the centre (an edge or a vertex: rounded)
            nbx = (bx - qbx) / dist
            nby = (by - qby) / dist
            nz = (dzw - qbz) / dist
            p, wrote = _wheel_contact(
                body,
                bat,
                bend,
                i,
                ID_LUG0 + part,
                d.hist_id,
                d.hist_s,
                d.hist_m,
                d.hist_n[i],
                p,
                cp[T_WHEEL, d.mat[i]],
                c * nbx - s * nby,
                s * nbx + c * nby,
                nz,
                ri - dist,
                c * qbx - s * qby,
                s * qbx + c * qby,
                VX,
                VY,
                WZ,
                d.vel[i, AX_X],
                d.vel[i, AX_Y],
                d.vel[i, AX_Z],
                d.spin[i, SP_X3],
                d.spin[i, SP_Y3],
                d.spin[i, SP_Z3],
                ri,
                mi * wmass / (mi + wmass),
                d.inertia[i],
                dt,
            )
            if wrote == 0:
                return bat, p, True
            bat += wrote
        if not more:
            return bat, p, False
        after = part


@njit(inline="always", cache=True)
def body_force(row):
    """A body row's force on its sphere as (fx, fy, fz) (physics.plates)."""
    return row.bx, row.by, row.bz


@njit(inline="always", cache=True)
def _component(a, x, y, z):
    """Component a (AX_X, AX_Y, AX_Z) of the vector (x, y, z)."""
    if a == AX_X:
        return x
    if a == AX_Y:
        return y
    return z


@njit(inline="always", cache=True)
def body_scene(walls, wg, ws):
    """The walls' and the wheel's geometry this step (body_rows' scene): the box's length
    and width and which walls there are (in ascending id order: back, front, right, left,
    bottom); whether there is a wheel, its radius, lugs, mass, z span, axle point,
    velocity and spin, its reach (the farthest point of a lug or the rim from the
    axle), its lateral centre z0 and its angle."""
    wl = walls[0]
    flags = np.array([wl.back > 0.5, wl.front > 0.5, wl.right > 0.5, wl.left > 0.5, wl.bottom > 0.5])
    g = wg[0]
    w0 = ws[0]
    R = g.radius
    reach = g.lug_out + g.cap
    if R > reach:
        reach = R
    return (
        wl.length,
        wl.width,
        flags,
        g.enabled > 0.5,
        R,
        g.lug_in,
        g.lug_out,
        g.cap,
        int(g.nlugs),
        g.mass,
        g.z0 - 0.5 * g.width,
        g.z0 + 0.5 * g.width,
        w0.x,
        w0.y,
        w0.vx,
        w0.vy,
        w0.wz,
        reach,
        g.z0,
        w0.theta,
    )


@njit(inline="always", cache=True)
def body_rows(i, d, cp, scene, with_plates, pscene, lugdir, mesh, body, bat, bend, dt):
    """Sphere i's rows with the wheel's lugs and rim (or its triangle mesh, when mesh has
    triangles: ``mesh_rows``), then the plates (with_plates: a constant; pscene:
    ``plates.plate_scene``), then the walls, from body row bat on (bend: its chunk's end).
    Returns (the next row, whether a row did not fit)."""
    (
        length,
        width,
        flags,
        wheel_on,
        R,
        lug_in,
        lug_out,
        cap_r,
        nlugs,
        wmass,
        zlo,
        zhi,
        X,
        Y,
        VX,
        VY,
        WZ,
        reach,
        z0,
        theta,
    ) = scene
    pos = d.pos
    xi = pos[i, AX_X]
    yi = pos[i, AX_Y]
    zi = pos[i, AX_Z]
    ri = d.r[i]
    # most spheres touch neither a wall nor the wheel: test that on the position
    # first (ri > t is exactly a wall's own test ri - t > 0, and the wheel's test
    # is the one below, so no contact is skipped or added)
    near_wall = (
        (flags[0] and ri > width - zi)
        or (flags[1] and ri > zi)
        or (flags[2] and ri > length - xi)
        or (flags[3] and ri > xi)
        or (flags[4] and ri > yi)
    )
    dxw = xi - X
    dyw = yi - Y
    d2 = dxw * dxw + dyw * dyw
    with_mesh = mesh.tri.shape[0] > 0
    if with_mesh:  # within the mesh's reach and z extent
        mb = mesh.bounds
        near_wheel = wheel_on and d2 < (mb[0] + ri) * (mb[0] + ri) and zi > z0 + mb[1] - ri and zi < z0 + mb[2] + ri
    else:
        zm = cap_r + ri
        near_wheel = wheel_on and d2 < (reach + ri) * (reach + ri) and zi > zlo - zm and zi < zhi + zm
    near_plate = False
    if with_plates:
        _, x_lo, x_hi, y_lo, y_hi, z_lo, z_hi = pscene
        near_plate = (
            xi + ri > x_lo
            and xi - ri < x_hi
            and yi + ri > y_lo
            and yi - ri < y_hi
            and zi + ri > z_lo
            and zi - ri < z_hi
        )
    full = False
    if not (near_wall or near_wheel or near_plate):
        return bat, full
    vxi = d.vel[i, AX_X]
    vyi = d.vel[i, AX_Y]
    vzi = d.vel[i, AX_Z]
    wxi = d.spin[i, SP_X3]
    wyi = d.spin[i, SP_Y3]
    wzi = d.spin[i, SP_Z3]
    mi = d.mass[i]
    ii = d.inertia[i]
    ti = d.mat[i]
    hist_id, hist_s, hist_m = d.hist_id, d.hist_s, d.hist_m
    hn = d.hist_n[i]
    p = 0
    # ------------------------------------------------------ wheel
    if near_wheel and with_mesh:
        bat, p, over = mesh_rows(i, d, cp, mesh, dxw, dyw, zi - z0, theta, VX, VY, WZ, wmass, body, bat, bend, p, dt)
        full = full or over
    elif near_wheel:
        meff = mi * wmass / (mi + wmass)
        zc = min(max(zi, zlo), zhi)
        for lug in range(nlugs):
            ux = lugdir[lug].ux
            uy = lugdir[lug].uy
            sproj = lug_axis_offset(dxw, dyw, ux, uy, lug_in, lug_out)
            px = sproj * ux  # the lug's closest axis point, relative to C
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
                    body,
                    bat,
                    bend,
                    i,
                    ID_LUG0 + lug,
                    hist_id,
                    hist_s,
                    hist_m,
                    hn,
                    p,
                    cp[T_WHEEL, ti],
                    nx,
                    ny,
                    nz,
                    delta,
                    px + cap_r * nx,
                    py + cap_r * ny,
                    VX,
                    VY,
                    WZ,
                    vxi,
                    vyi,
                    vzi,
                    wxi,
                    wyi,
                    wzi,
                    ri,
                    meff,
                    ii,
                    dt,
                )
                bat += wrote
                full = full or wrote == 0
        # the rim: the closest point of the solid cylinder
        rho = math.sqrt(d2)
        delta = -1.0
        nx = ny = nz = qx = qy = 0.0
        if zi >= zlo and zi <= zhi:
            if rho > 0.0:  # the curved surface (radial normal)
                nx = dxw / rho
                ny = dyw / rho
                delta = R + ri - rho
                qx = R * nx
                qy = R * ny
        elif rho <= R:  # an end face
            nz = 1.0 if zi > zhi else -1.0
            delta = ri - abs(zi - zc)
            qx = dxw
            qy = dyw
        else:  # an end face's edge circle
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
                body,
                bat,
                bend,
                i,
                ID_RIM,
                hist_id,
                hist_s,
                hist_m,
                hn,
                p,
                cp[T_WHEEL, ti],
                nx,
                ny,
                nz,
                delta,
                qx,
                qy,
                VX,
                VY,
                WZ,
                vxi,
                vyi,
                vzi,
                wxi,
                wyi,
                wzi,
                ri,
                meff,
                ii,
                dt,
            )
            bat += wrote
            full = full or wrote == 0
    # ------------------------------------------------------ plates
    if near_plate:
        bat, p, over = plate_rows(i, d, cp, pscene[0], body, bat, bend, p, dt)
        full = full or over
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
        p, s0x, s0y, s0z, m0x, m0y, m0z = _body_springs(hist_id, hist_s, hist_m, i, hn, p, pid)
        (fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz) = body_contact(
            cp[T_WALL, ti],
            nx,
            ny,
            nz,
            delta,
            vxi,
            vyi,
            vzi,
            0.0,
            0.0,
            0.0,
            wxi,
            wyi,
            wzi,
            0.0,
            ri,
            mi,
            ii,
            ri,
            s0x,
            s0y,
            s0z,
            m0x,
            m0y,
            m0z,
            dt,
        )
        if bat < bend:
            _body_row(body, bat, i, pid, fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz, nx, ny, nz, ri)
            bat += 1
        else:
            full = True
    return bat, full
