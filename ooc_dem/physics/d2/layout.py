"""Named layouts of the 2D kernels' own records (discs in the x-y plane, spin about z);
the records both dimensions share are ``physics.layout``'s.

Records:
- ``CONTACT_PARAMS``  contact parameters of one material pair, table cp[type_a, type_b]
- ``WALLS``           the bin's walls (floor y = 0, end walls x = 0 and x = length)
- ``PAIR_ROW``        one disc-disc contact of a step (phase 1 -> phase 2)
- ``BODY_ROW``        one disc-wall / disc-wheel-part contact of a step
- ``LawIn`` / ``LawOut`` the columns of a block of pairs for the block law
"""

from __future__ import annotations


import numpy as np

# the law blocks' sizes and the material types are the same in both dimensions
from ..layout import LAW_BLOCK, LAW_ROW, N_TYPES, field_indices, field_tuple, record_dtype  # noqa: F401

F8 = "<f8"

DIM = 2  # axes x (travel), y (vertical)
SPIN = 1  # the spin about z

# ----------------------------------------------------------- contact parameters
# no_tension = 1: the normal force is clamped at zero (the damping cannot pull); kc: the
# cohesion energy density times the discs' thickness (physics.cohesion; 0: none)
CONTACT_PARAMS = record_dtype(("kn", "ks", "zn", "zt", "mu", "mur", "zr", "no_tension", "kc"))
KN, KS, ZN, ZT, MU, MUR, ZR, NO_TENSION, KC = range(9)
N_FIELDS = len(CONTACT_PARAMS.names)


def linear_params(kn, ks, zn=0.0, zt=0.0, mu=0.0, mur=0.0, zr=0.0, no_tension=True, kc=0.0):
    """One CONTACT_PARAMS tuple (clamped at zero force unless no_tension=False; kc: the
    cohesion energy density times the discs' thickness)."""
    return (kn, ks, zn, zt, mu, mur, zr, float(no_tension), kc)


# ------------------------------------------------------------------- walls
WALLS = record_dtype(("length", "left", "right", "bottom"))
WALL_LENGTH, WALL_LEFT, WALL_RIGHT, WALL_BOTTOM = range(4)

# ---------------------------------------------------------------- contact rows
# one disc-disc pair (a = lower global id, b = higher) evaluated once: the force on b
# is (bx, by), a gets the exact negation; ta / tb are the torque terms of a / b
# (r_a ft - M, r_b ft + M); s, m the pair's new tangential and rolling springs
PAIR_ROW = record_dtype(("bx", "by", "ta", "tb", "s", "m"))
# one disc-body contact (the body is always the lower id): disc row index, body id,
# force and torque on the disc, new springs, and the torque on the wheel about its
# centre (wheel parts only; the wheel's force is (-bx, -by))
BODY_ROW = np.dtype(
    [("disc", "<i8"), ("pid", "<i8"), ("bx", F8), ("by", F8), ("tq", F8), ("s", F8), ("m", F8), ("wt", F8)]
)


def pair_row_layout(cp) -> np.dtype:
    """The pair-row layout of contact table cp: PAIR_ROW (one layout in 2D)."""
    return PAIR_ROW


# ------------------------------------------------------------ law blocks
# The touching disc pairs are evaluated in blocks (physics.produce, layout.LAW_BLOCK): a
# block's law inputs and results are rows of two (fields, layout.LAW_ROW) arrays. LawIn:
# what the law needs of a touching pair (the centres' offset b - a, relative velocity of
# b, spins, radii, masses, inertias, the springs of the last step), its material pair in
# the contact table (type_a * N_TYPES + type_b) and that pair's parameters
# (CONTACT_PARAMS fields in their order; filled only for a block of several material
# pairs); LawOut: the pair row's fields (PAIR_ROW).
LawIn = field_indices(
    "LawIn",
    ("dx", "dy", "vrx", "vry", "wa", "wb", "ra", "rb", "ma", "mb", "ia", "ib", "s_old", "m_old", "material")
    + CONTACT_PARAMS.names,
)
LawOut = field_indices("LawOut", PAIR_ROW.names)
N_LAW_IN = len(LawIn)
N_LAW_OUT = len(LawOut)
# one material pair's parameters as scalars (a block law's pair of several material pairs)
LawParams = field_tuple("LawParams", CONTACT_PARAMS.names)
