"""Cohesion of both dimensions (numba, no I/O): the simplified JKR model of LIGGGHTS
(``cohesion sjkr``), an attraction k_c A proportional to the contact area A while the
bodies overlap.

It acts only on touching bodies, so it needs neither a longer neighbour reach nor a
history of its own: the contact rows, their order and their bits in every mode are those
of the cohesionless law. k_c is a cohesion energy density (J/m^3 = Pa). The contact's
half-width a is that of the bodies' overlap: the radius of the lens of two spheres in
3D (A = pi a^2), the half-chord of two discs in 2D (A = 2 a per unit of thickness; the
contact table holds k_c times the discs' thickness). Friction and rolling resistance see
only the repulsive normal force (LIGGGHTS ``tangential_reduce on``): cohesion pulls the
grains together, and the friction limit grows with the overlap it makes.
"""

from numba import njit


@njit(inline="always", cache=True)
def contact_radius_sq(ra, rb, delta):
    """a^2 of two bodies of radii ra, rb whose surfaces overlap by delta > 0: the lens of
    two spheres (discs) at distance ra + rb - delta, or with ra = 0 (a wall, or a wheel
    part the law sees as flat) a sphere cut by a plane, a^2 = delta (2 rb - delta)."""
    if ra == 0.0:
        a2 = delta * (2.0 * rb - delta)
    else:
        d = ra + rb - delta
        x = (d * d + ra * ra - rb * rb) / (2.0 * d)
        a2 = ra * ra - x * x
    return max(a2, 0.0)
