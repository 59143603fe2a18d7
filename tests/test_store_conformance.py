"""Conformance tests of the storage package: every backend must pass all of them.

``StoreTests`` holds the checks every backend passes, ``DiskStoreTests`` adds those of the
backends whose stores are files; each backend's class (``TestHDF5``, ``TestZarr``,
``TestMemory``) subclasses one of them, sets ``backend`` and supplies the few backend-specific
steps (damaging an epoch, failing a manifest write, reading an epoch with the format's own
library). A new backend gets every check by subclassing.
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from ooc_dem import storage
from support.stores import zip_without
from ooc_dem.storage import BACKENDS, COMPRESSIONS, StoreError, create_store, drop_memory_store, open_store
from ooc_dem.storage._util import gather_rows, write_error

REPO = pathlib.Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------- helpers


def domain_arrays(step: int, d: int, n: int = 12) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(1000 * step + d)
    return {
        "x": rng.standard_normal(n),  # float64
        "ids": np.arange(n, dtype=np.int64) + 100 * d,  # int64
        "mat": rng.integers(-5, 5, size=n, dtype=np.int32),  # int32
        "vel": rng.standard_normal((n, 2)),  # 2-D
        "flag": rng.random(n) < 0.5,  # bool
        "w": rng.random(n).astype(np.float32),
        "hist_ptr": np.arange(n + 1, dtype=np.int64),  # different length
        "hist_partner": np.zeros(0, dtype=np.int64),  # empty
        "empty2d": np.zeros((0, 3), dtype=np.float64),  # empty 2-D
    }


def write_epoch(store, step, ndom=2, n=12, durable=False):
    w = store.begin_epoch(step)
    for d in range(ndom):
        w.write_domain(d, domain_arrays(step, d, n), {"d": d, "step": step, "bounds": [0.5 * d, 0.5 * d + 0.5]})
    w.write_globals(
        {"step": np.array(step, dtype=np.int64), "wheel": np.arange(6.0) + step},
        {"rng": {"state": 2**100 + step}, "scenario": "quick"},
    )
    w.commit(durable=durable)


def assert_same(a: np.ndarray, b: np.ndarray):
    assert a.dtype == b.dtype and a.shape == b.shape
    assert a.tobytes() == b.tobytes()


def assert_epoch(store, step, ndom=2, n=12, reader=None):
    r = reader or store.read_epoch(step)
    assert r.step == step
    assert r.domains() == list(range(ndom))
    for d in range(ndom):
        exp = domain_arrays(step, d, n)
        got = r.read_domain(d)
        assert list(got) == list(exp)
        for k in exp:
            assert_same(got[k], exp[k])
        assert r.domain_attrs(d) == {"d": d, "step": step, "bounds": [0.5 * d, 0.5 * d + 0.5]}
        assert r.domain_len(d) == n
    g, gattrs = r.read_globals()
    assert_same(g["step"], np.array(step, dtype=np.int64))
    assert_same(g["wheel"], np.arange(6.0) + step)
    assert gattrs == {"rng": {"state": 2**100 + step}, "scenario": "quick"}
    r.close()


def epoch_entries(spath) -> list[str]:
    return sorted(os.listdir(os.path.join(spath, "epochs")))


def current_path(spath) -> pathlib.Path:
    m = json.loads(pathlib.Path(spath, "MANIFEST.json").read_text())
    return pathlib.Path(spath, m["current"]["path"])


def a_data_file(spath) -> pathlib.Path:
    """A file holding array data of the current epoch (the HDF5 file, or a zarr chunk)."""
    p = current_path(spath)
    if p.is_file():
        return p
    return p / "domains" / "d0000" / "x" / "c" / "0"


def flip_byte(path: pathlib.Path, offset: int | None = None):
    data = bytearray(path.read_bytes())
    i = len(data) // 2 if offset is None else offset
    data[i] ^= 0x40
    path.write_bytes(bytes(data))


_DTYPES = [
    np.bool_,
    np.int8,
    np.int16,
    np.int32,
    np.int64,
    np.uint8,
    np.uint16,
    np.uint32,
    np.uint64,
    np.float16,
    np.float32,
    np.float64,
    np.complex64,
    np.complex128,
]


@st.composite
def array_dicts(draw):
    k = draw(st.integers(0, 4))
    names = draw(
        st.lists(st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,8}", fullmatch=True), min_size=k, max_size=k, unique=True)
    )
    out = {}
    for n in names:
        dtype = np.dtype(draw(st.sampled_from(_DTYPES)))
        shape = draw(
            st.one_of(
                hnp.array_shapes(min_dims=1, max_dims=1, min_side=0, max_side=40),
                hnp.array_shapes(min_dims=2, max_dims=2, min_side=0, max_side=6),
            )
        )
        out[n] = draw(hnp.arrays(dtype, shape))  # includes nan / inf / -0.0 / extremes
    return out


# ----------------------------------------------------------------------------- every backend


class StoreTests:
    """The checks every backend passes. A subclass sets ``backend`` and implements
    ``corrupt``, ``spoil_previous`` and ``fail_manifest_write``."""

    backend: str
    on_disk = False  # the store is a directory of files (epochs/, MANIFEST.json)
    ext = ""  # the extension of the epoch files it writes

    @pytest.fixture
    def spath(self, tmp_path):
        """Store location for the backend (memory stores get a unique mem:// key)."""
        p = str(tmp_path / "store") if self.on_disk else f"mem://{tmp_path}"
        yield p
        drop_memory_store(p)

    def corrupt(self, spath, how: str) -> str:
        """Damage epoch 2's domain data (how: flip, truncate, delete_group); return the name
        expected in the problem message."""
        raise NotImplementedError

    def spoil_previous(self, spath) -> None:
        """Damage the previous epoch's data."""
        raise NotImplementedError

    def fail_manifest_write(self, store, spath, monkeypatch) -> None:
        """Make the next manifest write fail as a full disk does."""
        raise NotImplementedError

    # ------------------------------------------------------------------------- round trips

    def test_roundtrip_arrays_attrs_globals_and_reopen(self, spath):
        meta = {"scenario": "[bed]\nn = 10\n", "hash": "abc", "engine": "0.1.0", "nested": {"k": [1, 2.5, None]}}
        s = create_store(spath, self.backend, meta)
        assert s.backend == self.backend and s.meta == meta
        assert s.current() is None and s.epochs() == []
        with pytest.raises(StoreError, match="no committed epoch"):
            s.read_epoch()
        write_epoch(s, 10)
        assert s.current() == 10 and s.epochs() == [10]
        assert_epoch(s, 10)
        assert_epoch(s, 10, reader=s.read_epoch())
        s.close()
        with pytest.raises(StoreError, match="closed"):
            s.begin_epoch(11)

        s2 = open_store(spath)
        assert s2.backend == self.backend and s2.meta == meta and s2.current() == 10
        assert s2.verify() == []
        assert_epoch(s2, 10, reader=s2.read_epoch())
        r = s2.read_epoch()
        assert r.domain_arrays(1)["vel"] == ((12, 2), np.dtype(np.float64))
        sub = r.read_domain(1, names=["vel", "ids"])
        assert list(sub) == ["vel", "ids"]
        with pytest.raises(StoreError, match="no array 'nope'"):
            r.read_domain(1, names=["nope"])
        with pytest.raises(StoreError, match="no domain 7"):
            r.read_domain(7)
        r.close()
        s2.close()

    def test_returned_arrays_are_independent(self, spath):
        s = create_store(spath, self.backend, {})
        a = np.arange(5.0)
        w = s.begin_epoch(1)
        w.write_domain(0, {"a": a})
        a[0] = 99.0  # caller reuses its buffer after writing
        w.commit()
        r = s.read_epoch()
        got = r.read_domain(0)["a"]
        assert got[0] == 0.0
        got[1] = -1.0  # caller mutates what it read
        assert r.read_domain(0)["a"][1] == 1.0
        assert s.verify() == []

    def test_numpy_scalars_in_attrs_and_non_native_byte_order(self, spath):
        s = create_store(spath, self.backend, {"n": np.int64(3)})
        w = s.begin_epoch(0)
        w.write_domain(0, {"be": np.arange(4, dtype=">f8")}, {"k": np.float64(0.1), "v": np.arange(3)})
        w.commit()
        r = s.read_epoch()
        got = r.read_domain(0)["be"]
        assert got.dtype == np.dtype("=f8") and np.array_equal(got, np.arange(4.0))
        assert r.domain_attrs(0) == {"k": 0.1, "v": [0, 1, 2]}
        assert s.meta == {"n": 3}

    def test_domain_without_arrays_and_no_globals(self, spath):
        s = create_store(spath, self.backend, {})
        w = s.begin_epoch(0)
        w.write_domain(3, {}, {"empty": True})
        w.commit()
        r = s.read_epoch()
        assert r.domains() == [3] and r.domain_len(3) == 0
        assert r.read_domain(3) == {} and r.domain_attrs(3) == {"empty": True}
        assert r.read_globals() == ({}, {})
        assert s.verify() == []

    def test_invalid_input_is_refused(self, spath):
        s = create_store(spath, self.backend, {})
        w = s.begin_epoch(1)
        for bad in ("a/b", "", ".hidden", "zarr.json", "x y", 3):
            with pytest.raises(StoreError, match="invalid array name"):
                w.write_domain(0, {bad: np.zeros(2)})
        with pytest.raises(StoreError, match="non-numeric dtype"):
            w.write_domain(0, {"s": np.array(["x"])})
        with pytest.raises(StoreError, match="at least 1 dimension"):
            w.write_domain(0, {"s": np.array(1.0)})
        with pytest.raises(StoreError, match="JSON"):
            w.write_domain(0, {"a": np.zeros(1)}, {"bad": object()})
        w.write_domain(0, {"a": np.zeros(1)})  # the writer is still usable
        with pytest.raises(StoreError, match="already written"):
            w.write_domain(0, {"a": np.zeros(1)})
        with pytest.raises(StoreError, match="still being written"):
            s.begin_epoch(2)
        w.write_globals({}, {})
        with pytest.raises(StoreError, match="already written"):
            w.write_globals({}, {})
        w.commit()
        with pytest.raises(StoreError, match="committed"):
            w.write_domain(1, {})
        with pytest.raises(StoreError, match="unknown backend"):
            create_store(spath + "x", "sqlite", {})

    def test_random_arrays_roundtrip_bit_exact(self, spath):
        s = create_store(spath, self.backend, {})
        state = {"step": 0}

        @settings(
            max_examples=20,
            deadline=None,
            database=None,
            suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
        )
        @given(
            doms=st.lists(array_dicts(), min_size=1, max_size=2),
            attrs=st.dictionaries(
                st.text(max_size=5),
                st.one_of(st.integers(), st.floats(allow_nan=False), st.text(max_size=5)),
                max_size=3,
            ),
            rows=st.data(),
        )
        def check(doms, attrs, rows):
            state["step"] += 1
            with s.begin_epoch(state["step"]) as w:
                for d, arrays in enumerate(doms):
                    w.write_domain(d, arrays, attrs)
                w.commit()
            r = s.read_epoch()
            assert r.step == state["step"] and r.domains() == list(range(len(doms)))
            for d, arrays in enumerate(doms):
                got = r.read_domain(d)
                assert list(got) == list(arrays)
                assert r.domain_attrs(d) == attrs
                for n, a in arrays.items():
                    assert_same(got[n], a)
                    assert np.array_equal(got[n], a, equal_nan=a.dtype.kind in "fc")
                if arrays:
                    first = next(iter(arrays.values()))
                    assert r.domain_len(d) == first.shape[0]
                    idx = np.array(
                        sorted(rows.draw(st.sets(st.integers(0, max(0, first.shape[0] - 1)), max_size=5)))
                        if first.shape[0]
                        else [],
                        dtype=np.int64,
                    )
                    part = r.read_domain(d, rows=idx, names=[next(iter(arrays))])
                    assert_same(part[next(iter(arrays))], first[idx])
            r.close()

        check()
        assert s.verify() == []

    # ------------------------------------------------------------------------- partial reads

    def test_partial_row_reads(self, spath):
        n = 1000
        s = create_store(spath, self.backend, {})
        arrays = {
            "x": np.arange(n, dtype=np.float64) * 0.5,
            "v": np.arange(3 * n, dtype=np.int32).reshape(n, 3),
            "f": np.arange(n) % 3 == 0,
            "ptr": np.arange(n + 1, dtype=np.int64),
        }
        w = s.begin_epoch(1)
        w.write_domain(0, arrays)
        w.commit()
        r = open_store(spath, repair=False).read_epoch()  # a reader beside the open writer
        selections = [
            slice(10, 20),
            slice(0, n),
            slice(990, 2000),
            slice(5, 5),
            slice(None, None, 7),
            slice(900, 100, -3),
            np.array([0, 1, 2, 500, 501, 999]),
            np.array([999, 3, 3, 0]),
            np.array([], dtype=np.int64),
            np.array([-1, -2]),
            np.arange(n) % 5 == 1,
        ]
        for sel in selections:
            got = r.read_domain(0, names=["x", "v", "f"], rows=sel)
            for k in ("x", "v", "f"):
                assert_same(got[k], arrays[k][sel])
        with pytest.raises(StoreError, match="out of range"):
            r.read_domain(0, names=["x"], rows=np.array([n]))
        with pytest.raises(StoreError, match="rows must be"):
            r.read_domain(0, names=["x"], rows=np.array([[1]]))
        assert_same(r.read_domain(0, names=["ptr"], rows=np.array([n]))["ptr"], np.array([n]))
        r.close()

    # ------------------------------------------------------------------------- commit protocol

    def test_uncommitted_and_aborted_writers_leave_current_unchanged(self, spath):
        s = create_store(spath, self.backend, {})
        write_epoch(s, 1)
        # aborted writer
        w = s.begin_epoch(2)
        w.write_domain(0, domain_arrays(2, 0))
        w.abort()
        w.abort()  # idempotent
        assert s.current() == 1
        # exception inside the context manager aborts
        with pytest.raises(ZeroDivisionError):
            with s.begin_epoch(2) as w:
                w.write_domain(0, domain_arrays(2, 0))
                1 / 0
        # leaving the block without commit discards the epoch
        with s.begin_epoch(2) as w:
            w.write_domain(0, domain_arrays(2, 0))
        assert s.current() == 1
        if self.on_disk:
            assert epoch_entries(spath) == ["e000000000001." + self.ext]
        # a writer that is never finished (crash): reopening cleans up and sees epoch 1
        w = s.begin_epoch(2)
        w.write_domain(0, domain_arrays(2, 0))
        w.write_domain(1, domain_arrays(2, 1))
        if self.on_disk:
            assert any(".tmp-" in n for n in epoch_entries(spath))
            with pytest.raises(StoreError, match="already has this store open for writing"):
                open_store(spath)  # a second writer is refused while s holds the lock
            s._lock.release()  # the crash: the kernel drops a dead writer's lock
        s2 = open_store(spath)
        assert s2.current() == 1 and s2.epochs() == [1]
        assert_epoch(s2, 1, reader=s2.read_epoch())
        if self.on_disk:
            assert not any(".tmp-" in n for n in epoch_entries(spath))
            assert any(".tmp-" in r for r in s2.repaired)
        w.abort()
        s2.close()

    def test_failed_manifest_write_leaves_store_unchanged(self, spath, monkeypatch):
        s = create_store(spath, self.backend, {})
        write_epoch(s, 1)
        w = s.begin_epoch(2)
        w.write_domain(0, domain_arrays(2, 0))
        self.fail_manifest_write(s, spath, monkeypatch)
        with pytest.raises(StoreError, match="disk full or file too large"):
            w.commit()
        monkeypatch.undo()
        assert s.current() == 1 and s.epochs() == [1]
        if self.on_disk:
            assert [n[:14] for n in epoch_entries(spath)] == ["e000000000001."]
            assert not pathlib.Path(spath, "MANIFEST.json.tmp").exists()
        s2 = open_store(spath, repair=False)  # (s still holds the write lock)
        assert s2.current() == 1 and s2.verify() == [] and s2.leftovers() == []
        write_epoch(s, 2)  # and the store is still usable
        assert s.epochs() == [1, 2] and open_store(spath, repair=False).verify() == []

    def test_previous_epoch_kept_older_removed(self, spath):
        s = create_store(spath, self.backend, {})
        write_epoch(s, 1)
        write_epoch(s, 2, durable=True)
        assert s.epochs() == [1, 2]
        write_epoch(s, 3)
        assert s.epochs() == [2, 3] and s.current() == 3
        if self.on_disk:
            assert [n[:14] for n in epoch_entries(spath)] == ["e000000000002.", "e000000000003."]
            m = json.loads(pathlib.Path(spath, "MANIFEST.json").read_text())
            assert m["format"] == "ooc-dem-store" and m["format_version"] == 2 and m["backend"] == self.backend
            assert m["current"]["step"] == 3 and m["previous"]["step"] == 2
            for f in m["current"]["files"]:
                assert os.path.getsize(os.path.join(spath, f["path"])) == f["size"]
        assert_epoch(s, 2)
        assert_epoch(s, 3)
        with pytest.raises(StoreError, match="not in the manifest"):
            s.read_epoch(1)
        with pytest.raises(StoreError, match="not newer than the previous"):
            s.begin_epoch(2)
        assert open_store(spath, repair=False).epochs() == [2, 3]

    def test_prune(self, spath):
        s = create_store(spath, self.backend, {})
        assert s.prune(1) == []
        for step in (5, 6, 7):
            write_epoch(s, step)
        assert s.prune(2) == []
        assert s.prune(1) == [6]
        assert s.epochs() == [7] and s.prune(0) == [] and s.epochs() == [7]
        if self.on_disk:
            assert [n[:14] for n in epoch_entries(spath)] == ["e000000000007."]
        s.close()
        s2 = open_store(spath)
        assert s2.epochs() == [7] and s2.verify() == []
        write_epoch(s2, 8)
        assert s2.epochs() == [7, 8]

    # ------------------------------------------------------------------------- verification

    @pytest.mark.parametrize("how", ["flip", "truncate", "delete_group"])
    def test_verify_detects_damage_and_falls_back(self, spath, how):
        s = create_store(spath, self.backend, {})
        write_epoch(s, 1)
        write_epoch(s, 2)
        s.close()
        name = self.corrupt(spath, how)
        s = open_store(spath)
        problems = s.verify()
        assert problems and all(p.startswith("epoch 2: ") for p in problems)
        assert any(name in p for p in problems), problems
        if how == "delete_group":
            assert any("group /domains/d0001 missing" in p for p in problems), problems
        assert s.verify(1) == []
        assert s.verify(2) == problems
        # the current epoch fails -> fall back to the previous one, with a warning
        r = s.read_epoch()
        assert r.step == 1 and s.warnings and "using previous epoch 1" in s.warnings[0]
        assert_epoch(s, 1, reader=r)
        with pytest.raises(StoreError, match="epoch 2 is corrupt"):
            s.read_epoch(2)
        # resuming from epoch 1 rewrites epoch 2 without touching the damaged one in place
        write_epoch(s, 2)
        assert s.epochs() == [1, 2] and s.verify() == []
        s3 = open_store(spath, repair=False)
        assert s3.verify() == [] and s3.read_epoch().step == 2 and not s3.warnings
        assert_epoch(s3, 2)

    def test_both_epochs_corrupt_raises(self, spath):
        s = create_store(spath, self.backend, {})
        write_epoch(s, 1)
        s.close()
        self.corrupt(spath, "flip")
        with pytest.raises(StoreError, match="no previous epoch"):
            open_store(spath, repair=False).read_epoch()
        s = open_store(spath)
        write_epoch(s, 1)  # same step as the corrupt current: replaces it
        write_epoch(s, 2)
        s.close()
        self.corrupt(spath, "flip")
        self.spoil_previous(spath)
        with pytest.raises(StoreError, match="epoch 2 is corrupt .* and previous epoch 1 too"):
            open_store(spath, repair=False).read_epoch()

    # ------------------------------------------------------------------------- opening / creating

    def test_create_over_existing_store_replaces_it(self, spath):
        s = create_store(spath, self.backend, {"run": 1})
        write_epoch(s, 1)
        s.close()
        # another backend of the same kind (a directory of files, or memory)
        other = next((b for b in BACKENDS if b != self.backend and (b == "memory") != self.on_disk), self.backend)
        s = create_store(spath, other, {"run": 2})
        assert s.current() is None and s.epochs() == []
        s2 = open_store(spath, repair=False)
        assert s2.meta == {"run": 2} and s2.backend == other and s2.current() is None
        if self.on_disk:
            assert epoch_entries(spath) == []


# ----------------------------------------------------------------------------- backends of files

_DISK_FULL_CHILD = textwrap.dedent("""
    import os, resource, signal, sys
    sys.path.insert(0, {repo!r})
    import numpy as np, h5py, zarr
    from ooc_dem import storage
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    s = storage.create_store({path!r}, {backend!r}, {{"run": "disk-full"}})
    w = s.begin_epoch(1)
    w.write_domain(0, {{"x": np.arange(1000.0)}}, {{"ok": True}})
    w.commit()
    resource.setrlimit(resource.RLIMIT_FSIZE, (256 * 1024, 256 * 1024))
    try:
        w = s.begin_epoch(2)
        w.write_domain(0, {{"x": np.arange(1000.0)}})
        w.write_domain(1, {{"x": np.zeros(200_000)}})       # 1.6 MB > limit
        w.commit()
    except storage.StoreError as e:
        print("STOREERROR", e)
        print("ENTRIES", sorted(os.listdir(os.path.join({path!r}, "epochs"))))
        print("CURRENT", s.current())
    else:
        print("NO ERROR")
""")


class DiskStoreTests(StoreTests):
    """The checks of a backend whose store is a directory of files: leftovers, checksums,
    the manifest file, foreign directories, a full disk, and epochs that the format's own
    library reads (``read_with_library``), for every compression the backend offers."""

    on_disk = True

    def pytest_generate_tests(self, metafunc):
        """A test taking ``compression`` and not given its own runs with each of the backend's."""
        own = any("compression" in m.args[0] for m in metafunc.definition.iter_markers("parametrize"))
        if "compression" in metafunc.fixturenames and not own:
            metafunc.parametrize("compression", [None, *COMPRESSIONS[self.backend]], ids=lambda c: c or "none")

    def fail_manifest_write(self, store, spath, monkeypatch):
        def boom(src, dst):
            raise OSError(28, "No space left on device")

        monkeypatch.setattr(os, "replace", boom)  # (after the data: zarr uses it too)

    def spoil_previous(self, spath):
        m = json.loads(pathlib.Path(spath, "MANIFEST.json").read_text())
        p = pathlib.Path(spath, m["previous"]["files"][-1]["path"])
        with open(p, "r+b") as fh:
            fh.truncate(p.stat().st_size - 1)

    def read_with_library(self, path: pathlib.Path, names) -> tuple[dict, float]:
        """Domain 0's arrays ``names`` and the global ``scalar`` of the epoch file at ``path``,
        read by the format's own library."""
        raise NotImplementedError

    def test_repair_removes_leftovers(self, spath):
        s = create_store(spath, self.backend, {})
        write_epoch(s, 1)
        s.close()
        cur = current_path(spath)
        stray = cur.with_name(cur.name.replace("000000001", "000000099"))
        (shutil.copytree if cur.is_dir() else shutil.copy)(cur, stray)  # renamed but never committed
        pathlib.Path(spath, "MANIFEST.json.tmp").write_text("{half a manif")
        pathlib.Path(spath, "epochs", cur.name + ".tmp-12345").write_bytes(b"partial")
        pathlib.Path(spath, "notes.txt").write_text("user file")  # not ours: left alone
        s = open_store(spath, repair=False)
        assert len(epoch_entries(spath)) == 3 and s.repaired == []
        s = open_store(spath)
        assert epoch_entries(spath) == [cur.name]
        assert len(s.repaired) == 3
        assert not pathlib.Path(spath, "MANIFEST.json.tmp").exists()
        assert pathlib.Path(spath, "notes.txt").exists()
        assert s.verify() == []

    def test_files_carry_xxh3_128_and_sha256_of_older_stores_is_still_checked(self, spath):
        """New epochs record XXH3-128 of each file's bytes (the value the xxhash package gives);
        an epoch whose entries carry sha256, as stores written before did, verifies and reads,
        and a changed byte under either checksum is a mismatch named by the checksum."""
        import hashlib

        import xxhash

        p = spath
        s = create_store(p, self.backend, {})
        write_epoch(s, 1)
        write_epoch(s, 2)
        s.close()
        mpath = pathlib.Path(p, "MANIFEST.json")
        m = json.loads(mpath.read_text())
        for e in (m["current"], m["previous"]):
            for f in e["files"]:
                data = pathlib.Path(p, f["path"]).read_bytes()
                assert set(f) == {"path", "size", "xxh3_128"}
                assert f["xxh3_128"] == xxhash.xxh3_128(data).hexdigest() and f["size"] == len(data)
        # the previous epoch re-signed with sha256, as an older store recorded it
        for f in m["previous"]["files"]:
            data = pathlib.Path(p, f["path"]).read_bytes()
            del f["xxh3_128"]
            f["sha256"] = hashlib.sha256(data).hexdigest()
        mpath.write_text(json.dumps(m))
        s = open_store(p)
        assert s.verify(1) == [] and s.verify(2) == []
        assert_epoch(s, 1, reader=s.read_epoch(1))
        s.close()
        for step, entry, name in ((2, "current", "xxh3_128"), (1, "previous", "sha256")):
            flip_byte(pathlib.Path(p, m[entry]["files"][-1]["path"]))
            problems = open_store(p, repair=False).verify(step)
            assert problems and f"{name} mismatch (content changed)" in problems[0], problems

    def test_missing_or_unreadable_manifest(self, spath):
        p = spath
        s = create_store(p, self.backend, {})
        write_epoch(s, 1)
        write_epoch(s, 2)
        s.close()
        before = epoch_entries(p)
        mp = pathlib.Path(p, "MANIFEST.json")
        good = mp.read_text()
        mp.write_text(good[: len(good) // 2])
        with pytest.raises(StoreError, match="MANIFEST.json missing or unreadable"):
            open_store(p)
        mp.unlink()
        with pytest.raises(StoreError, match="MANIFEST.json missing or unreadable"):
            open_store(p)
        assert epoch_entries(p) == before  # nothing deleted by a failed open
        mp.write_text(good)
        assert open_store(p).verify() == []
        bad = json.loads(good)
        bad["format_version"] = 99
        mp.write_text(json.dumps(bad))
        with pytest.raises(StoreError, match="unsupported format_version 99"):
            open_store(p)
        bad = json.loads(good)
        bad["current"]["files"] = "nope"
        mp.write_text(json.dumps(bad))
        with pytest.raises(StoreError, match="malformed"):
            open_store(p)

    def test_foreign_directory_refused(self, tmp_path):
        d = tmp_path / "foreign"
        d.mkdir()
        (d / "thesis.tex").write_text("precious")
        with pytest.raises(StoreError, match="not an ooc-dem store"):
            create_store(str(d), self.backend, {})
        with pytest.raises(StoreError, match="not an ooc-dem store"):
            open_store(str(d))
        (d / "MANIFEST.json").write_text(json.dumps({"format": "something-else"}))
        with pytest.raises(StoreError, match="not an ooc-dem store"):
            create_store(d, self.backend, {})
        with pytest.raises(StoreError, match="not an ooc-dem store"):
            open_store(d)
        assert sorted(os.listdir(d)) == ["MANIFEST.json", "thesis.tex"]
        f = tmp_path / "file"
        f.write_text("x")
        with pytest.raises(StoreError, match="not a directory"):
            create_store(f, self.backend, {})
        with pytest.raises(StoreError, match="does not exist"):
            open_store(tmp_path / "nowhere")
        (tmp_path / "empty").mkdir()
        with pytest.raises(StoreError, match="not an ooc-dem store"):
            open_store(tmp_path / "empty")
        s = create_store(tmp_path / "empty", self.backend, {"ok": 1})  # empty dir is fine
        assert open_store(tmp_path / "empty", repair=False).meta == {"ok": 1}
        s.close()

    def test_disk_full_gives_store_error_and_keeps_committed_epoch(self, spath):
        p = spath
        res = subprocess.run(
            [sys.executable, "-c", _DISK_FULL_CHILD.format(repo=str(REPO), path=p, backend=self.backend)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert res.returncode == 0, res.stderr
        out = res.stdout
        assert "STOREERROR" in out, out + res.stderr
        line = next(x for x in out.splitlines() if x.startswith("STOREERROR"))
        assert "disk full or file too large" in line, line
        assert f"ENTRIES ['e000000000001.{self.ext}']" in out, out
        assert "CURRENT 1" in out
        s = open_store(p)
        assert s.epochs() == [1] and s.verify() == [] and s.meta == {"run": "disk-full"}
        r = s.read_epoch()
        assert_same(r.read_domain(0)["x"], np.arange(1000.0))
        assert r.domain_attrs(0) == {"ok": True}
        write_epoch(s, 2)  # the store is still usable
        assert s.epochs() == [1, 2]

    def test_epochs_are_read_by_the_formats_library_and_reopen_compressed(self, spath, compression):
        """What the store writes (every compression) is what the format's own library
        (zarr-python's ZipStore, h5py) reads, bit for bit; the compression is kept when the
        store is opened again; a compressed epoch is smaller than the raw record when the
        data compresses."""
        p = spath
        rng = np.random.default_rng(3)
        arrays = {
            "id": np.arange(300_001, dtype=np.int64),
            "pos": rng.random((300_001, 2)),
            "flag": rng.random(300_001) < 0.5,
            "mat": np.zeros(300_001, np.int32),
            "z": np.array([1 + 2j, 3 - 4j]),
            "empty": np.zeros((0, 3)),
        }
        glob = {"scalar": np.float64(2.5), "ws": np.arange(6.0)}
        s = create_store(p, self.backend, {}, compression=compression)
        w = s.begin_epoch(7)
        w.write_domain(0, arrays, {"n": 300_001})
        w.write_globals(glob, {"t": 1.0})
        w.commit()
        s.close()
        s = open_store(p)
        assert s.compression == compression
        write_epoch(s, 8)  # written again with the same compression
        assert s.manifest()["current"].get("compression") == compression
        r = s.read_epoch(7)
        back = r.read_domain(0)
        assert all(np.array_equal(back[k], arrays[k]) and back[k].dtype == arrays[k].dtype for k in arrays)
        assert np.array_equal(r.read_domain(0, ["pos"], slice(123_456, 250_001))["pos"], arrays["pos"][123_456:250_001])
        g, _ = r.read_globals()
        assert g["scalar"] == 2.5 and np.array_equal(g["ws"], glob["ws"])
        r.close()
        path = pathlib.Path(p, s.manifest()["previous"]["path"])
        size = path.stat().st_size
        s.close()
        read, scalar = self.read_with_library(path, list(arrays))
        assert scalar == 2.5
        assert all(np.array_equal(read[k], arrays[k]) for k in arrays)
        raw = sum(a.nbytes for a in arrays.values())
        if compression is not None:  # ids, zeros and booleans compress; the random floats not
            assert size < 0.9 * raw, (size, raw)


# ----------------------------------------------------------------------------- the backends


class TestHDF5(DiskStoreTests):
    backend = "hdf5"
    ext = "h5"

    def corrupt(self, spath, how):
        import h5py

        f = a_data_file(spath)
        if how == "flip":
            with h5py.File(f, "r", locking=False) as h:
                off = h["domains/d0000/x"].id.get_offset()
            flip_byte(f, off + 8)
            return f.name
        if how == "truncate":
            with open(f, "r+b") as fh:
                fh.truncate(f.stat().st_size - 9)
            return f.name
        with h5py.File(f, "r+", locking=False) as h:
            del h["domains/d0001"]
        return "d0001"

    def read_with_library(self, path, names):
        import h5py

        with h5py.File(path, "r", locking=False) as f:
            return {k: f[f"domains/d0000/{k}"][()] for k in names}, f["globals/scalar"][()]


class TestZarr(DiskStoreTests):
    backend = "zarr"
    ext = "zip"

    def corrupt(self, spath, how):
        f = a_data_file(spath)
        if how == "flip":
            flip_byte(f)
            return f.name
        if how == "truncate":
            with open(f, "r+b") as fh:
                fh.truncate(f.stat().st_size - 9)
            return f.name
        zip_without(current_path(spath), "domains/d0001/")
        return "d0001"

    def read_with_library(self, path, names):
        import zarr
        from zarr.storage import ZipStore

        z = zarr.open_group(store=ZipStore(str(path), mode="r"), mode="r")
        return {k: z[f"domains/d0000/{k}"][...] for k in names}, z["globals/scalar"][()]

    @pytest.mark.parametrize("compression", [None, "zstd"])
    def test_partial_read_only_touches_requested_bytes(self, spath, monkeypatch, compression):
        """A row range reads only those rows' bytes (uncompressed: at their offset in the archive)
        or the chunks holding them (compressed), never the whole array."""
        s = create_store(spath, self.backend, {}, compression=compression)
        # 8 MB of random floats (barely compressible: the group is far beyond the 1 MiB a reader
        # reads in one go), 8 chunks of 1 MiB when compressed
        x = np.random.default_rng(5).random(1_000_000)
        w = s.begin_epoch(1)
        w.write_domain(0, {"x": x})
        w.commit()
        r = s.read_epoch()
        assert_same(r.read_domain(0, rows=slice(0, 1))["x"], x[:1])  # metadata now cached
        read = []
        real = os.preadv

        def counting(fd, bufs, offset, *a):
            n = real(fd, bufs, offset, *a)
            read.append(n)
            return n

        monkeypatch.setattr(os, "preadv", counting)
        assert_same(r.read_domain(0, rows=slice(300_000, 300_100))["x"], x[300_000:300_100])
        if compression is None:
            assert sum(read) == 100 * 8, read
        else:  # one compressed chunk of 131072 rows (and its 30-byte zip header), not the 8 MB
            assert len(read) <= 2 and 0 < sum(read) < (1 << 20), read
        read.clear()
        assert_same(r.read_domain(0, rows=np.array([1, 999_999]))["x"], x[[1, 999_999]])
        assert sum(read) <= (2 << 20), read
        r.close()
        s.close()

    def test_truncated_epoch_is_corrupt_and_says_so(self, spath):
        s = create_store(spath, self.backend, {})
        x = np.arange(1000, dtype=np.float64)
        for step in (1, 2):
            w = s.begin_epoch(step)
            w.write_domain(0, {"x": x + step})
            w.commit()
        s.close()
        f = a_data_file(spath)
        with open(f, "r+b") as fh:
            fh.truncate(f.stat().st_size // 2)  # the central directory is gone
        s = open_store(spath)
        with pytest.raises(StoreError, match="cannot open epoch 2"):
            s.read_epoch(verify=False)
        r = s.read_epoch()  # falls back to epoch 1
        assert r.step == 1 and "using previous epoch 1" in s.warnings[0]
        assert_same(r.read_domain(0)["x"], x + 1)


class TestMemory(StoreTests):
    backend = "memory"

    @staticmethod
    def _epochs(spath):
        """The memory store's manifest and epochs (there is no file to damage)."""
        from ooc_dem.storage import _memory

        b = _memory._REGISTRY[spath]
        return json.loads(b.manifest_json), b.epochs

    def corrupt(self, spath, how):
        m, epochs = self._epochs(spath)
        grp = epochs[m["current"]["path"]]
        if how == "flip":
            grp["domains/d0000"]["arrays"]["x"][3] += 1e-12
            return "d0000/x"
        if how == "truncate":
            grp["domains/d0000"]["arrays"]["x"] = grp["domains/d0000"]["arrays"]["x"][:5].copy()
            return "d0000/x"
        del grp["domains/d0001"]
        return "d0001"

    def spoil_previous(self, spath):
        m, epochs = self._epochs(spath)
        epochs[m["previous"]["path"]]["domains/d0001"]["arrays"]["ids"][0] = -7

    def fail_manifest_write(self, store, spath, monkeypatch):
        def boom(m, durable=False):
            raise StoreError(f"{spath}/MANIFEST.json: disk full or file too large (simulated)")

        monkeypatch.setattr(store._place, "write_manifest", boom)

    def test_registry(self):
        key = "mem://conformance-registry"
        s = create_store(key, "memory", {"a": 1})
        write_epoch(s, 4)
        s.close()
        s2 = open_store(key)
        assert s2.current() == 4 and s2.meta == {"a": 1}
        assert_epoch(s2, 4)
        assert drop_memory_store(key)
        with pytest.raises(StoreError, match="no such memory store"):
            open_store(key)


def test_every_backend_has_its_conformance_class():
    tested = {c.backend for c in (TestHDF5, TestZarr, TestMemory)}
    assert tested == set(BACKENDS)


# ----------------------------------------------------------------------------- helpers of the package


def test_gather_rows_windows_match_fancy_indexing():
    a = np.arange(5000 * 2, dtype=np.float64).reshape(5000, 2)
    calls = []

    def read_range(s, e, out):
        calls.append((s, e))
        out[...] = a[s:e]

    rng = np.random.default_rng(0)
    idx = np.sort(rng.choice(5000, 300, replace=False))
    got = gather_rows(read_range, idx, a.shape, a.dtype, window_bytes=1600)  # 100 rows per window
    assert_same(got, a[idx])
    assert max(e - s for s, e in calls) <= 100  # never reads more than a window
    assert sum(e - s for s, e in calls) < a.shape[0]  # ... nor the whole array
    calls.clear()
    assert_same(gather_rows(read_range, np.arange(100, 4000), a.shape, a.dtype, 1600), a[100:4000])
    assert all(e - s <= 100 for s, e in calls)


def test_store_errors_are_one_line():
    e = write_error(
        "/x/e1.h5", RuntimeError("Can't write (file write failed: errno = 27,\n error message = 'File too large')")
    )
    assert isinstance(e, StoreError) and "\n" not in str(e)
    assert str(e).startswith("/x/e1.h5: disk full or file too large (")
    assert "disk full" in str(write_error("p", OSError(28, "No space left on device")))
    assert "write failed" in str(write_error("p", OSError(13, "Permission denied")))


def test_drop_page_cache_never_raises(tmp_path):
    f = tmp_path / "f"
    f.write_bytes(b"x" * 10000)
    storage.drop_page_cache(f)
    storage.drop_page_cache(f, sync=True)
    storage.drop_page_cache(tmp_path)
    storage.drop_page_cache(tmp_path / "missing")


def test_start_writeback_never_raises_nor_blocks(tmp_path):
    """The write-back hint on a file, a directory, a missing path, and a FIFO (opened
    non-blocking: a FIFO with no writer would otherwise hang the writer)."""
    from ooc_dem.storage._util import start_writeback

    f = tmp_path / "f"
    f.write_bytes(b"x" * 100000)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for p in (f, tmp_path, tmp_path / "missing", fifo):
        start_writeback(p)
    assert f.read_bytes() == b"x" * 100000
