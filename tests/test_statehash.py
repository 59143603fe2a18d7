"""The streamed state hash and the bounded-memory paths of the checkpoint tools.

- ``statehash.xxh64_words`` is XXH64 (checked against the ``xxhash`` package);
- the hash is a function of the set of discs: any row order and any partition into
  groups give the same value; every field, history entry, the step and the wheel enter it;
- `checkpoint hash`, the epoch validation (verify / resume) and the bounds of a
  re-decomposition hold O(group) memory, not O(N): the same group size with 4x the groups
  gives about the same tracemalloc peak; the bounds read no disc when the groups carry their
  x summaries, and an older store without them gives the same histogram (counted group by
  group) and still verifies and resumes to the same bits;
- `checkpoint export` sorts by id with an external merge (sorted runs on disk beside the
  output): the same group size with 4x the groups gives about the same peak, the export
  holds every disc once in id order with the same bits, and an id held by two groups is
  refused with one line;
- the HDF5 reader holds one group's objects open at a time: reading every group of an
  epoch does not grow resident memory with the number of groups.
"""

import json
import shutil
import tracemalloc

import h5py
import numpy as np
import pytest
import xxhash

from support.cli import cli_in_process, one_line_error, run_cli
from ooc_dem.model import state_check, statehash
from ooc_dem.model.checkpoint import hash_epoch, hash_particles, open_epoch, particles_to_record
from ooc_dem.model.state_check import validate_epoch
from ooc_dem.model.decomposition import XHistogram, equal_bounds, x_summary
from ooc_dem.app import export, export_formats
from ooc_dem.engine.sweep import RamEpochs, group_of, x_histogram
from ooc_dem.physics.layout import AX_X
from ooc_dem.model.state import Particles, state_hash
from ooc_dem.storage import create_store, open_store

LENGTH = 1.0
CELL = 0.01  # the groups' memory-order cell (any positive size gives the same hashes)


def test_xxh64_is_xxhash():
    rng = np.random.default_rng(5)
    for n in list(range(0, 12)) + [31, 32, 33, 100]:
        words = rng.integers(0, 2**63, n, dtype=np.int64).view(np.uint64)
        for seed in (0, 1, 3, 2**64 - 1):
            got = int(statehash.xxh64_words(words, n, np.uint64(seed)))
            assert got == xxhash.xxh64(words.tobytes(), seed=seed).intdigest(), (n, seed)


def _state(n, seed, dim=2, first_id=0, cap=12):
    """n discs with random (valid) content and a random contact history (ids shuffled)."""
    rng = np.random.default_rng(seed)
    p = Particles.empty(n, dim, cap)
    p.id[:] = first_id + rng.permutation(n)
    p.pos[:] = rng.random((n, dim)) * LENGTH
    p.vel[:] = rng.standard_normal((n, dim))
    p.spin[:] = rng.standard_normal(p.spin.shape)
    p.r[:] = 0.002 + 0.001 * rng.random(n)
    p.mass[:] = rng.random(n) + 0.1
    p.inertia[:] = rng.random(n) + 0.1
    p.mat[:] = rng.integers(0, 3, n)
    p.hist_n[:] = rng.integers(0, 5, n)
    # partners strictly ascending, never the disc itself: a wall (-2) for every third disc,
    # then discs above its own id
    slot = np.arange(cap)[None, :]
    partner = p.id[:, None] + 1 + 3 * slot
    partner[:, 0] = np.where(np.arange(n) % 3 == 0, -2, partner[:, 0])
    used = slot < p.hist_n[:, None]
    p.hist_id[used] = partner[used]
    p.hist_s[used] = rng.standard_normal(p.hist_s[used].shape)
    p.hist_m[used] = rng.standard_normal(p.hist_m[used].shape)
    return p


@pytest.mark.parametrize("dim", [2, 3])
def test_hash_is_a_function_of_the_set_of_discs(dim):
    p = _state(400, 1, dim)
    wheel = np.arange(6.0)
    h = hash_particles(p, wheel, 77)
    assert h.startswith(statehash.PREFIX) and len(h) == len(statehash.PREFIX) + 64
    assert state_hash(p, wheel, 77) == h
    rng = np.random.default_rng(2)
    assert hash_particles(p.take(rng.permutation(len(p))), wheel, 77) == h
    cuts = np.sort(rng.choice(np.arange(1, len(p)), 4, replace=False))
    parts = [particles_to_record(p.take(rows)) for rows in np.split(rng.permutation(len(p)), cuts)]
    assert statehash.hash_records(parts, wheel, 77) == h
    # stale values in unused history slots are not state
    q = p.take(np.arange(len(p)))
    free = np.flatnonzero(q.hist_n < q.hist_cap)[0]
    q.hist_id[free, q.hist_n[free] :] = 12345
    assert hash_particles(q, wheel, 77) == h
    # every field, a history entry, the step and the wheel enter the hash
    seen = {h}
    i = int(np.flatnonzero(p.hist_n > 0)[0])
    for name in ("id", "pos", "vel", "spin", "r", "mass", "inertia", "mat", "hist_id", "hist_s", "hist_m"):
        q = p.take(np.arange(len(p)))
        a = getattr(q, name)
        a[i] = a[i] + (1 if a.dtype.kind == "i" else 1e-12 * np.abs(a[i]) + 1e-300)
        if name == "id":
            a[i] = 10**9
        seen.add(hash_particles(q, wheel, 77))
    q = p.take(np.arange(len(p)))
    q.hist_n[i] -= 1  # one contact fewer
    seen.add(hash_particles(q, wheel, 77))
    seen.add(hash_particles(p, wheel, 78))
    seen.add(hash_particles(p, wheel + [0, 0, 0, 0, 0, 1e-9], 77))
    seen.add(hash_particles(p, None, 77))
    seen.add(hash_particles(p.take(np.arange(len(p) - 1)), wheel, 77))
    assert len(seen) == 17


def _write_store(path, groups: int, per_group: int, summaries: bool = True):
    """An HDF5 store of one epoch: `groups` x-slabs of `per_group` discs, ids scattered over
    every group (the worst case for the id check)."""
    n = groups * per_group
    p = _state(n, 3)
    p.pos[:, AX_X] = (np.arange(n) + 0.5) / n * LENGTH  # slab d holds discs d*per_group ...
    store = create_store(str(path), "hdf5", {"format_version": 2, "dim": 2, "hist_cap": 12})
    w = store.begin_epoch(10)
    for d in range(groups):
        q, attrs = group_of(p, np.arange(d * per_group, (d + 1) * per_group), CELL)
        if summaries:
            attrs["x_summary"] = x_summary(q.pos[:, AX_X], LENGTH)
        w.write_domain(d, particles_to_record(q), attrs)
    w.write_globals({"wheel_state": np.zeros(6)}, {"step": 10, "time": 0.1})
    w.commit()
    store.close()
    return p


def _peak(fn):
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_hash_verify_and_bounds_memory_scales_with_the_group_not_n(tmp_path, monkeypatch):
    """The same group size (3000 discs), 4 and 16 groups: the peaks of `checkpoint hash`,
    the epoch validation and the bounds' histogram stay within 1.5x (an array of the whole
    bed would make them 4x). ID_CHECK_CAP is lowered to 0 so the id check holds its floor
    of two groups' ids (its default, 2**16 ids, is a constant whatever N is, but larger than
    these groups)."""
    monkeypatch.setattr(state_check, "ID_CHECK_CAP", 0)
    hash_particles(_state(5, 0), None, 0)  # compile the digest kernel outside the measurement
    peaks = {}
    for groups in (4, 16):
        p = _write_store(tmp_path / f"s{groups}", groups, 3000)
        store = open_store(str(tmp_path / f"s{groups}"), repair=False)
        with open_epoch(store) as reader:
            h = {}
            peaks[groups] = {
                "hash": _peak(lambda: h.setdefault("v", hash_epoch(reader))),
                "verify": _peak(lambda: validate_epoch(reader, "t")),
                "bounds": _peak(lambda: x_histogram(reader, LENGTH)),
            }
            assert h["v"] == hash_particles(p, np.zeros(6), 10)
        store.close()
    for what in ("hash", "verify", "bounds"):
        ratio = peaks[16][what] / peaks[4][what]
        assert ratio < 1.5, (what, peaks)
    assert peaks[16]["bounds"] < 200_000, peaks  # summaries only: no disc is read


def _csv_columns(path) -> dict[str, list[str]]:
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    names = lines[0].split(",")
    return dict(zip(names, zip(*(ln.split(",") for ln in lines[1:]))))


def test_export_memory_scales_with_the_group_not_n(tmp_path, monkeypatch):
    """4 and 16 groups of 3000 discs, ids scattered over every group, exported in slices of
    500 rows with a 256 kB merge buffer: the peaks stay within 1.5x (the whole bed sorted in
    RAM, as before, makes them ~4x), and the CSV is the whole state in id order, bit for bit."""
    monkeypatch.setattr(export_formats, "_ROWS_PER_WRITE", 500)
    peaks = {}
    for groups in (4, 16):
        p = _write_store(tmp_path / f"s{groups}", groups, 3000)
        out = tmp_path / f"e{groups}.csv"
        store = open_store(str(tmp_path / f"s{groups}"), repair=False)
        with open_epoch(store) as reader:

            def run():
                with export.read_snapshot(reader, "t", tmp_path, buffer_bytes=256 << 10) as snap:
                    export.export_snapshot(snap, "csv", out)

            peaks[groups] = _peak(run)
        store.close()
        cols = _csv_columns(out)
        order = np.argsort(p.id)
        assert np.array_equal(np.array(cols["id"], np.int64), p.id[order])
        for name, want in (
            ("x", p.pos[:, 0]),
            ("y", p.pos[:, 1]),
            ("vx", p.vel[:, 0]),
            ("vy", p.vel[:, 1]),
            ("w", p.spin[:, 0]),
            ("r", p.r),
            ("mass", p.mass),
        ):
            assert np.array_equal(np.array(cols[name], np.float64), want[order]), name
        assert np.array_equal(np.array(cols["mat"], np.int32), p.mat[order])
        assert sorted(tmp_path.iterdir()) == sorted(
            [tmp_path / f"s{g}" for g in peaks] + [tmp_path / f"e{g}.csv" for g in peaks]
        )
    assert peaks[16] / peaks[4] < 1.5, peaks


def test_export_refuses_an_id_held_by_two_groups(tmp_path):
    """Each group alone is valid; only the merge across groups can see the repeat."""
    n, groups = 400, 4
    p = _state(n, 7)
    p.pos[:, AX_X] = (np.arange(n) + 0.5) / n * LENGTH
    p.id[n - 1] = p.id[0]  # the first and the last group share an id
    p.hist_n[:] = 0
    store = create_store(str(tmp_path / "s"), "hdf5", {"format_version": 2, "dim": 2, "hist_cap": 12})
    w = store.begin_epoch(10)
    for d in range(groups):
        q, attrs = group_of(p, np.arange(d * n // groups, (d + 1) * n // groups), CELL)
        w.write_domain(d, particles_to_record(q), attrs)
    w.write_globals({"wheel_state": np.zeros(6)}, {"step": 10, "time": 0.1})
    w.commit()
    store.close()
    with open_epoch(open_store(str(tmp_path / "s"), repair=False)) as reader:
        with pytest.raises(state_check.StateError, match=f"disc id {int(p.id[0])} appears more than once"):
            export.read_snapshot(reader, "t", tmp_path)
    cp = cli_in_process("checkpoint", "export", tmp_path / "s", "--out", tmp_path / "e.csv")
    one_line_error(cp, "appears more than once")
    assert not (tmp_path / "e.csv").exists()


class _CountingReader:
    def __init__(self, reader):
        self.reader, self.rows = reader, 0

    def __getattr__(self, name):
        return getattr(self.reader, name)

    def read_domain(self, d, names=None, rows=None):
        out = self.reader.read_domain(d, names, rows)
        self.rows += len(next(iter(out.values())))
        return out


def test_bounds_from_summaries_and_from_an_older_store_agree(tmp_path):
    p = _write_store(tmp_path / "new", 5, 700)
    _write_store(tmp_path / "old", 5, 700, summaries=False)
    hists = {}
    for name in ("new", "old"):
        store = open_store(str(tmp_path / name), repair=False)
        with open_epoch(store) as reader:
            counting = _CountingReader(reader)
            hists[name] = x_histogram(counting, LENGTH)
            # with summaries nothing is read; without, each group's x once
            assert counting.rows == (0 if name == "new" else len(p)), name
            validate_epoch(reader, name)  # an older store (no summaries) still verifies
        store.close()
    # serial DDM's groups in RAM, grouped otherwise (3 groups of scattered rows): same counts
    ram = RamEpochs()
    for d, rows in enumerate(np.array_split(np.random.default_rng(4).permutation(len(p)), 3)):
        ram.write_particles(d, *group_of(p, rows, CELL))
    hists["ram"] = x_histogram(ram, LENGTH)
    whole = XHistogram.of(p.pos[:, AX_X], LENGTH)
    for h in hists.values():
        assert np.array_equal(h.counts, whole.counts)
        assert np.array_equal(equal_bounds(h, 7), equal_bounds(whole, 7))
    b = equal_bounds(whole, 5)
    counts = np.histogram(p.pos[:, AX_X], b)[0]
    assert abs(counts - len(p) / 5).max() <= len(p) / 4096 + 1  # within a bin's share


def test_ids_repeated_across_groups_are_refused_in_bounded_memory(tmp_path, monkeypatch):
    monkeypatch.setattr(state_check, "ID_CHECK_CAP", 0)
    _write_store(tmp_path / "s", 6, 500)
    with h5py.File(next((tmp_path / "s" / "epochs").glob("*.h5")), "r+") as f:
        a, b = f["domains/d0001/id"][:], f["domains/d0004/id"][:]
        a[7] = b[3]
        f["domains/d0001/id"][:] = a
    store = open_store(str(tmp_path / "s"), repair=False)
    with open_epoch(store, verify=False) as reader:
        for fn in (lambda: hash_epoch(reader), lambda: validate_epoch(reader, "t")):
            with pytest.raises(state_check.StateError, match=f"disc id {int(b[3])} appears more than once"):
                fn()
    store.close()


def _strip_summaries(store_dir):
    """Remove every group's x_summary from the current HDF5 epoch (as written before groups kept x summaries)
    and recompute the manifest's size and checksum of the file."""
    import hashlib

    m = json.loads((store_dir / "MANIFEST.json").read_text())
    cur = m["current"]
    path = store_dir / cur["path"]
    with h5py.File(path, "r+") as f:
        for g in f["domains"].values():
            a = json.loads(g.attrs["ooc_dem_attrs"])
            assert "x_summary" in a
            del a["x_summary"]
            g.attrs["ooc_dem_attrs"] = json.dumps(a)
    data = path.read_bytes()
    for e in cur["files"]:
        if e["path"] == cur["path"]:
            e.pop("xxh3_128", None)  # re-signed as the stores of that time were (sha256)
            e["size"], e["sha256"] = len(data), hashlib.sha256(data).hexdigest()
    m["previous"] = None
    (store_dir / "MANIFEST.json").write_text(json.dumps(m))


def test_store_without_summaries_resumes_to_the_same_bits(tmp_path):
    """A store whose epoch lacks the x summaries (written before groups kept x summaries) verifies, resumes
    and ends with the hash of an uninterrupted run; a summary that lies is refused."""
    common = ["--mode", "ooc", "--backend", "hdf5", "--domains", 3, "--block", 10, "--no-progress", "--no-figures"]
    run_cli("run", "bed-1200", "--steps", 60, "--out", tmp_path / "whole", *common, check=True)
    run_cli("run", "bed-1200", "--steps", 30, "--out", tmp_path / "part", *common, check=True)
    shutil.copytree(tmp_path / "part", tmp_path / "lie", symlinks=True)
    _strip_summaries(tmp_path / "part")
    assert cli_in_process("checkpoint", "verify", tmp_path / "part").returncode == 0
    run_cli("resume", tmp_path / "part", "--steps", 60, "--no-progress", "--no-figures", check=True)
    whole = json.loads((tmp_path / "whole" / "summary.json").read_text())
    part = json.loads((tmp_path / "part" / "summary.json").read_text())
    assert part["state_hash"] == whole["state_hash"]
    assert part["state_hash"] == cli_in_process("checkpoint", "hash", tmp_path / "part", check=True).stdout.strip()

    m = json.loads((tmp_path / "lie" / "MANIFEST.json").read_text())
    path = tmp_path / "lie" / m["current"]["path"]
    with h5py.File(path, "r+") as f:
        g = f["domains/d0000"]
        a = json.loads(g.attrs["ooc_dem_attrs"])
        a["x_summary"]["counts"][0] += 1
        a["x_summary"]["counts"][-1] -= 1
        g.attrs["ooc_dem_attrs"] = json.dumps(a)
    import hashlib

    data = path.read_bytes()
    for e in m["current"]["files"]:
        if e["path"] == m["current"]["path"]:
            e.pop("xxh3_128", None)  # re-signed as the stores of that time were (sha256)
            e["size"], e["sha256"] = len(data), hashlib.sha256(data).hexdigest()
    m["previous"] = None
    (tmp_path / "lie" / "MANIFEST.json").write_text(json.dumps(m))
    one_line_error(
        cli_in_process("resume", tmp_path / "lie", "--steps", 60, "--no-progress", "--no-figures"), "x_summary"
    )


def test_reading_every_group_holds_no_memory_per_group(tmp_path):
    """An HDF5 epoch reader keeps the objects of one group open at a time: an open dataset
    holds up to ~64 kB of HDF5's own buffers once read (not seen by tracemalloc), so keeping
    every group's open grew resident memory with D (24 MB at 64 groups of 8192 discs here)
    instead of with the slab."""
    import psutil

    groups, per_group = 64, 8192
    n = groups * per_group
    p = _state(n, 3, cap=1)
    p.hist_n[:] = 0
    store = create_store(str(tmp_path / "s"), "hdf5", {"format_version": 2, "dim": 2, "hist_cap": 1})
    w = store.begin_epoch(10)
    for d in range(groups):
        q, attrs = group_of(p, np.arange(d * per_group, (d + 1) * per_group), CELL)
        w.write_domain(d, particles_to_record(q), attrs)
    w.write_globals({"wheel_state": np.zeros(6)}, {"step": 10, "time": 0.1})
    w.commit()
    store.close()
    del p, q
    store = open_store(str(tmp_path / "s"), repair=False)
    proc = psutil.Process()
    with open_epoch(store) as reader:
        names = list(reader.domains())
        reader.read_domain(names[0])
        before = proc.memory_info().rss
        for d in names:
            reader.read_domain(d)
        grown = proc.memory_info().rss - before
    store.close()
    assert grown < 12 * 2**20, f"{grown / 2**20:.1f} MiB for {len(names)} groups"


@pytest.mark.slow
def test_resume_memory_scales_with_the_group_not_n(tmp_path, monkeypatch):
    """Reopening an out-of-core run (the store's checks, the epoch's validation, the
    engine's geometry from the stored summaries) holds about one group, whatever N is:
    4 and 16 groups of 3000 discs give tracemalloc peaks within 1.5x (a per-disc array of
    the whole bed would make them 4x). The resumed runs then finish to the uninterrupted
    runs' hashes."""
    from ooc_dem.app.run import RunOptions, Simulation, resume_simulation
    from ooc_dem.model.scenario import load_scenario

    monkeypatch.setattr(state_check, "ID_CHECK_CAP", 0)
    peaks, hashes = {}, {}
    for groups in (4, 16):
        sc = load_scenario(f"bed-{3000 * groups}", ["decomposition.policy=equal"])

        def opts(steps):
            return RunOptions(
                mode="ooc",
                backend="hdf5",
                domains=groups,
                block=5,
                steps=steps,
                checkpoint_every=5,
                progress=False,
                figures=False,
            )

        whole = Simulation(sc, tmp_path / f"whole{groups}", opts(10))
        whole.start(streamed=True)
        hashes[groups] = whole.run()["state_hash"]
        first = Simulation(sc, tmp_path / f"run{groups}", opts(5))
        first.start(streamed=True)
        first.run()
        first.close()
        box = {}
        peaks[groups] = _peak(
            lambda: box.setdefault(
                "sim", resume_simulation(tmp_path / f"run{groups}", steps=10, progress=False, figures=False)
            )
        )
        assert box["sim"].run()["state_hash"] == hashes[groups]
    assert peaks[16] / peaks[4] < 1.5, peaks
