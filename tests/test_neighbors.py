"""The half pair list + CSR index (physics.d2.neighbors in 2D, physics.d3.neighbors in 3D)
against brute force."""

import numpy as np
import pytest

from ooc_dem.physics.d2 import neighbors as n2
from ooc_dem.physics.d3 import neighbors as n3

BUILDS = {"2d": n2.build_pairs, "2d-serial": n2.build_pairs_serial, "3d": n3.build_pairs}


@pytest.mark.parametrize("build", list(BUILDS))
@pytest.mark.parametrize("bed", ["loose", "clustered", "far"])
def test_half_list_and_csr_match_brute_force(bed, build):
    """Every pair within r_i + r_j + skin exactly once, stored at the lower global id,
    partners ascending by id; the CSR index lists each particle's lower-id partners in
    ascending id and points at the right slots; a too-small capacity returns the count
    and fills nothing. clustered: 60 particles piled on one point (one cell far fuller
    than the rest: the scan's candidate buffers are sized from the fullest cell); far: a
    few particles 1 km away (the grid is bounded or enlarged, still exact)."""
    dim = 3 if build == "3d" else 2
    rng = np.random.default_rng(7)
    n = 900 if dim == 2 else 600
    side, r_lo, r_hi, skin = (0.15, 0.0018, 0.0022, 0.0006) if dim == 2 else (0.1, 0.003, 0.005, 0.001)
    pos = rng.uniform(0, side, (n, dim))
    if bed == "clustered":
        pos[:60] = 0.5 * side + 1e-4 * rng.normal(size=(60, dim))
    if bed == "far":
        pos[:5] += 1000.0 * rng.normal(size=(5, dim))
    r = rng.uniform(r_lo, r_hi, n)
    gid = rng.permutation(n).astype(np.int64) * 3 + 11  # ids unrelated to the order
    d = np.sqrt(((pos[:, None] - pos[None]) ** 2).sum(-1))
    near = (d < r[:, None] + r[None] + skin) & ~np.eye(n, dtype=bool)
    expect = {(min(gid[i], gid[j]), max(gid[i], gid[j])) for i, j in zip(*np.nonzero(near))}
    half_off = np.zeros(n + 1, np.int32)
    inc_off = np.zeros(n + 1, np.int32)
    small = np.zeros(3, np.int32)
    ref = np.zeros((n, dim))
    npairs = BUILDS[build](pos, r, gid, n, skin, half_off, small, small.copy(), inc_off, small.copy(), ref)
    assert npairs == len(expect) and not ref.any()
    pair_b = np.zeros(npairs, np.int32)
    pair_a = np.zeros(npairs, np.int32)
    inc_k = np.zeros(npairs, np.int32)
    assert BUILDS[build](pos, r, gid, n, skin, half_off, pair_b, pair_a, inc_off, inc_k, ref) == npairs
    got = set()
    for i in range(n):
        bs = pair_b[half_off[i] : half_off[i + 1]]
        assert (gid[bs] > gid[i]).all() and (np.diff(gid[bs]) > 0).all()
        assert (pair_a[half_off[i] : half_off[i + 1]] == i).all()
        got |= {(gid[i], gid[b]) for b in bs}
        slots = inc_k[inc_off[i] : inc_off[i + 1]]
        assert (pair_b[slots] == i).all()
        assert (np.diff(gid[pair_a[slots]]) > 0).all()
    assert got == expect and inc_off[-1] == npairs
    assert np.array_equal(ref, pos)
    order = (n2 if dim == 2 else n3).spatial_order(pos, n, 2 * r_hi + skin)
    assert np.array_equal(np.sort(order), np.arange(n))
