"""docs/design.md §3: the result does not depend on the thread count."""

import numba
import numpy as np

from ooc_dem.app.bed import settled_bed
from ooc_dem.engine.stepper import DomainStepper, Model
from ooc_dem.model.scenario import load_scenario
from ooc_dem.physics.layout import AX_X, AX_Y, HM_R, HS_T, SP_Z  # noqa: F401

from support.state import assert_same_state


def _run(bed, sc, threads, steps=500):
    numba.set_num_threads(threads)
    try:
        st = DomainStepper(bed.take(np.arange(len(bed))), Model.from_scenario(sc))
        st.advance(0, steps)
        return st
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


def test_one_and_two_threads_bit_identical():
    """500 steps of a ~5k-disc bed with 1 and 2 numba threads: every state array equal."""
    sc = load_scenario("bed-5000")
    bed = settled_bed(sc)
    assert len(bed) == 5000
    # the bed must actually be moving somewhere, or the test proves nothing
    one = _run(bed, sc, 1)
    two = _run(bed, sc, 2) if numba.config.NUMBA_NUM_THREADS >= 2 else None
    assert np.abs(one.p.vel[:, AX_Y]).max() > 0
    assert one.p.hist_n.mean() > 2.0
    if two is not None:
        assert_same_state(one.p, two.p)


def test_wheel_run_thread_independent():
    """The wheel's forces are summed canonically: same wheel records with 1 and 2 threads."""
    from ooc_dem.app.run_setup import place_wheel

    sc = load_scenario("quick", ["wheel.settle_time=0.0", "wheel.drawbar_ramp=0.0"])
    bed = settled_bed(sc)
    ws = place_wheel(sc, bed)
    ws[1] -= 0.008  # start with the lugs in the soil so contacts exist at once
    recs = []
    states = []
    for threads in (1, 2):
        numba.set_num_threads(threads)
        try:
            st = DomainStepper(bed.take(np.arange(len(bed))), Model.from_scenario(sc), ws, reorder=True)
            # force the parallel path even for this small bed
            import ooc_dem.engine.stepper as stp

            old = stp.SERIAL_BELOW
            stp.SERIAL_BELOW = 0
            try:
                recs.append(st.advance(0, 300))
            finally:
                stp.SERIAL_BELOW = old
            states.append(st)
        finally:
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    assert recs[0][:, 11].max() > 0, "the wheel never touched the soil"
    assert np.array_equal(recs[0], recs[1])
    assert_same_state(states[0].p, states[1].p)
    assert np.array_equal(states[0].ws, states[1].ws)


_TOY = """
import numpy as np
from numba import njit, prange

@njit(parallel=True)
def fill(a):
    for i in prange(a.shape[0]):
        a[i] = i
    return a

@njit(parallel=True)
def scale(a, c):
    for i in prange(a.shape[0]):
        a[i] *= c
    return a
"""


def test_serial_twins_have_no_parallel_region(tmp_path, monkeypatch):
    """Serial DDM runs one sub-domain per thread with the kernels' serial twins: a twin
    must not open a parallel region of its own (nested regions create threads every call).
    Every twin made, not only the first, is free of numba's parallel scheduler: numba once
    emptied the shared options dict on the first compilation, so the later twins came out
    parallel. The toy module is written here so that its twins compile afresh (LLVM of
    cached code cannot be inspected)."""
    from ooc_dem.physics.twins import serial_twin

    (tmp_path / "twin_toy.py").write_text(_TOY)
    monkeypatch.syspath_prepend(str(tmp_path))
    import twin_toy

    scheduled = "do_scheduling"  # numba's parallel launch (numba/parfors/parfor_lowering.py)
    twins = [serial_twin(twin_toy.fill, "fill_serial"), serial_twin(twin_toy.scale, "scale_serial")]
    a = np.zeros(8)
    twins[0](a)
    twins[1](a, 2.0)
    assert np.array_equal(a, 2.0 * np.arange(8))
    # the parallel originals do launch (so the check below can fail)
    twin_toy.fill(np.zeros(8))
    assert any(scheduled in ir for ir in twin_toy.fill.inspect_llvm().values())
    for twin in twins:
        irs = twin.inspect_llvm()
        assert irs and not any(scheduled in ir for ir in irs.values()), twin.__name__
