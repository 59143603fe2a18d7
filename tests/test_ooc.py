"""Out-of-core mode: the sweep over HDF5/zarr epochs is bit-identical to the monolithic run."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from ooc_dem.app.bed import settled_bed
from ooc_dem.model.checkpoint import particles_to_record, read_all_particles, record_rows, records_to_particles
from ooc_dem.model.decomposition import group_order
from ooc_dem.app.run import RunOptions, Simulation
from ooc_dem.model.scenario import load_scenario
from ooc_dem.physics.layout import AX_X, AX_Y, HM_R, HS_T, SP_Z  # noqa: F401
from ooc_dem.storage import open_store

from support.state import assert_same_state

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow


def run(sc, out, bed, steps, **kw):
    opts = RunOptions(steps=steps, progress=False, figures=False, **kw)
    sim = Simulation(sc, out, opts)
    sim.start(bed.take(np.arange(len(bed))))
    summary = sim.run()
    store = open_store(out, repair=False)  # read-only: `sim` still holds the write lock
    reader = store.read_epoch()
    p = read_all_particles(reader)
    arrays, _ = reader.read_globals()
    reader.close()
    store.close()
    return summary, p, arrays, sim


@pytest.fixture(scope="module")
def bare(tmp_path_factory):
    sc = load_scenario("bed-3495", ["decomposition.policy=equal"])  # three 0.1 m tiles
    bed = settled_bed(sc)
    ref = run(sc, tmp_path_factory.mktemp("mono") / "m", bed, 100)
    return sc, bed, ref


@pytest.mark.parametrize("backend", ["hdf5", "zarr"])
@pytest.mark.parametrize("domains", [2, 6, 16])
@pytest.mark.parametrize("block", [1, 10, 50])
def test_bare_bed_ooc_equals_monolithic(bare, tmp_path, backend, domains, block):
    sc, bed, (ref_summary, ref_p, _, _) = bare
    steps = 20 if block == 1 else 100  # K = 1 commits an epoch per step: keep it short
    if steps != 100:
        ref_summary, ref_p, _, _ = run(sc, tmp_path / "m", bed, steps)
    summary, p, _, sim = run(sc, tmp_path / "o", bed, steps, mode="ooc", backend=backend, domains=domains, block=block)
    assert summary["state_hash"] == ref_summary["state_hash"]
    assert_same_state(ref_p, p)
    eng = sim.engine
    assert eng.D == domains
    # resident discs = exactly the sub-domain plus its halo strips (first sweep, from the bed),
    # and never more than the largest of those (+2 % for discs that moved) afterwards
    lo, hi = eng.bounds[:-1], eng.bounds[1:]
    expected = [
        int(np.count_nonzero((bed.pos[:, AX_X] >= a - eng.halo) & (bed.pos[:, AX_X] < b + eng.halo)))
        for a, b in zip(lo, hi)
    ]
    assert eng.resident_first == expected
    assert eng.resident_max <= 1.02 * max(expected) + 10
    if block == 1 and domains >= 6:
        assert eng.resident_max < len(bed) / 2


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    sc = load_scenario(
        "quick",
        [
            "wheel.omega=4.0",
            "wheel.control=slip",
            "wheel.slip=0.2",
            "wheel.settle_time=0.01",
            "wheel.drop_gap=0.0",
            "wheel.travel_time=0.02",
            "decomposition.margin=0.001",
            "output.steady_start=0.005",
            "output.steady_end=0.02",
        ],
    )
    bed = settled_bed(sc)
    ref = run(sc, tmp_path_factory.mktemp("wm") / "m", bed, 3000)
    return sc, bed, ref


# every D with both backends across the wheel runs; K = 1 (an epoch per step, 3000 commits)
# is exercised on the bare bed above and, through the same sweep, by the DDM wheel tests
@pytest.mark.parametrize("backend,domains,block", [("hdf5", 2, 10), ("hdf5", 6, 10), ("zarr", 6, 50), ("zarr", 16, 50)])
def test_wheel_run_ooc_equals_monolithic(wheel, tmp_path, backend, domains, block):
    sc, bed, (ref_summary, ref_p, ref_arrays, _) = wheel
    summary, p, arrays, sim = run(
        sc, tmp_path / "o", bed, 3000, mode="ooc", backend=backend, domains=domains, block=block
    )
    assert summary["state_hash"] == ref_summary["state_hash"]
    assert_same_state(ref_p, p)
    assert np.array_equal(ref_arrays["wheel_state"], arrays["wheel_state"])
    for key in ("slip", "net_traction", "gross_traction", "sinkage"):
        assert summary[key] == ref_summary[key], key
    assert len(sim.redecompositions) >= 3, "the run must cross re-decompositions"


@pytest.mark.parametrize("backend", ["hdf5", "zarr"])
def test_io_overlap_gives_the_same_bits(wheel, bare, tmp_path, backend):
    """--io-overlap (slab d + 1 read and slab d - 1 written in threads while slab d computes):
    the wheel run across re-decompositions and the bare bed end on the monolithic bits, and
    a resume keeps the option (stored with the run)."""
    sc, bed, (ref_summary, ref_p, ref_arrays, _) = wheel
    summary, p, arrays, sim = run(
        sc, tmp_path / "w", bed, 3000, mode="ooc", backend=backend, domains=6, block=50, io_overlap=True
    )
    assert sim.engine.io_overlap
    assert summary["state_hash"] == ref_summary["state_hash"]
    assert_same_state(ref_p, p)
    assert np.array_equal(ref_arrays["wheel_state"], arrays["wheel_state"])
    assert summary["slip"] == ref_summary["slip"] and len(sim.redecompositions) >= 3
    sc, bed, (ref_summary, ref_p, _, _) = bare
    summary, p, _, _ = run(
        sc, tmp_path / "b", bed, 60, mode="ooc", backend=backend, domains=16, block=10, io_overlap=True
    )
    from ooc_dem.app.run import resume_simulation

    sim = resume_simulation(tmp_path / "b", steps=100, progress=False, figures=False)
    assert sim.engine.io_overlap
    summary = sim.run()
    assert summary["state_hash"] == ref_summary["state_hash"]


def _within(x, lo, hi, reach):
    return np.maximum(np.maximum(lo - x, x - hi), 0.0) <= reach


def test_cone_spans_hold_every_disc_within_reach_and_shrink_to_the_slab():
    """Step s of a k-step block advances the discs within k - s hops of the slab: in x
    order the span is exactly those discs; in any order it still holds them all."""
    from ooc_dem.engine.sweep import cone_spans

    rng = np.random.default_rng(7)
    hop, lo, hi, k = 0.01, 0.3, 0.5, 20
    x = np.sort(rng.uniform(lo - k * hop, hi + k * hop, 5000))
    spans = cone_spans(x, lo, hi, hop, k)
    assert spans.shape == (k, 2)
    for s in range(k):
        rows = np.flatnonzero(_within(x, lo, hi, (k - s) * hop))
        assert (spans[s, 0], spans[s, 1]) == (rows[0], rows[-1] + 1)
    assert spans[0, 0] == 0 and spans[0, 1] == len(x)  # the first step: the whole read slab
    assert spans[-1, 1] - spans[-1, 0] < 0.6 * len(x)  # the last: the slab and one hop
    shuffled = rng.permutation(x)
    spans = cone_spans(shuffled, lo, hi, hop, k)
    for s in range(k):
        rows = np.flatnonzero(_within(shuffled, lo, hi, (k - s) * hop))
        assert spans[s, 0] <= rows[0] and rows[-1] < spans[s, 1]
    assert np.array_equal(cone_spans(x[:0], lo, hi, hop, k), np.zeros((k, 2), np.int64))


def test_a_cone_one_hop_too_narrow_loses_the_monolithic_bits(bare, tmp_path, monkeypatch):
    """The exactness tests above see the cone: one that leaves out the hop the last steps
    need (the partners of the discs at the slab's edge) ends on other bits."""
    from ooc_dem.engine import sweep

    sc, bed, (ref_summary, ref_p, _, _) = bare
    exact = sweep.cone_spans

    def narrow(x, lo, hi, hop, k):
        spans = exact(x, lo, hi, hop, k)
        spans[:-1] = exact(x, lo, hi, hop, k - 1)  # step s: k - s - 1 hops
        own = np.flatnonzero(_within(x, lo, hi, 0.0))
        spans[-1] = (own.min(), own.max() + 1)  # the last step: the slab alone
        return spans

    monkeypatch.setattr(sweep, "cone_spans", narrow)
    summary, p, _, _ = run(sc, tmp_path / "o", bed, 100, mode="ooc", domains=6, block=10)
    assert summary["state_hash"] != ref_summary["state_hash"]
    assert not np.array_equal(ref_p.pos, p.pos)


@pytest.mark.parametrize("id_cap", [97, None])
def test_streamed_hash_equals_in_memory_hash(bare, tmp_path, id_cap, monkeypatch):
    """`checkpoint hash` streams an epoch group by group (their lane sums added; the ids
    checked unique in ranges of at most max(id_cap, 2 x a group) ids): it must be the hash
    of all the discs gathered in RAM, history included."""
    from ooc_dem.model import state_check
    from ooc_dem.model.checkpoint import hash_epoch, hash_particles

    if id_cap is not None:
        monkeypatch.setattr(state_check, "ID_CHECK_CAP", id_cap)
    sc, bed, _ = bare
    _, p, arrays, _ = run(sc, tmp_path / "o", bed, 30, mode="ooc", backend="hdf5", domains=6, block=10)
    assert p.hist_n.sum() > len(p)  # a loaded bed: the history is part of the hash
    store = open_store(tmp_path / "o", repair=False)  # (the run returned above holds the write lock)
    reader = store.read_epoch()
    _, attrs = reader.read_globals()
    assert len(reader.domains()) == 6
    expected = hash_particles(read_all_particles(reader), arrays["wheel_state"], int(attrs["step"]))
    assert hash_epoch(reader) == expected
    reader.close()
    store.close()


_RSS_PER_GROUP = r"""
import json, sys
import psutil
from ooc_dem import storage
from ooc_dem.app.run import RunOptions, Simulation
from ooc_dem.model.scenario import load_scenario
out, groups = sys.argv[1], int(sys.argv[2])
proc, after_stage = psutil.Process(), []
write_domain = storage.EpochWriter.write_domain

def staged(self, d, arrays, attrs):
    write_domain(self, d, arrays, attrs)
    after_stage.append(proc.memory_info().rss)
storage.EpochWriter.write_domain = staged
sc = load_scenario(f"bed-{50_000 * groups}", ["decomposition.policy=equal"])
sim = Simulation(sc, out, RunOptions(mode="ooc", backend="hdf5", domains=groups, block=20, steps=40,
                                     checkpoint_every=40, progress=False, figures=False))
sim.start(streamed=True)
sim.run()
print(json.dumps(after_stage))
"""


def test_a_sweep_does_not_grow_resident_memory_group_by_group(tmp_path):
    """Out-of-core RSS follows the slab, not the number of groups passed: after
    the first slab of 50k discs has come and gone, glibc's malloc had raised its mmap
    threshold and served the next slabs' arrays from a heap that fragmented, so RSS climbed
    with every group of a sweep (+30 MiB over 10 groups here, ~1.4 MiB a group at 500k-disc
    slabs in the memsweep) until the sweep ended. Measured in a fresh process after each
    group is staged: set-up and two sweeps of 10 groups."""
    groups = 10
    cp = subprocess.run(
        [sys.executable, "-c", _RSS_PER_GROUP, str(tmp_path / "run"), str(groups)],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "NUMBA_NUM_THREADS": "1"},
    )
    assert cp.returncode == 0, cp.stderr[-3000:]
    rss = np.array(json.loads(cp.stdout.strip().splitlines()[-1]), dtype=np.int64)
    assert len(rss) == 3 * groups  # the set-up's epoch and two sweeps
    for start in range(groups, len(rss), groups):  # each sweep, against its first group
        sweep_rss = rss[start : start + groups]
        grown = sweep_rss.max() - sweep_rss[0]
        assert grown < 10 * 2**20, (
            f"RSS grew {grown / 2**20:.1f} MiB over the groups of one sweep "
            f"(MiB after each group: {np.round(rss / 2**20, 1).tolist()})"
        )


@pytest.mark.parametrize("dim", [2, 3])
def test_group_order_is_cell_order_x_column_first(dim):
    """Groups are stored in cell order: the packed int64 key sorts as the cells' (x column,
    y row[, z row]) tuples do, for beds far longer than a slab and for particles flown off
    (clipped to the key's edge, still a permutation)."""
    rng = np.random.default_rng(dim)
    cell = 0.005
    pos = rng.random((20_000, dim)) * np.array([30_000.0, 0.5, 0.2][:dim]) - 0.01
    o = group_order(pos, cell)
    assert np.array_equal(o, np.lexsort(np.floor(pos / cell).T[::-1]))
    pos[:3] = np.array([1e300, -1e300, 7.0][:dim])
    assert np.array_equal(np.sort(group_order(pos, cell)), np.arange(len(pos)))


def test_records_gather_and_fill_like_the_particles_they_hold():
    """The sweep's record paths (owned rows gathered straight into a record, strips of
    records filtered by row, a slab filled from several records) hold exactly what the
    per-Particles paths held."""
    p = settled_bed(load_scenario("quick"))
    rng = np.random.default_rng(7)
    hn = rng.integers(0, p.hist_cap + 1, len(p))
    p.hist_n[:] = hn
    unused = np.arange(p.hist_cap)[None, :] >= hn[:, None]
    for k in ("hist_id", "hist_s", "hist_m"):
        a = getattr(p, k)
        a[...] = rng.integers(-5, 10**6, a.shape) if a.dtype.kind == "i" else rng.random(a.shape)
        a[unused] = 0
    rows = rng.permutation(len(p))[: len(p) // 3]
    got, want = particles_to_record(p, rows), particles_to_record(p.take(rows))
    assert sorted(got) == sorted(want)
    for k in want:
        assert np.array_equal(got[k], want[k]) and got[k].dtype == want[k].dtype, k
    rec = particles_to_record(p)
    half = len(p) // 2
    pieces = [
        record_rows(rec, np.arange(half)),
        record_rows(rec, np.zeros(0, np.int64)),
        record_rows(rec, np.arange(half, len(p))),
    ]
    q = records_to_particles(pieces, p.hist_cap, p.dim)
    for k, v in p.arrays().items():
        assert np.array_equal(getattr(q, k), v), k


def test_strip_reads_are_exact_in_any_row_order():
    """A halo strip is read from the candidate rows that the running max / min of x bound,
    then filtered by x: the discs with lo <= x < hi and no other, whether the group is in
    cell order, x order or shuffled (a foreign store's)."""
    from ooc_dem.engine.sweep import RamEpochs, group_attrs, read_strip

    p = settled_bed(load_scenario("quick"))
    x = p.pos[:, AX_X]
    rng = np.random.default_rng(3)
    for order in (group_order(p.pos, 0.004), np.argsort(x), rng.permutation(len(p))):
        g = p.take(order)
        ram = RamEpochs(p.hist_cap)
        ram.write_particles(0, g, group_attrs(g.pos[:, AX_X]))
        for lo, hi in [(-1.0, 9.0), (0.1, 0.2), (0.25, 0.2500001), (x.min(), x.max()), (9.0, 10.0)]:
            rec = read_strip(ram, 0, lo, hi)
            want = np.sort(p.id[(x >= lo) & (x < hi)])
            got = np.zeros(0, np.int64) if rec is None else np.sort(rec["id"])
            assert np.array_equal(got, want), (lo, hi)
            if rec is not None:
                q = records_to_particles([rec], p.hist_cap, p.dim)
                assert np.array_equal(q.hist_n, p.hist_n[np.searchsorted(p.id, q.id)])
