"""Contact law (numba, no I/O): linear spring-dashpot normal force without tension,
tangential spring with history and a Coulomb limit, elastic-plastic rolling
resistance.

Every contact is evaluated in its canonical orientation: body ``a`` is the partner
with the lower id (walls and wheel parts have negative ids, so they are always
``a``), body ``b`` the higher. Both discs of a pair call this function with the same
arguments in the same order, so both get the same bits and each applies its own
sign; this is what makes every execution mode bit-identical (DESIGN section 3).
"""
import math

from numba import njit

# contact-parameter table fields: cp[type_a, type_b, field]
KN, KS, ZN, ZT, MU, MUR, ZR = 0, 1, 2, 3, 4, 5, 6
N_FIELDS = 7


@njit(inline="always", cache=True)
def contact_force(nx, ny, delta, vrx, vry, wa, wb, ra, rb, meff, ieff, reff,
                  s_old, m_old, kn, ks, zn, zt, mu, mur, zr, dt):
    """Forces of one contact in canonical orientation.

    n = (nx, ny) is the unit normal from a to b, delta > 0 the overlap,
    (vrx, vry) the velocity of b's centre relative to a's contact-frame centre,
    wa, wb the spins, ra, rb the lever arms from each centre to the contact.
    Returns (fn, ft, s_new, M, m_new): the force on b is fn*n - ft*t with
    t = (-ny, nx); a gets the exact negation; the torque on each disc from the
    tangential force is r*ft; the rolling moment M acts on b and -M on a.
    s and m are the stored tangential spring force and rolling spring moment.
    """
    tx = -ny
    ty = nx
    vn = vrx * nx + vry * ny
    vt = vrx * tx + vry * ty - (wa * ra + wb * rb)
    fn = kn * delta - 2.0 * zn * math.sqrt(meff * kn) * vn
    if fn < 0.0:
        fn = 0.0
    s = s_old + ks * vt * dt
    ft = s + 2.0 * zt * math.sqrt(meff * ks) * vt
    lim = mu * fn
    if abs(ft) > lim:
        ft = math.copysign(lim, ft)
        s = ft
    moment = 0.0
    m_new = 0.0
    if mur > 0.0:
        kr = ks * reff * reff
        wrel = wb - wa
        m_new = m_old - kr * wrel * dt
        moment = m_new - 2.0 * zr * math.sqrt(ieff * kr) * wrel
        mlim = mur * reff * fn
        if abs(moment) > mlim:
            moment = math.copysign(mlim, moment)
            m_new = moment
    return fn, ft, s, moment, m_new
