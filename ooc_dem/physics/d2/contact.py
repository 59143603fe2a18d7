"""Contact law (numba, no I/O), composed of three parts shared by every contact
(disc-disc pairs, walls, wheel rim and lugs), as LAMMPS's granular_model composes
its sub-models:

- ``normal_force``      linear spring-dashpot (Voigt), clamped at zero force unless the
                        pair's ``no_tension`` is off, less the cohesion
                        (``physics.cohesion``: k_c times the contact's chord);
- ``tangential_force``  tangential spring with history and a Coulomb limit;
- ``rolling_moment``    elastic-plastic rolling resistance (limit mu_r r_eff Fn).

Every contact is evaluated once, in its canonical orientation: body ``a`` is the
partner with the lower id (walls and wheel parts have negative ids, so they are
always ``a``), body ``b`` the higher. Both partners take the result of that one
evaluation (b the force, a its exact negation), which is what makes every execution
mode bit-identical (docs/design.md §3).

The parameters of a material pair are one ``layout.CONTACT_PARAMS`` record
``c`` (fields kn, ks, zn, zt, mu, mur, zr, no_tension, kc).
"""

import math

from numba import njit

from ..cohesion import contact_radius_sq
from .layout import CONTACT_PARAMS, KC, KN, KS, MU, MUR, N_FIELDS, NO_TENSION, ZN, ZR, ZT  # noqa: F401


@njit(inline="always", cache=True)
def normal_force(delta, vn, meff, kn, zn, no_tension):
    """Repulsive normal force of overlap delta > 0 at normal approach speed -vn: clamped at
    zero when no_tension is set (the damping cannot pull), else the plain Voigt force."""
    fn = kn * delta - 2.0 * zn * math.sqrt(meff * kn) * vn
    if fn < 0.0 and no_tension > 0.5:
        fn = 0.0
    return fn


@njit(inline="always", cache=True)
def cohesive_force(kc, ra, rb, delta):
    """The simplified-JKR attraction: kc (cohesion energy density times the discs'
    thickness) times the contact's chord 2 a (ra = 0: a disc on a wall)."""
    return kc * 2.0 * math.sqrt(contact_radius_sq(ra, rb, delta))


@njit(inline="always", cache=True)
def tangential_force(vt, fn, s_old, meff, ks, zt, mu, dt):
    """(ft, s_new): spring s integrated with the tangential slip speed vt, plus
    damping, clamped to mu fn (the spring then holds the limit)."""
    s = s_old + ks * vt * dt
    ft = s + 2.0 * zt * math.sqrt(meff * ks) * vt
    lim = mu * fn
    if abs(ft) > lim:
        ft = math.copysign(lim, ft)
        s = ft
    return ft, s


@njit(inline="always", cache=True)
def rolling_moment(wrel, fn, m_old, ieff, reff, ks, mur, zr, dt):
    """(M, m_new): rolling moment on b from the relative spin wrel = wb - wa
    (zero when mur = 0)."""
    moment = 0.0
    m_new = 0.0
    if mur > 0.0:
        kr = ks * reff * reff
        m_new = m_old - kr * wrel * dt
        moment = m_new - 2.0 * zr * math.sqrt(ieff * kr) * wrel
        mlim = mur * reff * fn
        if abs(moment) > mlim:
            moment = math.copysign(mlim, moment)
            m_new = moment
    return moment, m_new


@njit(inline="always", cache=True)
def contact_force(
    nx,
    ny,
    delta,
    vrx,
    vry,
    wa,
    wb,
    ra,
    rb,
    meff,
    ieff,
    reff,
    s_old,
    m_old,
    kn,
    ks,
    zn,
    zt,
    mu,
    mur,
    zr,
    dt,
    no_tension=1.0,
    kc=0.0,
):
    """Forces of one contact in canonical orientation.

    n = (nx, ny) is the unit normal from a to b, delta > 0 the overlap,
    (vrx, vry) the velocity of b's centre relative to a's contact-frame centre,
    wa, wb the spins, ra, rb the lever arms from each centre to the contact (0 for a wall),
    which are also the radii of the cohesion's contact chord.
    Returns (fn, ft, s_new, M, m_new): the force on b is fn*n - ft*t with
    t = (-ny, nx); a gets the exact negation; the torque on each disc from the
    tangential force is r*ft; the rolling moment M acts on b and -M on a.
    s and m are the stored tangential spring force and rolling spring moment.
    """
    tx = -ny
    ty = nx
    vn = vrx * nx + vry * ny
    vt = vrx * tx + vry * ty - (wa * ra + wb * rb)
    fn = normal_force(delta, vn, meff, kn, zn, no_tension)
    fc = max(fn, 0.0)  # compressive part: the friction and rolling limits (fn when clamped)
    ft, s = tangential_force(vt, fc, s_old, meff, ks, zt, mu, dt)
    moment, m_new = rolling_moment(wb - wa, fc, m_old, ieff, reff, ks, mur, zr, dt)
    if kc > 0.0:
        fn -= cohesive_force(kc, ra, rb, delta)
    return fn, ft, s, moment, m_new


@njit(inline="always", cache=True)
def contact(c, nx, ny, delta, vrx, vry, wa, wb, ra, rb, meff, ieff, reff, s_old, m_old, dt):
    """``contact_force`` with the material pair's parameters as one CONTACT_PARAMS record."""
    return contact_force(
        nx,
        ny,
        delta,
        vrx,
        vry,
        wa,
        wb,
        ra,
        rb,
        meff,
        ieff,
        reff,
        s_old,
        m_old,
        c.kn,
        c.ks,
        c.zn,
        c.zt,
        c.mu,
        c.mur,
        c.zr,
        dt,
        c.no_tension,
        c.kc,
    )
