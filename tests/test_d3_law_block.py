"""The 3D pair law evaluated in blocks (physics.d3.forces.law_block): the touching
pairs' arguments are laid out as columns and one loop runs the law on them, which the
compiler turns into SIMD code. The per-pair arithmetic must stay contact.contact's: every
output of a block is compared, with np.array_equal, to the scalar law on the same pair
(the code the walls and the wheel use), for both laws, a mixed block, both row layouts,
new, sticking and sliding contacts, with and without the no-tension clamp."""

from __future__ import annotations

import platform

import numpy as np
import pytest
from numba import njit

from ooc_dem.physics.d3 import forces as F
from ooc_dem.physics.d3 import layout as L
from ooc_dem.physics.d3.contact import contact

LINEAR, HERTZ = 0, 1  # the sphere types of the test's contact table


def _table():
    """Sphere types 0 and 1: 0-0 linear, 1-1 and 0-1 Hertz (with rolling resistance)."""
    return L.contact_table(
        {
            (LINEAR, LINEAR): L.linear_params(5e4, 1.6e4, 0.3, 0.3, 0.5, 0.05, 0.2),
            (HERTZ, HERTZ): L.hertz_params(1e8, 0.3, 0.5, mu=0.4, mur=0.1, zr=0.3, E2=1e8, nu2=0.3),
            (LINEAR, HERTZ): L.hertz_params(1e8, 0.3, 0.5, mu=0.4, mur=0.1, zr=0.3, E2=1e8, nu2=0.3, no_tension=True),
        }
    )


def _pairs(k, types_a, types_b, seed):
    """k touching pairs as produce lists them (LawIn columns up to the material pair)."""
    rng = np.random.default_rng(seed)
    args = np.zeros((L.N_LAW_IN, k))
    args[L.LawIn.ra] = rng.uniform(2e-3, 3e-3, k)
    args[L.LawIn.rb] = rng.uniform(2e-3, 3e-3, k)
    n = rng.normal(size=(k, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    dist = args[L.LawIn.ra] + args[L.LawIn.rb] - rng.uniform(1e-7, 2e-4, k)  # overlapping
    args[L.LawIn.dx], args[L.LawIn.dy], args[L.LawIn.dz] = (n * dist[:, None]).T
    for f in (L.LawIn.vrx, L.LawIn.vry, L.LawIn.vrz):
        args[f] = rng.normal(0.0, 0.05, k)
    for f in (L.LawIn.wax, L.LawIn.way, L.LawIn.waz, L.LawIn.wbx, L.LawIn.wby, L.LawIn.wbz):
        args[f] = rng.normal(0.0, 20.0, k)
    args[L.LawIn.ma] = rng.uniform(2e-5, 9e-5, k)
    args[L.LawIn.mb] = rng.uniform(2e-5, 9e-5, k)
    args[L.LawIn.ia] = 0.4 * args[L.LawIn.ma] * args[L.LawIn.ra] ** 2
    args[L.LawIn.ib] = 0.4 * args[L.LawIn.mb] * args[L.LawIn.rb] ** 2
    # springs: new contacts (zero), small (sticking) and large (sliding) ones
    scale = rng.choice([0.0, 1e-4, 1e-2, 10.0], size=k)
    for f in (L.LawIn.s_x, L.LawIn.s_y, L.LawIn.s_z):
        args[f] = rng.normal(size=k) * scale
    for f in (L.LawIn.m_x, L.LawIn.m_y, L.LawIn.m_z):
        args[f] = rng.normal(size=k) * scale * 1e-3
    ta = rng.choice(types_a, size=k)
    tb = rng.choice(types_b, size=k)
    args[L.LawIn.material] = ta * L.N_TYPES + tb
    return args, ta, tb


@njit
def _blocks(args, cp, dt, rows):
    """produce's way: blocks of at most LAW_BLOCK pairs run by law_rows (one record for a
    block of one material pair, else each pair's parameters); returns the LawOut columns."""
    k = args.shape[1]
    out = np.zeros((L.N_LAW_OUT, k))
    law_in = np.empty((L.N_LAW_IN, F.LAW_ROW))
    law_out = np.zeros((L.N_LAW_OUT, F.LAW_ROW))
    for first in range(0, k, F.LAW_BLOCK):
        m = min(k - first, F.LAW_BLOCK)
        uniform = True
        for t in range(m):
            for f in range(L.LawIn.material + 1):
                law_in[f, t] = args[f, first + t]
            uniform = uniform and law_in[L.LawIn.material, t] == law_in[L.LawIn.material, 0]
        F.law_rows(m, law_in, law_out, dt, rows, cp, uniform)
        for f in range(L.N_LAW_OUT):
            for t in range(m):
                out[f, first + t] = law_out[f, t]
    return out


@njit
def _one_by_one(args, ta, tb, cp, dt):
    """Each pair alone, as the scalar code computed it before the blocks (the contact
    geometry and effective quantities, then contact.contact, the law of the wall and wheel
    contacts), in LawOut columns."""
    k = args.shape[1]
    out = np.zeros((L.N_LAW_OUT, k))
    for t in range(k):
        a = args[:, t]
        dx, dy, dz = a[L.LawIn.dx], a[L.LawIn.dy], a[L.LawIn.dz]
        ri, rb = a[L.LawIn.ra], a[L.LawIn.rb]
        mi, mb = a[L.LawIn.ma], a[L.LawIn.mb]
        ii, ib = a[L.LawIn.ia], a[L.LawIn.ib]
        d2 = dx * dx + dy * dy + dz * dz
        rs = ri + rb
        dd = np.sqrt(d2)
        nx, ny, nz = dx / dd, dy / dd, dz / dd
        (fn, ftx, fty, ftz, snx, sny, snz, mox, moy, moz, mnx, mny, mnz) = contact(
            cp[ta[t], tb[t]],
            nx,
            ny,
            nz,
            rs - dd,
            a[L.LawIn.vrx],
            a[L.LawIn.vry],
            a[L.LawIn.vrz],
            a[L.LawIn.wax],
            a[L.LawIn.way],
            a[L.LawIn.waz],
            a[L.LawIn.wbx],
            a[L.LawIn.wby],
            a[L.LawIn.wbz],
            ri,
            rb,
            mi * mb / (mi + mb),
            ii * ib / (ii + ib),
            ri * rb / (ri + rb),
            a[L.LawIn.s_x],
            a[L.LawIn.s_y],
            a[L.LawIn.s_z],
            a[L.LawIn.m_x],
            a[L.LawIn.m_y],
            a[L.LawIn.m_z],
            dt,
        )
        out[L.LawOut.bx, t] = fn * nx - ftx
        out[L.LawOut.by, t] = fn * ny - fty
        out[L.LawOut.bz, t] = fn * nz - ftz
        out[L.LawOut.cx, t] = ny * ftz - nz * fty
        out[L.LawOut.cy, t] = nz * ftx - nx * ftz
        out[L.LawOut.cz, t] = nx * fty - ny * ftx
        out[L.LawOut.mox, t] = mox
        out[L.LawOut.moy, t] = moy
        out[L.LawOut.moz, t] = moz
        out[L.LawOut.sx, t] = snx
        out[L.LawOut.sy, t] = sny
        out[L.LawOut.sz, t] = snz
        out[L.LawOut.mx, t] = mnx
        out[L.LawOut.my, t] = mny
        out[L.LawOut.mz, t] = mnz
    return out


ROLLING_FIELDS = ("mox", "moy", "moz", "mx", "my", "mz")


# linear / hertz: blocks of one material pair (one record); hertz-2 / mixed: several
# material pairs, one law or both
@pytest.mark.parametrize("blocks", ["linear", "hertz", "hertz-2", "mixed"])
@pytest.mark.parametrize("layout", ["rolling", "sliding"])
def test_block_law_gives_the_bits_of_the_pair_law(blocks, layout):
    types_a, types_b = {
        "linear": ([LINEAR], [LINEAR]),
        "hertz": ([HERTZ], [HERTZ]),
        "hertz-2": ([HERTZ], [HERTZ, LINEAR]),
        "mixed": ([LINEAR, HERTZ], [LINEAR, HERTZ]),
    }[blocks]
    args, ta, tb = _pairs(700, types_a, types_b, seed=len(blocks) + len(layout))
    cp = _table()
    dt = 2e-6
    rows = np.zeros(1, L.PAIR_ROW_ROLLING if layout == "rolling" else L.PAIR_ROW_SLIDING)
    got = _blocks(args, cp, dt, rows)
    want = _one_by_one(args, ta, tb, cp, dt)
    # the cases are there: new contacts, sliding ones (the spring cut to the Coulomb
    # limit), and both laws in one block when mixed
    s_in = np.sqrt(args[L.LawIn.s_x] ** 2 + args[L.LawIn.s_y] ** 2 + args[L.LawIn.s_z] ** 2)
    s_out = np.sqrt(got[L.LawOut.sx] ** 2 + got[L.LawOut.sy] ** 2 + got[L.LawOut.sz] ** 2)
    assert (s_in == 0).sum() > 50 and (s_out < 0.5 * s_in).sum() > 50
    laws = _table()["law"][ta, tb]
    assert len(np.unique(laws[: F.LAW_BLOCK])) == (2 if blocks == "mixed" else 1)
    several = len(np.unique((ta * L.N_TYPES + tb)[: F.LAW_BLOCK])) > 1
    assert several == (blocks not in ("linear", "hertz"))
    for f in L.LawOut:
        if layout == "sliding" and f.name in ROLLING_FIELDS:
            continue  # not computed for a layout without rolling parts (never read)
        assert np.array_equal(got[f], want[f]), f"{blocks}/{layout}: {f.name} differs"


def test_block_law_compiles_to_simd():
    """The block loop is vectorised (packed square roots in its machine code): the LLVM
    option set in ooc_dem.physics is what allows it."""
    rows = np.zeros(1, L.PAIR_ROW_SLIDING)
    args, _, _ = _pairs(8, [LINEAR], [LINEAR], seed=1)
    _blocks(args, _table(), 1e-6, rows)
    asm = "".join(_blocks.inspect_asm().values())
    packed = {
        "x86_64": ("vsqrtpd", "sqrtpd"),
        "AMD64": ("vsqrtpd", "sqrtpd"),
        "aarch64": ("fsqrt\tv", "fsqrt\tz"),
        "arm64": ("fsqrt\tv",),
    }[platform.machine()]
    assert any(op in asm for op in packed), "the block law was not vectorised"
