"""Named layouts of the 3D kernels' own records (spheres; x = travel, y = vertical,
z = across the bin); the records both dimensions share are ``physics.layout``'s.

As there, every packed vector is a structured dtype, kernels read and write by field
name through record views (``record(flat, DTYPE)``), no kernel indexes a column by
number.

Records:
- ``CONTACT_PARAMS``  one material pair, table cp[type_a, type_b]; ``law`` selects
                      LAW_LINEAR (kn, ks, zn, zt, mu, mur, zr: the 2D law's parameters)
                      or LAW_HERTZ (Hertz-Mindlin, Tsuji / DEM-Engine
                      ``FullHertzianForceModel`` / LAMMPS ``hertz/material`` form:
                      estar, gstar, beta, mu, mur, zr; see ``hertz_params``)
- ``WALLS``           box walls: floor y=0, end walls x=0 / x=length, side walls
                      z=0 / z=width, each with an on-flag (frictional, table type T_WALL)
- ``WHEEL_GEOMETRY`` / ``WHEEL_CONTROLS`` / ``WHEEL_STATE`` / ``WHEEL_RECORD``: the 2D
                      records (the wheel's axle is along z in both dimensions; 3D reads
                      the geometry's width and z0: rim cylinder and lug plates span
                      z0 - width/2 .. z0 + width/2)
- ``PAIR_ROW_ROLLING`` / ``PAIR_ROW_SLIDING``  one sphere-sphere contact of a step
                      (phase 1 -> phase 2), with / without the rolling parts
                      (``pair_row_layout(cp)`` picks one from the contact table)
- ``BODY_ROW``        one sphere-wall / sphere-wheel-part contact of a step

Partner ids of the walls (negative, so they sort before every sphere, ascending =
the sum order): back (z=width) -5, front (z=0) -4, right (x=length) -3,
left (x=0) -2, bottom (y=0) -1 (the 2D ids are kept for the 2D walls); the wheel's
parts have the 2D ids (lug k: ID_LUG0 + k = -1000 + k, rim ID_RIM = -100), below every wall.
"""

from __future__ import annotations

import math

import numpy as np

# the records both dimensions share (physics.layout): the wheel's, the error flags, the
# material types, the law blocks' sizes, the partner ids of the wheel's parts and of the
# walls 2D has too
from .. import exactmath
from ..layout import (
    ERR_BODY_CAPACITY,  # noqa: F401
    ERR_HIST_OVERFLOW,  # noqa: F401
    ERR_PAIR_CAPACITY,  # noqa: F401
    ERRORS,  # noqa: F401
    ID_LUG0,  # noqa: F401
    ID_RIM,  # noqa: F401
    ID_WALL_BOTTOM,  # noqa: F401
    ID_WALL_LEFT,  # noqa: F401
    ID_WALL_RIGHT,  # noqa: F401
    LAW_BLOCK,  # noqa: F401
    LAW_ROW,  # noqa: F401
    N_ERR,  # noqa: F401
    N_TYPES,
    T_SOIL,  # noqa: F401
    T_WALL,  # noqa: F401
    T_WHEEL,  # noqa: F401
    WHEEL_CONTROLS,  # noqa: F401
    WHEEL_GEOMETRY,  # noqa: F401
    WHEEL_RECORD,  # noqa: F401
    WHEEL_STATE,  # noqa: F401
    record,  # noqa: F401
    record_dtype,
)
from ..layout import Bodies, Discs, Forces, KernelParams, Pairs, field_indices, field_tuple  # noqa: F401

F8 = "<f8"

DIM = 3  # axes x (travel), y (vertical), z (across the bin)
SPIN = 3  # the spin about x, y and z


# ----------------------------------------------------------- contact parameters
LAW_LINEAR = 0
LAW_HERTZ = 1
# no_tension = 1: the normal force is clamped at zero (the 2D law); 0: the damping
# term may pull while the spheres overlap (LAMMPS granular without ``limit_damping``),
# which is what makes the restitution of the Tsuji law exactly the target e
# (validation-3d.md section 3; clamped, e = 0.3 gives 0.397). Friction and rolling
# limits use max(Fn, 0).
# kc: the cohesion energy density (physics.cohesion; 0: none).
CONTACT_PARAMS = record_dtype(
    ("law", "kn", "ks", "zn", "zt", "mu", "mur", "zr", "estar", "gstar", "beta", "no_tension", "kc")
)
N_FIELDS = len(CONTACT_PARAMS.names)

# ------------------------------------------------------------------- walls
WALLS = record_dtype(("length", "width", "left", "right", "bottom", "front", "back"))

# -------------------------------------------------------------- partner ids
# the side walls (the end walls, the floor and the wheel's parts have the ids of 2D)
ID_WALL_BACK = -5
ID_WALL_FRONT = -4

# history widths of the 3D law (tangential spring force, rolling spring moment)
S_WIDTH = 3
M_WIDTH = 3

# ---------------------------------------------------------------- contact rows
# one sphere-sphere pair (a = lower global id, b = higher), evaluated once: force on b
# (bx, by, bz) (a gets the exact negation), the lever-free torque n x Ft (cx, cy, cz:
# phase 2 makes a's torque r_a c - M and b's r_b c + M from its own radius, the same
# arithmetic as in phase 1, so the bits do not depend on where it is done), the
# rolling moment on b (mox, moy, moz) and the pair's new tangential spring (s*) and
# rolling spring (m*). Without rolling resistance in the contact table (every mur = 0)
# the moment and rolling spring are exactly zero: the row then leaves them out
# (PAIR_ROW_SLIDING, 72 bytes against 120), the kernels read them as zeros.
PAIR_ROW_ROLLING = record_dtype(
    ("bx", "by", "bz", "cx", "cy", "cz", "mox", "moy", "moz", "sx", "sy", "sz", "mx", "my", "mz")
)
PAIR_ROW_SLIDING = record_dtype(("bx", "by", "bz", "cx", "cy", "cz", "sx", "sy", "sz"))
PAIR_ROW = PAIR_ROW_ROLLING  # the general layout (any contact table)


def pair_row_layout(cp) -> np.dtype:
    """The pair-row layout of contact table cp (CONTACT_PARAMS records [type_a, type_b]):
    PAIR_ROW_SLIDING when no material pair has rolling resistance, else PAIR_ROW_ROLLING."""
    return PAIR_ROW_ROLLING if bool(np.any(np.asarray(cp["mur"]) > 0.0)) else PAIR_ROW_SLIDING


# ------------------------------------------------------------ law blocks
# The touching sphere pairs are evaluated in blocks (forces.law_block): a block's law
# inputs and results are rows of two (fields, LAW_BLOCK) arrays (structure of arrays),
# so the compiler runs the law on several pairs at once (SIMD). Each pair's arithmetic is
# ``contact.contact``'s, with no reordering, so its bits are those of the pair evaluated alone.
# LawIn: what the law needs of a touching pair (the centres' offset b - a, relative
# velocity, spins, radii, masses, inertias, stored springs), its material pair in the contact
# table (type_a * N_TYPES + type_b) and that pair's parameters (the CONTACT_PARAMS fields,
# in their order; filled only for a block of several material pairs: an indexed load in
# the loop would stop the SIMD); LawOut: the pair row's fields (PAIR_ROW_ROLLING).
LawIn = field_indices(
    "LawIn",
    (
        "dx",
        "dy",
        "dz",
        "vrx",
        "vry",
        "vrz",
        "wax",
        "way",
        "waz",
        "wbx",
        "wby",
        "wbz",
        "ra",
        "rb",
        "ma",
        "mb",
        "ia",
        "ib",
        "s_x",
        "s_y",
        "s_z",
        "m_x",
        "m_y",
        "m_z",
        "material",
    )
    + CONTACT_PARAMS.names,
)
LawOut = field_indices("LawOut", PAIR_ROW_ROLLING.names)
N_LAW_IN = len(LawIn)
N_LAW_OUT = len(LawOut)
# one material pair's parameters as scalars (the fields of CONTACT_PARAMS): what the law
# reads from a table record
LawParams = field_tuple("LawParams", CONTACT_PARAMS.names)


# one sphere-wall or sphere-wheel-part contact (the body is always a): sphere row index,
# body id, force and torque on the sphere, new springs, and (wheel parts only) the torque
# on the wheel about its axle z (the wheel's force is (-bx, -by); its z force goes to the
# axle)
BODY_ROW = np.dtype(
    [("disc", "<i8"), ("pid", "<i8")]
    + [(n, F8) for n in ("bx", "by", "bz", "tx", "ty", "tz", "sx", "sy", "sz", "mx", "my", "mz", "wt")]
)

# ------------------------------------------------------- kernel argument records
# the shared named tuples of physics.layout: Discs (pos/vel/spin (N, 3), hist_s/hist_m
# (N, C, 3)), Pairs (ref: build positions (N, 3)), Bodies (rows: BODY_ROW of this module),
# KernelParams (cp: CONTACT_PARAMS and walls: WALLS of this module; gravity (3,)), Forces
# (force, torque (N, 3))


# ------------------------------------------------------- parameter helpers
def effective_modulus(E1, nu1, E2=math.inf, nu2=0.0):
    """E*: 1/E* = (1 - nu1^2)/E1 + (1 - nu2^2)/E2 (E2 = inf: rigid wall)."""
    inv = (1.0 - nu1 * nu1) / E1 + (0.0 if math.isinf(E2) else (1.0 - nu2 * nu2) / E2)
    return 1.0 / inv


def effective_shear_modulus(E1, nu1, E2=math.inf, nu2=0.0):
    """G*: 1/G* = (2 - nu1)/G1 + (2 - nu2)/G2, G = E / (2 (1 + nu)) (E2 = inf: rigid)."""
    G1 = E1 / (2.0 * (1.0 + nu1))
    inv = (2.0 - nu1) / G1
    if not math.isinf(E2):
        inv += (2.0 - nu2) / (E2 / (2.0 * (1.0 + nu2)))
    return 1.0 / inv


def beta_of_restitution(e):
    """beta = ln e / sqrt(ln^2 e + pi^2) (<= 0; 0 for e = 1); ln correctly rounded (the same
    on every machine: exactmath)."""
    if e >= 1.0:
        return 0.0
    le = exactmath.ln(e)
    return le / math.sqrt(le * le + math.pi * math.pi)


def zeta_of_restitution(e):
    """Damping ratio of the linear law giving restitution e (unclamped): -ln e / sqrt(pi^2 + ln^2 e)."""
    return -beta_of_restitution(e)


def linear_params(kn, ks, zn=0.0, zt=0.0, mu=0.0, mur=0.0, zr=0.0, no_tension=True, kc=0.0):
    """One CONTACT_PARAMS tuple of the linear spring-dashpot law (the 2D law's parameters;
    clamped at zero force like the 2D law unless no_tension=False; kc: cohesion energy
    density)."""
    return (LAW_LINEAR, kn, ks, zn, zt, mu, mur, zr, 0.0, 0.0, 0.0, float(no_tension), kc)


def hertz_params(E1, nu1, e, mu=0.0, mur=0.0, zr=0.0, E2=math.inf, nu2=0.0, no_tension=False, kc=0.0):
    """One CONTACT_PARAMS tuple of Hertz-Mindlin from Young's moduli, Poisson ratios and
    restitution e (validation-3d.md section 3); E2 = inf for a rigid wall. By default
    the damping may pull while overlapping (restitution = e exactly); no_tension=True
    clamps the force at zero (the restitution is then higher than e at low e)."""
    return (
        LAW_HERTZ,
        0.0,
        0.0,
        0.0,
        0.0,
        mu,
        mur,
        zr,
        effective_modulus(E1, nu1, E2, nu2),
        effective_shear_modulus(E1, nu1, E2, nu2),
        beta_of_restitution(e),
        float(no_tension),
        kc,
    )


def contact_table(pairs: dict) -> np.ndarray:
    """CONTACT_PARAMS table [N_TYPES, N_TYPES] from {(type_a, type_b): params tuple}
    (symmetric)."""
    cp = np.zeros((N_TYPES, N_TYPES), CONTACT_PARAMS)
    for (a, b), vals in pairs.items():
        cp[a, b] = vals
        cp[b, a] = vals
    return cp


def walls_record(length, width, left=True, right=True, bottom=True, front=True, back=True):
    w = np.zeros(1, WALLS)
    w[0] = (length, width, float(left), float(right), float(bottom), float(front), float(back))
    return w
