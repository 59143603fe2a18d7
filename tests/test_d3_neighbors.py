"""The 3D half pair list + CSR index against brute force."""
import numpy as np
import pytest

from ooc_dem.physics.d3 import layout as L
from ooc_dem.physics.d3.neighbors import build_pairs, spatial_order
from ooc_dem.physics.d3.sim import EngineError, Sim, make_spheres


@pytest.mark.parametrize("far", [False, True])
def test_half_list_and_csr_match_brute_force(far):
    """Every pair within r_i + r_j + skin exactly once, stored at the lower global id,
    partners ascending by id; the CSR index lists each sphere's lower-id partners in
    ascending id and points at the right slots; a too-small capacity returns the count
    and fills nothing. far: a few spheres 1 km away (the grid is enlarged, still exact)."""
    rng = np.random.default_rng(5)
    n = 600
    pos = rng.uniform(0, 0.1, (n, 3))
    if far:
        pos[:5] += 1000.0 * rng.normal(size=(5, 3))
    r = rng.uniform(0.003, 0.005, n)
    gid = rng.permutation(n).astype(np.int64) * 3 + 11      # ids unrelated to the order
    skin = 0.001
    d = np.sqrt(((pos[:, None] - pos[None]) ** 2).sum(-1))
    near = (d < r[:, None] + r[None] + skin) & ~np.eye(n, dtype=bool)
    expect = {(min(gid[i], gid[j]), max(gid[i], gid[j])) for i, j in zip(*np.nonzero(near))}
    half_off = np.zeros(n + 1, np.int64)
    inc_off = np.zeros(n + 1, np.int64)
    small = np.zeros(3, np.int64)
    pref = np.zeros((n, 3))
    npairs = build_pairs(pos, r, gid, n, skin, half_off, small, small.copy(), inc_off, small.copy(), pref)
    assert npairs == len(expect) and not pref.any()
    pair_b = np.zeros(npairs, np.int64)
    pair_a = np.zeros(npairs, np.int64)
    inc_k = np.zeros(npairs, np.int64)
    assert build_pairs(pos, r, gid, n, skin, half_off, pair_b, pair_a, inc_off, inc_k, pref) == npairs
    got = set()
    for i in range(n):
        bs = pair_b[half_off[i]:half_off[i + 1]]
        assert (gid[bs] > gid[i]).all() and (np.diff(gid[bs]) > 0).all()
        assert (pair_a[half_off[i]:half_off[i + 1]] == i).all()
        got |= {(gid[i], gid[b]) for b in bs}
        slots = inc_k[inc_off[i]:inc_off[i + 1]]
        assert (pair_b[slots] == i).all()
        assert (np.diff(gid[pair_a[slots]]) > 0).all()
    assert got == expect and inc_off[-1] == npairs
    assert np.array_equal(pref, pos)
    perm = spatial_order(pos, n, 0.012)
    assert np.array_equal(np.sort(perm), np.arange(n))
