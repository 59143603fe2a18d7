"""The 2D pair law evaluated in blocks (physics.d2.forces.law_block), as in 3D: the
touching pairs' arguments are laid out as columns and one loop runs the law on them, which
the compiler turns into SIMD code. The per-pair arithmetic must stay contact.contact's:
every output of a block is compared, with np.array_equal, to the scalar law on the same pair
(as produce computed each pair before the blocks, and as the walls and the wheel still do),
for blocks of one material pair and of several, with and without rolling resistance, for
new, sticking and sliding contacts."""

from __future__ import annotations

import platform

import numpy as np
import pytest
from numba import njit

from ooc_dem.physics.d2 import forces as F
from ooc_dem.physics.d2 import layout as L
from ooc_dem.physics.d2.contact import contact


def _table():
    """Disc types 0 and 1 (the table's soil and wall rows stand in for two soils): 0-0 with
    rolling resistance, 1-1 and 0-1 without, other stiffness, damping and friction."""
    cp = np.zeros((L.N_TYPES, L.N_TYPES), L.CONTACT_PARAMS)
    params = {
        (0, 0): L.linear_params(5e4, 1.6e4, 0.3, 0.3, 0.5, 0.1, 0.3),
        (1, 1): L.linear_params(8e4, 2.0e4, 0.2, 0.25, 0.4, 0.0, 0.0),
        (0, 1): L.linear_params(6e4, 1.8e4, 0.25, 0.3, 0.45, 0.0, 0.0),
    }
    for (a, b), p in params.items():
        cp[a, b] = p
        cp[b, a] = p
    return cp


def _pairs(k, types_a, types_b, seed):
    """k touching pairs as produce lists them (LawIn columns up to the material pair)."""
    rng = np.random.default_rng(seed)
    args = np.zeros((L.N_LAW_IN, k))
    args[L.LawIn.ra] = rng.uniform(2e-3, 3e-3, k)
    args[L.LawIn.rb] = rng.uniform(2e-3, 3e-3, k)
    phi = rng.uniform(0.0, 2.0 * np.pi, k)
    dist = args[L.LawIn.ra] + args[L.LawIn.rb] - rng.uniform(1e-7, 2e-4, k)  # overlapping
    args[L.LawIn.dx] = dist * np.cos(phi)
    args[L.LawIn.dy] = dist * np.sin(phi)
    args[L.LawIn.vrx] = rng.normal(0.0, 0.05, k)
    args[L.LawIn.vry] = rng.normal(0.0, 0.05, k)
    args[L.LawIn.wa] = rng.normal(0.0, 20.0, k)
    args[L.LawIn.wb] = rng.normal(0.0, 20.0, k)
    args[L.LawIn.ma] = rng.uniform(2e-5, 9e-5, k)
    args[L.LawIn.mb] = rng.uniform(2e-5, 9e-5, k)
    args[L.LawIn.ia] = 0.5 * args[L.LawIn.ma] * args[L.LawIn.ra] ** 2
    args[L.LawIn.ib] = 0.5 * args[L.LawIn.mb] * args[L.LawIn.rb] ** 2
    # springs: new contacts (zero), small (sticking) and large (sliding) ones
    scale = rng.choice([0.0, 1e-4, 1e-2, 10.0], size=k)
    args[L.LawIn.s_old] = rng.normal(size=k) * scale
    args[L.LawIn.m_old] = rng.normal(size=k) * scale * 1e-3
    ta = rng.choice(types_a, size=k)
    tb = rng.choice(types_b, size=k)
    args[L.LawIn.material] = ta * L.N_TYPES + tb
    return args, ta, tb


@njit
def _blocks(args, cp, dt):
    """produce's way: blocks of at most LAW_BLOCK pairs run by law_rows (one record for a
    block of one material pair, else each pair's parameters); returns the LawOut columns."""
    k = args.shape[1]
    out = np.zeros((L.N_LAW_OUT, k))
    law_in = np.empty((L.N_LAW_IN, L.LAW_ROW))
    law_out = np.zeros((L.N_LAW_OUT, L.LAW_ROW))
    for first in range(0, k, L.LAW_BLOCK):
        m = min(k - first, L.LAW_BLOCK)
        uniform = True
        for t in range(m):
            for f in range(L.LawIn.material + 1):
                law_in[f, t] = args[f, first + t]
            uniform = uniform and law_in[L.LawIn.material, t] == law_in[L.LawIn.material, 0]
        F.law_rows(m, law_in, law_out, dt, cp, uniform)
        for f in range(L.N_LAW_OUT):
            for t in range(m):
                out[f, first + t] = law_out[f, t]
    return out


@njit
def _one_by_one(args, ta, tb, cp, dt):
    """Each pair alone, as produce computed it before the blocks (the contact geometry and
    effective quantities, then contact.contact), in LawOut columns."""
    k = args.shape[1]
    out = np.zeros((L.N_LAW_OUT, k))
    for t in range(k):
        a = args[:, t]
        dx, dy = a[L.LawIn.dx], a[L.LawIn.dy]
        ri, rb = a[L.LawIn.ra], a[L.LawIn.rb]
        mi, mb = a[L.LawIn.ma], a[L.LawIn.mb]
        ii, ib = a[L.LawIn.ia], a[L.LawIn.ib]
        d2 = dx * dx + dy * dy
        rs = ri + rb
        dd = np.sqrt(d2)
        delta = rs - dd
        nx = dx / dd
        ny = dy / dd
        fn, ft, s_new, mom, m_new = contact(
            cp[ta[t], tb[t]],
            nx,
            ny,
            delta,
            a[L.LawIn.vrx],
            a[L.LawIn.vry],
            a[L.LawIn.wa],
            a[L.LawIn.wb],
            ri,
            rb,
            mi * mb / (mi + mb),
            ii * ib / (ii + ib),
            ri * rb / (ri + rb),
            a[L.LawIn.s_old],
            a[L.LawIn.m_old],
            dt,
        )
        out[L.LawOut.bx, t] = fn * nx + ft * ny
        out[L.LawOut.by, t] = fn * ny - ft * nx
        out[L.LawOut.ta, t] = ri * ft - mom
        out[L.LawOut.tb, t] = rb * ft + mom
        out[L.LawOut.s, t] = s_new
        out[L.LawOut.m, t] = m_new
    return out


# one: blocks of one material pair (one record, with rolling resistance); several: each
# block mixes three material pairs, with and without rolling resistance
@pytest.mark.parametrize("blocks", ["one", "several"])
def test_block_law_gives_the_bits_of_the_pair_law(blocks):
    types_a, types_b = {"one": ([0], [0]), "several": ([0, 1], [0, 1])}[blocks]
    args, ta, tb = _pairs(700, types_a, types_b, seed=len(blocks))
    cp = _table()
    dt = 2e-6
    got = _blocks(args, cp, dt)
    want = _one_by_one(args, ta, tb, cp, dt)
    # the cases are there: new contacts, sliding ones (the spring cut to the Coulomb
    # limit), and several material pairs in one block when asked
    s_in = np.abs(args[L.LawIn.s_old])
    s_out = np.abs(got[L.LawOut.s])
    assert (s_in == 0).sum() > 50 and (s_out < 0.5 * s_in).sum() > 50
    assert (np.abs(got[L.LawOut.m]) > 0).sum() > 50
    several = len(np.unique((ta * L.N_TYPES + tb)[: L.LAW_BLOCK])) > 1
    assert several == (blocks == "several")
    for f in L.LawOut:
        assert np.array_equal(got[f], want[f]), f"{blocks}: {f.name} differs"


def test_block_law_compiles_to_simd():
    """The block loop is vectorised: packed square roots in its machine code."""
    args, _, _ = _pairs(8, [0], [0], seed=1)
    _blocks(args, _table(), 1e-6)
    asm = "".join(_blocks.inspect_asm().values())
    packed = {
        "x86_64": ("vsqrtpd", "sqrtpd"),
        "AMD64": ("vsqrtpd", "sqrtpd"),
        "aarch64": ("fsqrt\tv", "fsqrt\tz"),
        "arm64": ("fsqrt\tv",),
    }[platform.machine()]
    assert any(op in asm for op in packed), "the block law was not vectorised"
