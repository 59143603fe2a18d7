"""Particles declares its fields (for readers and type checkers) in the state's one order."""

import numpy as np

from ooc_dem.model.state import ALL_FIELDS, Particles, fields


def test_declared_fields_are_the_states_fields_in_order():
    assert tuple(Particles.__annotations__) == ALL_FIELDS == tuple(Particles.__slots__)
    for dim in (2, 3):
        p = Particles.empty(4, dim)
        for name, (dt, tail) in fields(dim, p.hist_cap).items():
            a = getattr(p, name)
            assert isinstance(a, np.ndarray) and a.dtype == dt and a.shape == (4, *tail)
