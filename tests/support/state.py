"""Particle states compared bit for bit."""

import numpy as np


def state_arrays(p):
    """Every state array of a Particles set, sorted by id, history slots beyond the count zeroed."""
    from ooc_dem.model.state import clean_history

    q = p.sorted_by_id()
    clean_history(q)
    return q.arrays()


def assert_same_state(a, b):
    sa, sb = state_arrays(a), state_arrays(b)
    assert sa.keys() == sb.keys()
    for k in sa:
        assert sa[k].dtype == sb[k].dtype, k
        assert np.array_equal(sa[k], sb[k]), f"state array {k!r} differs"
