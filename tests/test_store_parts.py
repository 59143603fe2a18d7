"""Epochs written by several processes (storage.write_part, EpochWriter.add_part): the
two-phase commit MPI ranks use. Each part is written by a real separate process (so its
temporary carries that process's pid), read back with h5py / zarr-python, checked, and
attacked the way a hostile store could: a part is untrusted input like the rest."""

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest
import zarr

from ooc_dem.storage import StoreError, create_store, open_store

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}

# a child process writes part K of epoch STEP named BASENAME with domains {d: arange(n)}
_CHILD = r"""
import json, sys
import numpy as np
from ooc_dem.storage import write_part
path, step, basename, part, spec = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4]), json.loads(sys.argv[5])
doms = [(int(d), {"x": np.arange(n, dtype=np.float64) + 100 * int(d)}, {"d": int(d)}) for d, n in spec.items()]
print(json.dumps(write_part(path, step, basename, part, doms)))
"""


def _part(path, step, basename, part, spec) -> dict:
    cp = subprocess.run(
        [sys.executable, "-c", _CHILD, str(path), str(step), basename, str(part), json.dumps(spec)],
        capture_output=True,
        text=True,
        env=ENV,
    )
    assert cp.returncode == 0, cp.stderr
    return json.loads(cp.stdout)


def _epoch(store, step, parts_spec, main=(0,)):
    """Epoch `step`: domains `main` in the main file, part k's in a child process each."""
    w = store.begin_epoch(step)
    for d in main:
        w.write_domain(d, {"x": np.arange(3, dtype=np.float64) + 100 * d}, {"d": d})
    for k, spec in enumerate(parts_spec, start=1):
        w.add_part(_part(store.path, step, w.basename, k, spec))
    w.write_globals({"g": np.array([float(step)])})
    w.commit()


def _files(store_path) -> list[str]:
    return sorted(os.listdir(Path(store_path) / "epochs"))


@pytest.mark.parametrize("backend", ["hdf5", "zarr"])
def test_parts_written_by_other_processes_read_back(tmp_path, backend):
    path = tmp_path / "s"
    store = create_store(path, backend, {"who": "test"})
    _epoch(store, 10, [{"1": 4, "2": 5}, {"3": 6}])
    ext = "h5" if backend == "hdf5" else "zip"
    assert _files(path) == sorted([f"e000000000010.{ext}", f"e000000000010.p1.{ext}", f"e000000000010.p2.{ext}"])
    store.close()
    store = open_store(path)
    assert store.verify() == []
    r = store.read_epoch()
    assert r.domains() == [0, 1, 2, 3]
    for d, n in ((0, 3), (1, 4), (2, 5), (3, 6)):
        assert np.array_equal(r.read_domain(d)["x"], np.arange(n, dtype=np.float64) + 100 * d)
        assert r.domain_attrs(d) == {"d": d}
        assert np.array_equal(r.read_domain(d, rows=np.array([0, n - 1]))["x"], [100.0 * d, n - 1 + 100.0 * d])
    r.close()
    info = store.list_epochs()[0]
    on_disk = sum(os.path.getsize(Path(path) / "epochs" / n) for n in _files(path))
    assert info.nbytes == on_disk and info.n_domains == 4 and info.problems == ()
    # the parts are ordinary files of the backend: its own reader opens them
    part2 = Path(path) / "epochs" / f"e000000000010.p2.{ext}"
    if backend == "hdf5":
        with h5py.File(part2, "r") as f:
            assert np.array_equal(f["domains/d0003/x"][()], np.arange(6.0) + 300)
    else:
        with zipfile.ZipFile(part2) as z:
            names = z.namelist()
        assert any(n.startswith("domains/d0003/") for n in names)
        g = zarr.open_group(zarr.storage.ZipStore(part2, mode="r"), mode="r")
        assert np.array_equal(g["domains/d0003/x"][...], np.arange(6.0) + 300)
    # the epoch after next replaces it: its parts go with it
    _epoch(store, 20, [{"1": 2}])
    _epoch(store, 30, [])
    assert _files(path) == sorted([f"e000000000020.{ext}", f"e000000000020.p1.{ext}", f"e000000000030.{ext}"])
    store.close()


def test_an_aborted_or_failed_commit_leaves_no_part(tmp_path):
    path = tmp_path / "s"
    store = create_store(path, "hdf5", {})
    _epoch(store, 10, [{"1": 4}])
    before = _files(path)
    w = store.begin_epoch(20)
    w.add_part(_part(path, 20, w.basename, 1, {"1": 4}))
    w.abort()
    assert _files(path) == before
    # a part numbered 2 without a part 1: refused at commit, and nothing is left
    w = store.begin_epoch(20)
    w.write_domain(0, {"x": np.zeros(1)})
    w.add_part(_part(path, 20, w.basename, 2, {"1": 4}))
    w.write_globals({})
    with pytest.raises(StoreError, match="parts \\[2\\], not 1 to 1"):
        w.commit()
    assert _files(path) == before and store.current() == 10
    # a domain written twice (main file and a part): refused, the part removed
    w = store.begin_epoch(20)
    w.write_domain(1, {"x": np.zeros(1)})
    with pytest.raises(StoreError, match="domain 1: written twice"):
        w.add_part(_part(path, 20, w.basename, 1, {"1": 4}))
    assert _files(path) == before
    # a part of another epoch (another basename) is not taken
    w = store.begin_epoch(20)
    other = _part(path, 21, "e000000000021.h5", 1, {"1": 4})
    with pytest.raises(StoreError, match="was not written as part 1 of this epoch"):
        w.add_part(other)
    w.abort()
    os.remove(other["tmp"])
    store.close()


def test_a_part_written_by_a_killed_process_is_a_leftover(tmp_path):
    """Phase 1 done, phase 2 never came (the committing process died): the temporary part
    is not in any epoch, and the next writer's open removes it."""
    path = tmp_path / "s"
    store = create_store(path, "hdf5", {})
    _epoch(store, 10, [{"1": 4}])
    w = store.begin_epoch(20)
    orphan = _part(path, 20, w.basename, 1, {"1": 4})
    store.close()  # the writer never committed
    assert os.path.exists(orphan["tmp"])
    ro = open_store(path, repair=False)
    assert any(x.path == orphan["tmp"] for x in ro.leftovers())
    ro.close()
    store = open_store(path)
    assert orphan["tmp"] in store.repaired and not os.path.exists(orphan["tmp"])
    assert store.current() == 10 and store.verify() == []
    store.close()


def _manifest(path) -> dict:
    return json.loads((Path(path) / "MANIFEST.json").read_text())


def _write_manifest(path, m) -> None:
    (Path(path) / "MANIFEST.json").write_text(json.dumps(m))


def test_a_damaged_or_missing_part_fails_verification_and_reading_falls_back(tmp_path):
    path = tmp_path / "s"
    store = create_store(path, "hdf5", {})
    _epoch(store, 10, [{"1": 4}])
    _epoch(store, 20, [{"1": 4}])
    store.close()
    part = Path(path) / "epochs" / "e000000000020.p1.h5"
    data = bytearray(part.read_bytes())
    data[-10] ^= 0xFF
    part.write_bytes(bytes(data))
    store = open_store(path)
    problems = store.verify()
    assert [p.step for p in problems] == [20] and "e000000000020.p1.h5: xxh3_128 mismatch" in problems[0]
    r = store.read_epoch()
    assert r.step == 10 and "using previous epoch 10" in store.warnings[-1]
    r.close()
    store.close()
    part.unlink()
    store = open_store(path)
    assert any("e000000000020.p1.h5: missing" in p for p in store.verify(20))
    assert store.list_epochs()[1].problems
    store.close()


@pytest.mark.parametrize(
    "edit,needle",
    [
        (lambda e: e["parts"][0].update(path="../../victim.h5"), "has a forbidden part '..'"),
        (lambda e: e["parts"][0].update(path="epochs/e000000000020.p2.h5"), "is not part 1 of its epoch"),
        (lambda e: e["parts"][0].update(path="epochs/e000000000010.p1.h5"), "names step 10, the entry says 20"),
        (lambda e: e["parts"][0].update(path="epochs/e000000000020.h5"), "is not part 1 of its epoch"),
        (lambda e: e["parts"][0]["files"][0].update(path="epochs/e000000000020.h5"), "is not the epoch file"),
        (lambda e: e["parts"][0].update(files=[]), "lists no files"),
        (lambda e: e.update(parts={"1": 2}), 'malformed "parts"'),
        (lambda e: e["domains"]["1"].update(part=2), "domain 1 part"),
        (lambda e: e["parts"].append(dict(e["parts"][0])), "is not part 2"),
    ],
    ids=[
        "outside",
        "wrong-number",
        "other-step",
        "main-as-part",
        "file-of-main",
        "no-files",
        "not-a-list",
        "domain-part-out-of-range",
        "duplicate",
    ],
)
def test_a_hostile_part_entry_is_refused_in_one_line(tmp_path, edit, needle):
    path = tmp_path / "s"
    store = create_store(path, "hdf5", {})
    _epoch(store, 10, [])
    _epoch(store, 20, [{"1": 4}])
    store.close()
    victim = tmp_path / "victim.h5"
    victim.write_bytes(b"precious")
    m = _manifest(path)
    edit(m["current"])
    _write_manifest(path, m)
    with pytest.raises(StoreError) as ei:
        open_store(path)
    msg = str(ei.value)
    assert needle in msg and "\n" not in msg, msg
    assert victim.read_bytes() == b"precious"
    assert len(_files(path)) == 3  # nothing deleted by the refused open


def test_a_part_that_is_a_symbolic_link_out_of_the_store_is_refused(tmp_path):
    """As for an epoch's main file: a part resolving outside epochs/ refuses the store (one
    line), and nothing outside is read or deleted."""
    path = tmp_path / "s"
    store = create_store(path, "hdf5", {})
    _epoch(store, 10, [])
    _epoch(store, 20, [{"1": 4}])
    store.close()
    part = Path(path) / "epochs" / "e000000000020.p1.h5"
    outside = tmp_path / "outside.h5"
    part.rename(outside)
    part.symlink_to(outside)
    before = outside.read_bytes()
    for repair in (True, False):
        with pytest.raises(StoreError, match="current epoch part 1: .* outside the store's epochs/ directory"):
            open_store(path, repair=repair)
    assert outside.read_bytes() == before and part.is_symlink()
