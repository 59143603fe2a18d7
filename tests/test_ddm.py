"""Serial domain decomposition is bit-identical to the monolithic run (docs/design.md §3-4)."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ooc_dem.app.bed import initial_fill, settled_bed
from ooc_dem.app.run_setup import place_wheel
from ooc_dem.engine.stepper import DomainStepper, Model
from ooc_dem.engine.sweep import sweep_run
from ooc_dem.physics.layout import ID_WALL_BOTTOM
from ooc_dem.model.scenario import load_scenario
from ooc_dem.model.state import Particles
from ooc_dem.physics.layout import AX_X, AX_Y, HM_R, HS_T, SP_Z  # noqa: F401

from support.cli import cli_in_process, run_cli
from support.state import assert_same_state

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow


def mono(sc, p, ws, steps):
    st_ = DomainStepper(p.take(np.arange(len(p))), Model.from_scenario(sc), ws)
    rec = st_.advance(0, steps)
    return st_.p, st_.ws, rec


@pytest.fixture(scope="module")
def bare_bed():
    sc = load_scenario("bed-2330", ["decomposition.policy=equal"])
    return sc, settled_bed(sc)


@pytest.mark.parametrize("domains", [1, 2, 3, 6, 11])
def test_bare_bed_ddm_equals_monolithic(bare_bed, domains):
    sc, bed = bare_bed
    ref, _, _ = mono(sc, bed, None, 120)
    out, _, _, eng = sweep_run(sc, bed, np.zeros(6), 120, domains=domains, block=1)
    assert eng.D == domains
    assert_same_state(ref, out)
    # every slab owned discs, and a slab's residents are its discs plus a thin halo
    assert eng.resident_max < len(bed) or domains == 1


@pytest.fixture(scope="module")
def wheel_case():
    # a fast slip-controlled wheel on the quick rig (0.32 m/s forward), so that the
    # wheel slab is redefined several times within a short run
    sc = load_scenario(
        "quick",
        [
            "wheel.omega=4.0",
            "wheel.control=slip",
            "wheel.slip=0.2",
            "wheel.settle_time=0.01",
            "wheel.drop_gap=0.0",
            "wheel.travel_time=0.05",
            "decomposition.margin=0.001",
        ],
    )
    bed = settled_bed(sc)
    ws = place_wheel(sc, bed)
    steps = 6000
    ref = mono(sc, bed, ws, steps)
    return sc, bed, ws, steps, ref


@pytest.mark.parametrize("domains,block", [(1, 5), (2, 5), (3, 1), (6, 5), (11, 3)])
def test_wheel_run_ddm_equals_monolithic(wheel_case, domains, block):
    sc, bed, ws, steps, (ref_p, ref_ws, ref_rec) = wheel_case
    p, w, rec, eng = sweep_run(sc, bed, ws, steps, domains=domains, block=block)
    assert ref_rec[:, 11].max() > 0, "the wheel never touched the soil"
    assert_same_state(ref_p, p)
    assert np.array_equal(ref_ws, w)
    assert np.array_equal(ref_rec, rec)
    if domains > 1:
        # the initial decomposition plus at least two redefinitions as the wheel travelled
        assert len(eng.redecompositions) >= 3, eng.redecompositions


@pytest.mark.parametrize("block", [1, 2])
@pytest.mark.parametrize("membership_skin,rebuilds", [(1e-7, "often"), (1.0, "never")])
def test_persistent_subdomains_any_membership_skin(wheel_case, membership_skin, rebuilds, block):
    """Serial DDM keeps its sub-domains between sweeps and rebuilds their local sets only
    when a disc moved beyond the membership skin: rebuilding almost every sweep (tiny
    skin) or never (every slab holds the whole bin) gives the monolithic bits, with
    one-step sweeps (every pair row kept between sweeps) and two-step ones."""
    sc, bed, ws, steps, (ref_p, ref_ws, ref_rec) = wheel_case
    p, w, rec, eng = sweep_run(sc, bed, ws, steps, domains=6, block=block, membership_skin=membership_skin)
    assert_same_state(ref_p, p)
    assert np.array_equal(ref_ws, w)
    assert np.array_equal(ref_rec, rec)
    builds = eng.info()["local_set_builds"]
    if rebuilds == "often":
        assert builds > steps // block // 4, builds
    else:
        assert builds == len(eng.redecompositions), builds


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cuts=st.lists(st.floats(0.0, 0.2, allow_nan=False), min_size=0, max_size=7), block=st.integers(1, 4))
def test_random_decomposition_equals_monolithic(cuts, block):
    """Slab bounds anywhere (through contacts, empty slabs, duplicate bounds) on a falling fill."""
    sc = load_scenario("quick", ["soil.n=300", "bin.length=0.2", "bin.height=0.1", "wheel.enabled=false"])
    p = initial_fill(sc)
    steps = 24
    ref, _, _ = mono(sc, p, None, steps)
    bounds = np.array([-np.inf, *sorted(cuts), np.inf])
    out, _, _, eng = sweep_run(sc, p, np.zeros(6), steps, bounds=bounds, block=block)
    assert_same_state(ref, out)


def test_migrating_disc_keeps_its_contact_history():
    """A disc sliding on the floor crosses a slab boundary: its loaded tangential spring survives."""
    sc = load_scenario("bed-1200", ["physics.gravity=9.8"])
    r = 0.002
    p = Particles.new(np.array([[0.05, r - 2e-6]]), np.array([r]), 2650.0, 0.1)
    p.vel[:, AX_X][:] = 0.05  # sliding: friction at the Coulomb limit
    boundary = 0.05 + 0.05 * 300 * 1e-5 * 0.5  # crossed about half way through the run
    steps = 300
    ref, _, _ = mono(sc, p, None, steps)
    out, _, _, eng = sweep_run(sc, p, np.zeros(6), steps, bounds=[-np.inf, boundary, np.inf], block=1)
    assert ref.pos[:, AX_X][0] > boundary > p.pos[:, AX_X][0]
    assert_same_state(ref, out)
    q = out
    k = list(q.hist_id[0, : q.hist_n[0]]).index(ID_WALL_BOTTOM)
    mu_fn = 0.5 * q.mass[0] * 9.8
    assert abs(q.hist_s[:, :, HS_T][0, k]) > 0.5 * mu_fn, "tangential spring lost across the boundary"


def test_cli_ddm_and_compare(tmp_path):
    """`--mode ddm` through the CLI gives the monolithic hash; `compare` says so."""
    a, b = tmp_path / "mono", tmp_path / "ddm"
    args = ["--steps", "150", "--no-progress", "--no-figures"]
    run_cli("run", "quick", "--out", a, *args, check=True)
    run_cli("run", "quick", "--out", b, "--mode", "ddm", "--domains", "4", *args, check=True)
    ha = cli_in_process("checkpoint", "hash", a, check=True).stdout.strip()
    hb = cli_in_process("checkpoint", "hash", b, check=True).stdout.strip()
    assert ha == hb
    cmp = cli_in_process("compare", a, b, check=True).stdout
    assert "BIT-IDENTICAL" in cmp


@pytest.mark.parametrize("threads", [1, 2])
def test_compiled_sweeps_give_the_monolithic_bits(threads):
    """Serial DDM runs whole sweeps in one compiled call (live.run_sweeps), the
    sub-domains side by side on the threads: the engine must take that path and keep
    the bits."""
    import numba
    from ooc_dem.model.state import state_hash

    sc = load_scenario(
        "quick", ["wheel.settle_time=0.0", "wheel.drop_gap=0.0", "wheel.omega=5.0", "decomposition.margin=0.001"]
    )
    bed = settled_bed(sc)
    ws = place_wheel(sc, bed)
    before = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        ref_p, ref_ws, _ = mono(sc, bed, ws, 600)
        p, w, _, eng = sweep_run(sc, bed.take(np.arange(len(bed))), ws, 600, domains=6, block=1)
    finally:
        numba.set_num_threads(before)
    assert eng.compiled_sweeps
    assert state_hash(p, w, 600) == state_hash(ref_p, ref_ws, 600)
    assert np.array_equal(p.sorted_by_id().hist_s, ref_p.sorted_by_id().hist_s)


def test_one_step_sweeps_keep_rows_through_pair_rebuilds(wheel_case, monkeypatch):
    """One-step sweeps keep every pair row from sweep to sweep and copy no history
    between them (live_kernels._run_sweeps, keep_rows); when a refresh moves a halo disc past
    its sub-domain's rebuild threshold, that pair list is rebuilt and its rows reloaded
    from the discs' histories, which the sub-domain writes back from its own rows first.
    Forced at every sweep here (threshold 0): still the monolithic bits."""
    from ooc_dem.engine import live

    made = []
    init = live.LiveDomains.__init__

    def eager(self, *args, **kwargs):
        init(self, *args, **kwargs)
        self._rebuild2[:] = 0.0
        made.append(self)

    monkeypatch.setattr(live.LiveDomains, "__init__", eager)
    sc, bed, ws, steps, (ref_p, ref_ws, ref_rec) = wheel_case
    p, w, rec, eng = sweep_run(sc, bed, ws, steps, domains=6, block=1)
    assert made and eng.compiled_sweeps
    assert_same_state(ref_p, p)
    assert np.array_equal(ref_ws, w)
    assert np.array_equal(ref_rec, rec)


def test_sweeps_after_the_first_call_go_straight_to_the_compiled_overload(bare_bed):
    """LiveDomains calls numba's compiled overload directly once the dispatcher has typed a
    list of sub-domains (live.LiveDomains._compiled: typing costs an MPI block ~5 %). The
    overload must be found (else the saving is silently lost), and calls one sweep at a
    time through it keep the monolithic bits."""
    from ooc_dem.model.decomposition import XHistogram, equal_bounds
    from ooc_dem.engine.live import LiveDomains
    from ooc_dem.engine.live_kernels import sweeps_kernel
    from ooc_dem.physics.layout import WS_SIZE

    sc, bed = bare_bed
    model = Model.from_scenario(sc)
    K, calls = 3, 4
    hop = 2.0 * sc.soil.r_max + sc.bed.skin
    bounds = equal_bounds(XHistogram.of(bed.pos[:, AX_X], sc.bin.length), 4)
    live = LiveDomains(
        bed.take(np.arange(len(bed))), bounds, K * hop, hop, model, model.without_wheel(), np.zeros(WS_SIZE), -1
    )
    run = sweeps_kernel(live.steppers[0].kern)
    for c in range(calls):
        live.run_sweeps(c * K, 1, K, c > 0, -1.0)
        if c == 0:
            assert live._entry[1] is None  # the dispatcher compiled or loaded it
    held, fn = live._entry
    assert held is live._domain_list() and fn is not None and fn is not run
    ref, _, _ = mono(sc, bed, None, calls * K)
    out = live.p.take(live.owned_active_rows())
    assert_same_state(ref, out)


def test_fresh_local_sets_refuse_a_refresh(bare_bed):
    """A refresh before the first sweep of fresh local sets would write springs back from
    pair lists never built (it wiped the histories: found when MPI blocks asked for one);
    run_sweeps refuses it in one line, and takes it after a sweep."""
    from ooc_dem.model.decomposition import XHistogram, equal_bounds
    from ooc_dem.engine.live import LiveDomains
    from ooc_dem.engine.stepper import EngineError
    from ooc_dem.physics.layout import WS_SIZE

    sc, bed = bare_bed
    model = Model.from_scenario(sc)
    hop = 2.0 * sc.soil.r_max + sc.bed.skin
    bounds = equal_bounds(XHistogram.of(bed.pos[:, AX_X], sc.bin.length), 3)
    live = LiveDomains(
        bed.take(np.arange(len(bed))), bounds, 2 * hop, hop, model, model.without_wheel(), np.zeros(WS_SIZE), -1
    )
    with pytest.raises(EngineError, match="not been swept"):
        live.run_sweeps(0, 1, 2, True, -1.0)
    live.run_sweeps(0, 1, 2, False, -1.0)
    live.run_sweeps(2, 1, 2, True, -1.0)
    ref, _, _ = mono(sc, bed, None, 4)
    assert_same_state(ref, live.p.take(live.owned_active_rows()))
