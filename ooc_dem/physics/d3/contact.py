"""3D contact law for spheres (numba, no I/O), composed like the 2D law
(``ooc_dem.physics.contact``) and LAMMPS's granular sub-models:

- normal: linear spring-dashpot (kn, zn) or Hertz with Tsuji damping
  (validation-3d.md section 3: a = sqrt(R* delta), Sn = 2 E* a, F = (2/3) Sn delta
  = (4/3) E* sqrt(R*) delta^(3/2), damping gamma_n = -2 sqrt(5/6) beta sqrt(Sn m*)).
  With the pair's ``no_tension`` set the force is clamped at zero (the 2D law);
  without it the damping may pull while the bodies overlap (LAMMPS granular without
  ``limit_damping``), which makes the Tsuji restitution exactly e.
  The friction and rolling limits use the compressive part max(Fn, 0). The cohesion
  (``physics.cohesion``: kc times the contact area pi a^2) is then subtracted from Fn.
- tangential: the spring is a 3-vector force. Each step it is first projected onto
  the current tangent plane and rescaled to keep its magnitude (LAMMPS
  ``rotate_rescale_vec``, Luding 2008), then incremented by kt vt dt (kt = ks, or
  St = 8 G* a for Hertz-Mindlin with the force as history: LAMMPS ``mindlin_force``);
  Ft = s + ct vt (ct = 2 zt sqrt(m* ks), or -2 sqrt(5/6) beta sqrt(St m*)); when
  |Ft| > mu Fn it is scaled to mu Fn and the spring reset to it (as in 2D; LAMMPS
  resets it to the limit minus the damping part instead).
- rolling: elastic-plastic 3-vector spring moment on the relative rolling spin
  w_roll = (wb - wa) minus its component along n (twist excluded), projected and
  rescaled like the tangential spring, kr = kt R*^2, damping 2 zr sqrt(I* kr),
  limit mur R* Fn (zero when mur = 0).

Every contact is evaluated once in canonical orientation (a = lower id; walls have
negative ids, so they are always a). n is the unit normal from a to b. The relative
velocity of b's contact point w.r.t. a's is vr - (ra wa + rb wb) x n (lever arms
ra, rb from the centres to the contact along +-n). The force on b is fn n - Ft, a gets
the exact negation; the torque on a is ra (n x Ft) - M, on b rb (n x Ft) + M.
"""

import math

from numba import njit

from ..cohesion import contact_radius_sq
from .layout import LAW_HERTZ

SQRT_5_6 = math.sqrt(5.0 / 6.0)


@njit(inline="always", cache=True)
def project_rescale(sx, sy, sz, nx, ny, nz):
    """s minus its component along n, rescaled to |s| (LAMMPS rotate_rescale_vec)."""
    mag2 = sx * sx + sy * sy + sz * sz
    if mag2 == 0.0:
        return 0.0, 0.0, 0.0
    sn = sx * nx + sy * ny + sz * nz
    px = sx - sn * nx
    py = sy - sn * ny
    pz = sz - sn * nz
    p2 = px * px + py * py + pz * pz
    if p2 == 0.0:
        return 0.0, 0.0, 0.0
    f = math.sqrt(mag2 / p2)
    return px * f, py * f, pz * f


@njit(inline="always", cache=True)
def cohesive_force(kc, ra, rb, delta):
    """The simplified-JKR attraction: kc (cohesion energy density) times the contact area
    pi a^2 (ra = 0: a sphere on a wall or a wheel part)."""
    return kc * math.pi * contact_radius_sq(ra, rb, delta)


@njit(inline="always", cache=True)
def law_coefficients(c, delta, meff, reff):
    """(fe, cn, kt, ct) of material pair c at overlap delta > 0: elastic normal force,
    normal damping coefficient, tangential stiffness, tangential damping coefficient."""
    if c.law == LAW_HERTZ:
        a = math.sqrt(reff * delta)
        sn = 2.0 * c.estar * a
        st = 8.0 * c.gstar * a
        fe = (2.0 / 3.0) * sn * delta
        cn = -2.0 * SQRT_5_6 * c.beta * math.sqrt(sn * meff)
        kt = st
        ct = -2.0 * SQRT_5_6 * c.beta * math.sqrt(st * meff)
    else:
        fe = c.kn * delta
        cn = 2.0 * c.zn * math.sqrt(meff * c.kn)
        kt = c.ks
        ct = 2.0 * c.zt * math.sqrt(meff * c.ks)
    return fe, cn, kt, ct


@njit(inline="always", cache=True)
def contact(
    c,
    nx,
    ny,
    nz,
    delta,
    vrx,
    vry,
    vrz,
    wax,
    way,
    waz,
    wbx,
    wby,
    wbz,
    ra,
    rb,
    meff,
    ieff,
    reff,
    s_x,
    s_y,
    s_z,
    m_x,
    m_y,
    m_z,
    dt,
):
    """One contact in canonical orientation (module doc).

    c: CONTACT_PARAMS record; n: unit normal a -> b; delta > 0: overlap; vr: velocity
    of b's centre relative to a's; wa, wb: spins; ra, rb: lever arms; meff, ieff, reff:
    effective mass, inertia, radius; s, m: stored tangential spring force and rolling
    spring moment (3-vectors). Returns
    (fn, ftx, fty, ftz, snx, sny, snz, Mx, My, Mz, mnx, mny, mnz): the normal force
    (negative without no_tension or with cohesion), the
    tangential force Ft (force on b = fn n - Ft), the new spring, the rolling moment on
    b (a gets -M) and the new rolling spring."""
    fe, cn, kt, ct = law_coefficients(c, delta, meff, reff)
    # ----------------------------------------------------------- normal
    vn = vrx * nx + vry * ny + vrz * nz
    fn = fe - cn * vn
    if fn < 0.0 and c.no_tension > 0.5:
        fn = 0.0
    fc = max(0.0, fn)  # compressive part: friction and rolling limits
    # ------------------------------------------------------- tangential
    # slip velocity of the contact point: vr - (ra wa + rb wb) x n, tangential part
    wx = ra * wax + rb * wbx
    wy = ra * way + rb * wby
    wz = ra * waz + rb * wbz
    vcx = vrx - (wy * nz - wz * ny)
    vcy = vry - (wz * nx - wx * nz)
    vcz = vrz - (wx * ny - wy * nx)
    vcn = vcx * nx + vcy * ny + vcz * nz
    vtx = vcx - vcn * nx
    vty = vcy - vcn * ny
    vtz = vcz - vcn * nz
    sx, sy, sz = project_rescale(s_x, s_y, s_z, nx, ny, nz)
    sx += kt * vtx * dt
    sy += kt * vty * dt
    sz += kt * vtz * dt
    ftx = sx + ct * vtx
    fty = sy + ct * vty
    ftz = sz + ct * vtz
    lim = c.mu * fc
    ft2 = ftx * ftx + fty * fty + ftz * ftz
    if ft2 > lim * lim:
        f = lim / math.sqrt(ft2)
        ftx *= f
        fty *= f
        ftz *= f
        sx = ftx
        sy = fty
        sz = ftz
    # ---------------------------------------------------------- rolling
    mox = 0.0
    moy = 0.0
    moz = 0.0
    mnx = 0.0
    mny = 0.0
    mnz = 0.0
    if c.mur > 0.0:
        rx = wbx - wax
        ry = wby - way
        rz = wbz - waz
        rn = rx * nx + ry * ny + rz * nz
        rx -= rn * nx
        ry -= rn * ny
        rz -= rn * nz
        kr = kt * reff * reff
        cr = 2.0 * c.zr * math.sqrt(ieff * kr)
        mnx, mny, mnz = project_rescale(m_x, m_y, m_z, nx, ny, nz)
        mnx -= kr * rx * dt
        mny -= kr * ry * dt
        mnz -= kr * rz * dt
        mox = mnx - cr * rx
        moy = mny - cr * ry
        moz = mnz - cr * rz
        mlim = c.mur * reff * fc
        mo2 = mox * mox + moy * moy + moz * moz
        if mo2 > mlim * mlim:
            f = mlim / math.sqrt(mo2)
            mox *= f
            moy *= f
            moz *= f
            mnx = mox
            mny = moy
            mnz = moz
    if c.kc > 0.0:
        fn -= cohesive_force(c.kc, ra, rb, delta)
    return fn, ftx, fty, ftz, sx, sy, sz, mox, moy, moz, mnx, mny, mnz
