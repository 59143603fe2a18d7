"""One numba thread for a module of tiny systems: the machine has two cores that may be busy
with a long simulation, and spinning worker threads of a few particles are then very slow.
Results do not depend on the thread count (docs/design.md §3). A module uses it with
``from support.threads import one_numba_thread  # noqa: F401``."""

import numba
import pytest


@pytest.fixture(autouse=True, scope="module")
def one_numba_thread():
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(old)
