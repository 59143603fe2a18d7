"""A pair list that must grow is let go before its successor is allocated: at 1M discs the
list is ~120 bytes a disc, and holding both would put that on top of the peak RSS. The
growth never changes a result bit (docs/design.md §3)."""

import tracemalloc

import numpy as np
import pytest

from ooc_dem.app.bed import settled_bed
from ooc_dem.engine.stepper import PAIR_HEADROOM, DomainStepper, Model
from ooc_dem.model.scenario import load_scenario

from support.state import assert_same_state

LIST = ("pair_b", "pair_a", "inc_k", "on", "rows")


def _list_bytes(st) -> int:
    return sum(getattr(st, k).nbytes for k in LIST)


def _stepper():
    sc = load_scenario("bed-5000")
    bed = settled_bed(sc)
    st = DomainStepper(bed.take(np.arange(len(bed))), Model.from_scenario(sc))
    st.advance(0, 20)
    return st


def _traced_rise(fn) -> int:
    """Peak traced bytes above those held before fn() (NumPy's allocations are traced; the
    caller started tracing before making what fn frees, or its freeing would go unseen)."""
    before = tracemalloc.get_traced_memory()[0]
    tracemalloc.reset_peak()
    fn()
    return tracemalloc.get_traced_memory()[1] - before


@pytest.fixture
def traced():
    tracemalloc.start()
    yield
    tracemalloc.stop()


def test_grow_lets_the_old_list_go_first(traced):
    st = _stepper()
    old = _list_bytes(st)
    rise = _traced_rise(lambda: st._grow_pairs(2 * st.pairs))
    new = _list_bytes(st)
    assert new > 1.9 * old
    # old and new together would rise by `new`; let go first, by new - old
    assert rise <= new - old + 64 * 1024, (rise, new, old)


def test_a_list_regrown_inside_a_run_is_not_held_twice_and_keeps_the_bits(traced):
    ref = _stepper()
    st = _stepper()
    # a list just too short for the next build: the run counts, grows, builds again
    st._grow_pairs(int((st.pairs - 200) / PAIR_HEADROOM))
    assert st.pair_b.shape[0] < st.pairs
    st._built = False
    old = _list_bytes(st)
    rise = _traced_rise(lambda: st.advance(20, 30))
    new = _list_bytes(st)
    assert st.pair_b.shape[0] >= st.pairs
    assert rise < new - old + old // 2, (rise, new, old)  # not new + old
    ref.advance(20, 30)
    assert_same_state(ref.p, st.p)
