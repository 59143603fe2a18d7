"""A store is untrusted input: nothing in MANIFEST.json or epochs/ may make
`ooc-dem` read, write or delete outside the store, lose data inside it, hang, accept a
wrong state, or print a traceback.

Each test takes a real store made by the CLI (a tiny run of the quick rig), edits it the
way a hostile or careless party could, runs the CLI's `main()` on it (in this process; a real
process for the runs that must finish, and for the writer whose lock is held), and checks: exit 2
with exactly one line on stderr, no traceback, a `victim` directory beside the store
untouched, and (where nothing may change) the store itself untouched.
"""

import copy
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest

from support.cli import cli_in_process, one_line_error, run_cli
from support.stores import zarr_epochs_as_directories

STEPS, CKPT = 20, 10  # current epoch 20, previous epoch 10
RESUME_MORE = ["--steps", "40", "--no-progress", "--no-figures"]  # commits 30 and 40
HANG_TIMEOUT_S = 120  # a command reading /dev/zero or a FIFO never returns


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    """Finished monolithic stores of the quick rig, one per backend, built once."""
    made = {}

    def get(backend):
        if backend not in made:
            out = tmp_path_factory.mktemp(f"hostile-{backend}") / "store"
            run_cli(
                "run",
                "quick",
                "--steps",
                STEPS,
                "--checkpoint-every",
                CKPT,
                "--out",
                out,
                "--backend",
                backend,
                "--no-progress",
                "--no-figures",
                check=True,
            )
            made[backend] = out
        return made[backend]

    return get


def _make(pristine, tmp_path, backend="hdf5"):
    """A copy of the pristine store at tmp_path/store and a victim directory beside it."""
    store = tmp_path / "store"
    shutil.copytree(pristine(backend), store, symlinks=True)
    victim = tmp_path / "victim"
    (victim / "sub").mkdir(parents=True)
    (victim / "precious.txt").write_text("thesis draft")
    (victim / "sub" / "data.bin").write_bytes(bytes(range(256)))
    return store, victim


def _snapshot(root):
    """Every entry under root: relative path -> file bytes, link target or "<dir>"."""
    out = {}
    for dirpath, dirs, files in os.walk(root):
        for n in dirs + files:
            p = Path(dirpath, n)
            rel = str(p.relative_to(root))
            if p.is_symlink():
                out[rel] = "-> " + os.readlink(p)
            elif p.is_dir():
                out[rel] = "<dir>"
            elif p.is_file():
                out[rel] = p.read_bytes()
            else:
                out[rel] = "<special>"
    return out


def _manifest(store):
    return json.loads((Path(store) / "MANIFEST.json").read_text())


def _write_manifest(store, m):
    (Path(store) / "MANIFEST.json").write_text(json.dumps(m, indent=1))


def _edit(store, fn):
    m = _manifest(store)
    fn(m)
    _write_manifest(store, m)
    return m


def _cli(*args, timeout=HANG_TIMEOUT_S):
    """`ooc-dem ...` in this process (refusals and reads); one that hangs fails the test."""
    return cli_in_process(*args, timeout=timeout)


def _path_to_root(store) -> str:
    """ "../" enough times to climb from the store directory to "/"."""
    return "../" * (len(Path(store).resolve().parts) - 1)


# ------------------------------------------------------------------ 1. paths are confined


@pytest.mark.parametrize("where", ["relative", "absolute"])
def test_prune_never_deletes_a_previous_path_outside_the_store(pristine, tmp_path, where):
    store, victim = _make(pristine, tmp_path)
    _edit(store, lambda m: m["previous"].update(path="../victim" if where == "relative" else str(victim)))
    before, vbefore = _snapshot(store), _snapshot(victim)
    one_line_error(_cli("checkpoint", "prune", store, "--keep", "1"), "previous epoch", "victim")
    assert _snapshot(victim) == vbefore
    assert _snapshot(store) == before


def test_resume_never_deletes_a_previous_path_outside_the_store(pristine, tmp_path):
    """The old previous epoch is deleted on resume's first commit: here it names a file of ours."""
    store, victim = _make(pristine, tmp_path)
    _edit(store, lambda m: m["previous"].update(path="../victim/sub/data.bin"))
    vbefore = _snapshot(victim)
    one_line_error(_cli("resume", store, *RESUME_MORE), "previous epoch")
    assert _snapshot(victim) == vbefore


def test_resume_never_deletes_a_current_epoch_outside_the_store(pristine, tmp_path):
    """A current epoch that lives outside the store (a valid copy, with its checksums) would be
    read, and deleted once two newer commits age it out."""
    store, victim = _make(pristine, tmp_path)
    m = _manifest(store)
    shutil.copy(store / m["current"]["path"], victim / "e000000000020.h5")
    outside = "../victim/e000000000020.h5"

    def point_outside(m):
        m["current"]["path"] = outside
        m["current"]["files"][0]["path"] = outside

    _edit(store, point_outside)
    vbefore = _snapshot(victim)
    one_line_error(_cli("resume", store, *RESUME_MORE), "current epoch", "victim")
    assert _snapshot(victim) == vbefore


def test_repair_never_deletes_through_a_symlinked_epochs_dir(pristine, tmp_path):
    """With epochs/ a symbolic link, resume's clean-up would delete epoch-like names in the
    link's target; the store is refused instead, naming epochs/."""
    store, victim = _make(pristine, tmp_path)
    target = victim / "epochs-elsewhere"
    shutil.move(store / "epochs", target)
    (target / "e000000000005.h5").write_bytes(b"someone else's file named like an epoch")
    (target / "e000000000030.h5.tmp-1").write_bytes(b"someone else's file named like a temporary")
    os.symlink(target, store / "epochs")
    vbefore = _snapshot(victim)
    for cmd in (
        ("resume", store, *RESUME_MORE),
        ("checkpoint", "prune", store, "--keep", "1"),
        ("checkpoint", "verify", store),
    ):
        one_line_error(_cli(*cmd), "epochs", "symbolic link")
        assert _snapshot(victim) == vbefore


@pytest.mark.parametrize("command", ["verify", "resume"])
def test_a_file_entry_on_dev_zero_is_refused_not_read_forever(pristine, tmp_path, command):
    store, victim = _make(pristine, tmp_path)
    zero = _path_to_root(store) + "dev/zero"
    _edit(store, lambda m: m["current"]["files"].append({"path": zero, "size": 0, "sha256": "0" * 64}))
    before = _snapshot(store)
    cmd = ("checkpoint", "verify", store) if command == "verify" else ("resume", store, *RESUME_MORE)
    one_line_error(_cli(*cmd), "current epoch", "dev/zero")
    assert _snapshot(store) == before


# ------------------------------------------------------------------ 2. no data loss inside


@pytest.mark.parametrize(
    "path", [".", "epochs", "MANIFEST.json", "epochs/../epochs", "epochs/", "epochs//e000000000010.h5"]
)
def test_prune_never_deletes_the_store_its_epochs_dir_or_its_manifest(pristine, tmp_path, path):
    store, victim = _make(pristine, tmp_path)
    _edit(store, lambda m: m["previous"].update(path=path))
    before = _snapshot(store)
    one_line_error(_cli("checkpoint", "prune", store, "--keep", "1"), "previous epoch")
    assert _snapshot(store) == before


@pytest.mark.parametrize("same", ["whole entry", "path", "step"])
def test_prune_never_deletes_the_current_epoch_named_as_previous(pristine, tmp_path, same):
    store, victim = _make(pristine, tmp_path)

    def alias(m):
        if same == "whole entry":
            m["previous"] = copy.deepcopy(m["current"])
        elif same == "path":  # the current epoch's path under an older step
            m["previous"] = dict(copy.deepcopy(m["current"]), step=m["previous"]["step"])
        else:  # the current step under the previous path
            m["previous"]["step"] = m["current"]["step"]

    _edit(store, alias)
    before = _snapshot(store)
    one_line_error(_cli("checkpoint", "prune", store, "--keep", "1"), "MANIFEST.json")
    assert _snapshot(store) == before
    cp = _cli("checkpoint", "list", store)
    assert cp.returncode == 2 and "Traceback" not in cp.stderr, cp.stderr


# ------------------------------------------------------------------ 3. checksums always cover the epoch


def _flip_data_byte(store):
    """Flip one byte inside the x positions of the current HDF5 epoch (valid file, wrong data)."""
    f = store / _manifest(store)["current"]["path"]
    with h5py.File(f, "r", locking=False) as h:
        off = h["domains/d0000/pos"].id.get_offset()
    with open(f, "r+b") as fh:
        fh.seek(off + 8 * 7 + 3)
        b = fh.read(1)
        fh.seek(off + 8 * 7 + 3)
        fh.write(bytes([b[0] ^ 0x10]))


@pytest.mark.parametrize("listing", ["no files", "another epoch's file"])
def test_an_epoch_whose_files_are_not_listed_is_refused(pristine, tmp_path, listing):
    """`"files": []` (or a list naming another, intact file) and flipped bytes in the epoch file:
    `verify` must not say OK and `resume` must not continue from the wrong state."""
    store, victim = _make(pristine, tmp_path)
    _flip_data_byte(store)

    def unlist(m):
        m["current"]["files"] = [] if listing == "no files" else copy.deepcopy(m["previous"]["files"])

    _edit(store, unlist)
    cp = _cli("checkpoint", "verify", store)
    assert "OK" not in cp.stdout, cp.stdout
    one_line_error(cp, "current epoch")
    before = _snapshot(store)
    one_line_error(_cli("resume", store, *RESUME_MORE), "current epoch")
    assert _snapshot(store) == before


def test_zarr_epoch_files_must_be_exactly_the_listed_ones(pristine, tmp_path):
    store, victim = _make(pristine, tmp_path, "zarr")
    _edit(store, lambda m: m["current"].update(files=[]))
    one_line_error(_cli("checkpoint", "verify", store), "current epoch", "no files")


def test_a_symlink_inside_a_zarr_epoch_is_a_verification_problem(pristine, tmp_path):
    """A chunk replaced by a link to an identical file outside the store passes sizes and
    checksums; it is still not part of the store: verify fails, resume falls back. (Epochs
    in the directory layout of earlier versions: today's are one zip archive each.)"""
    store, victim = _make(pristine, tmp_path, "zarr")
    zarr_epochs_as_directories(store)
    chunk = store / _manifest(store)["current"]["path"] / "domains" / "d0000" / "pos" / "c" / "0" / "0"
    shutil.copy(chunk, victim / "chunk")
    chunk.unlink()
    os.symlink(victim / "chunk", chunk)
    vbefore = _snapshot(victim)
    cp = _cli("checkpoint", "verify", store)
    fails = [ln for ln in cp.stdout.splitlines() if ln.startswith("FAIL ")]
    assert any("epoch 20:" in ln and "symbolic link" in ln for ln in fails), cp.stdout
    one_line_error(cp, "problem(s) found", "falls back to epoch 10")
    cp = run_cli("resume", store, *RESUME_MORE, timeout=HANG_TIMEOUT_S)
    assert cp.returncode == 0 and "Traceback" not in cp.stderr, cp.stderr
    assert "using previous epoch 10" in cp.stderr, cp.stderr
    assert _snapshot(victim) == vbefore


# ------------------------------------------------------------------ 4. one writer per store


def _wait_for_commit(store, proc, timeout=300):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, "the run ended before it could be observed"
        try:
            m = _manifest(store)
            if m.get("current"):
                return m
        except (OSError, ValueError):
            pass
        time.sleep(0.2)
    pytest.fail("the run committed nothing in time")


def test_a_second_writer_is_refused_while_a_run_writes(pristine, tmp_path):
    store = tmp_path / "store"
    # epoch 0 is committed at the start and stays current while the run steps: `checkpoint hash`
    # of an epoch that a commit deletes under it is another matter (not the lock's)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ooc_dem.cli",
            "run",
            "quick",
            "--steps",
            "1000000",
            "--checkpoint-every",
            "1000000",
            "--out",
            str(store),
            "--no-progress",
            "--no-figures",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        _wait_for_commit(store, proc)
        one_line_error(
            _cli("resume", store, "--no-progress", "--no-figures"),
            "another process is writing this store",
            f"pid {proc.pid}",
        )
        one_line_error(_cli("checkpoint", "prune", store, "--keep", "1"), "is writing this store", str(proc.pid))
        for cmd in ("verify", "list", "hash"):  # read-only: never refused
            cp = _cli("checkpoint", cmd, store)
            assert cp.returncode == 0, (cmd, cp.stdout, cp.stderr)
        assert proc.poll() is None
    finally:
        proc.kill()
        proc.wait()
    step = _manifest(store)["current"]["step"]  # killed: the kernel dropped its lock
    cp = run_cli("resume", store, "--steps", step + CKPT, "--no-progress", "--no-figures", timeout=HANG_TIMEOUT_S)
    assert cp.returncode == 0, cp.stderr
    assert _manifest(store)["current"]["step"] == step + CKPT


@pytest.mark.parametrize("kind", ["hard link", "symlink"])
def test_a_planted_lock_file_is_never_written_through(pristine, tmp_path, kind):
    """The writer writes its pid into the lock file: a lock file that is another name of a
    file outside the store must be refused, not truncated."""
    store, victim = _make(pristine, tmp_path)
    lock = store / ".ooc-dem.lock"
    lock.unlink()
    (os.link if kind == "hard link" else os.symlink)(victim / "precious.txt", lock)
    vbefore = _snapshot(victim)
    one_line_error(_cli("resume", store, *RESUME_MORE), ".ooc-dem.lock")
    assert _snapshot(victim) == vbefore


def test_lock_file_is_part_of_the_store(tmp_path):
    """In one process: a second writer is refused, readers are not; closing releases; a
    directory holding only the lock file counts as empty."""
    from ooc_dem.storage import StoreError, create_store, open_store
    from ooc_dem.storage._disk import classify

    p = tmp_path / "s"
    s = create_store(p, "hdf5", {"k": 1})
    assert (p / ".ooc-dem.lock").is_file()
    assert classify(str(p))[0] == "store"
    with pytest.raises(StoreError, match="already has this store open for writing"):
        open_store(p)
    with open_store(p, repair=False) as r:
        assert r.meta == {"k": 1}
        with pytest.raises(StoreError, match="read-only"):
            r.begin_epoch(1)
    s.close()
    with open_store(p) as w:
        assert w.repaired == []
    for n in os.listdir(p):
        if n != ".ooc-dem.lock":
            shutil.rmtree(p / n) if (p / n).is_dir() else os.unlink(p / n)
    assert classify(str(p))[0] == "empty"
    create_store(p, "zarr", {}).close()


# ------------------------------------------------------------------ 5. hostile fields


def _rename_domain(key):
    def f(m):
        m["current"]["domains"][key] = m["current"]["domains"].pop("0")

    return f


def _set(role, field, value):
    def f(m):
        m[role][field] = value

    return f


def _set_file(field, value):
    def f(m):
        m["current"]["files"][0][field] = value

    return f


def _swap_checksum(name, value):
    """The first file's checksum replaced by `name`: `value` (None: no checksum at all)."""

    def f(m):
        entry = m["current"]["files"][0]
        entry.pop("xxh3_128")
        if name is not None:
            entry[name] = value

    return f


def _set_array(field, value):
    def f(m):
        spec = m["current"]["domains"]["0"]["arrays"]["pos"]
        spec[0 if field == "shape" else 1] = value

    return f


def _nest(depth):
    def f(m):
        v = 0
        for _ in range(depth):
            v = [v]
        m["meta"]["nested"] = v

    return f


HOSTILE = {
    "domain key x": (_rename_domain("x"), "domain key"),
    "domain key -1": (_rename_domain("-1"), "domain key"),
    "domain key 01": (_rename_domain("01"), "domain key"),
    "domain key ' 1'": (_rename_domain(" 1"), "domain key"),
    "step float": (_set("current", "step", 20.0), "step"),
    "step bool": (_set("current", "step", True), "step"),
    "step str": (_set("current", "step", "20"), "step"),
    "step huge": (_set("current", "step", 10**30), "step"),
    "step negative": (_set("previous", "step", -10), "step"),
    "path not a str": (_set("current", "path", ["epochs", "e000000000020.h5"]), "path"),
    "path with NUL": (_set("current", "path", "epochs/e000000000020.h5\0"), "path"),
    "files not a list": (_set("current", "files", {"a": 1}), "files"),
    "size negative": (_set_file("size", -1), "size"),
    "size huge": (_set_file("size", 10**40), "size"),
    "size str": (_set_file("size", "249888"), "size"),
    "xxh3_128 short": (_set_file("xxh3_128", "abc"), "xxh3_128 'abc' is not 32 lowercase hex"),
    "xxh3_128 not hex": (_set_file("xxh3_128", "g" * 32), "is not 32 lowercase hex"),
    "xxh3_128 upper case": (_set_file("xxh3_128", "A" * 32), "is not 32 lowercase hex"),
    "xxh3_128 int": (_set_file("xxh3_128", 7), "xxh3_128 7 is not 32"),
    "xxh3_128 with sha256's length": (_set_file("xxh3_128", "0" * 64), "is not 32 lowercase hex"),
    "sha256 short": (_swap_checksum("sha256", "abc"), "sha256 'abc' is not 64 lowercase hex"),
    "sha256 not hex": (_swap_checksum("sha256", "g" * 64), "is not 64 lowercase hex"),
    "sha256 int": (_swap_checksum("sha256", 7), "sha256 7 is not 64"),
    "two checksums": (_set_file("sha256", "0" * 64), "more than one checksum"),
    "no checksum": (_swap_checksum(None, None), "no checksum"),
    "shape not a list": (_set_array("shape", 1500), "shape"),
    "shape negative": (_set_array("shape", [-1]), "shape"),
    "shape float": (_set_array("shape", [1500.0]), "shape"),
    "shape huge": (_set_array("shape", [10**30]), "shape"),
    "shape too big for the file": (_set_array("shape", [10**12]), "bytes"),
    "dtype object": (_set_array("dtype", "O"), "dtype"),
    "dtype str": (_set_array("dtype", "<U8"), "dtype"),
    "dtype not canonical": (_set_array("dtype", "float64"), "dtype"),
    "dtype int": (_set_array("dtype", 8), "dtype"),
    "arrays not a dict": (lambda m: m["current"]["domains"]["0"].update(arrays=[1]), "arrays"),
    "array name hostile": (
        lambda m: m["current"]["domains"]["0"]["arrays"].update({"../x": [[1], "<f8"]}),
        "array name",
    ),
    "domains not a dict": (_set("current", "domains", [1]), "domains"),
    "step null": (_set("previous", "step", None), "step"),
    "previous without current": (lambda m: m.update(current=None), "no current"),
    "meta nested 200 deep": (_nest(200), "nested"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_manifest_fields_give_one_line(pristine, tmp_path, case):
    store, victim = _make(pristine, tmp_path)
    mutate, needle = HOSTILE[case]
    _edit(store, mutate)
    before = _snapshot(store)
    for cmd in (("checkpoint", "verify", store), ("checkpoint", "list", store), ("resume", store, *RESUME_MORE)):
        one_line_error(_cli(*cmd), "MANIFEST.json", needle)
        assert _snapshot(store) == before


def _deep_json(m) -> str:
    text = json.dumps(m)
    return text[:-1] + ', "deep": ' + "[" * 200_000 + "]" * 200_000 + "}"


@pytest.mark.parametrize(
    "case", ["nested 200000 deep", "integer of 5000 digits", "huge", "fifo", "directory", "symlink to /dev/zero"]
)
def test_hostile_manifest_files_give_one_line(pristine, tmp_path, case):
    store, victim = _make(pristine, tmp_path)
    mpath = store / "MANIFEST.json"
    m = _manifest(store)
    needle = {
        "nested 200000 deep": "nested too deeply",
        "integer of 5000 digits": "not valid JSON",
        "huge": "more than",
        "fifo": "not a regular file",
        "directory": "not a regular file",
        "symlink to /dev/zero": "symbolic link",
    }[case]
    if case == "nested 200000 deep":
        mpath.write_text(_deep_json(m))
    elif case == "integer of 5000 digits":
        mpath.write_text(json.dumps(m).replace('"step": 20', '"step": 2' + "0" * 5000))
    elif case == "huge":  # sparse: 65 MiB on paper, nothing on disk
        with open(mpath, "r+b") as f:
            f.truncate(65 << 20)
    else:
        mpath.unlink()
        if case == "fifo":
            os.mkfifo(mpath)
        elif case == "directory":
            mpath.mkdir()
        else:
            os.symlink("/dev/zero", mpath)
    before = _snapshot(store)
    for cmd in (
        ("checkpoint", "verify", store),
        ("resume", store, *RESUME_MORE),
        ("checkpoint", "prune", store, "--keep", "1"),
    ):
        one_line_error(_cli(*cmd), "MANIFEST.json", needle)
        assert _snapshot(store) == before


def test_memory_store_manifest_is_validated_too():
    """The memory backend has nothing to confine, but its manifest is checked the same way."""
    import numpy as np
    from ooc_dem.storage import StoreError, _memory, create_store, drop_memory_store, open_store

    key = "mem://hostile"
    s = create_store(key, "memory", {})
    w = s.begin_epoch(3)
    w.write_domain(0, {"x": np.arange(4.0)})
    w.commit()
    s.close()
    b = _memory._REGISTRY[key]
    good = b.manifest_json
    try:
        for mutate, needle in (
            (_rename_domain("01"), "domain key"),
            (_set("current", "step", 3.0), "step"),
            (_set("current", "path", "../e000000000003.mem"), "path"),
            (_set("current", "files", []), "files hold only 0"),
            (
                lambda m: m["current"].update(
                    files=[  # attrs unlisted
                        f for f in m["current"]["files"] if not f["path"].endswith(".attrs")
                    ]
                ),
                "unexpected",
            ),
        ):
            m = json.loads(good)
            mutate(m)
            b.manifest_json = json.dumps(m)
            try:
                st = open_store(key, repair=False)
            except StoreError as e:
                assert needle in str(e) and "\n" not in str(e), str(e)
                continue
            problems = st.verify()  # an unlisted pseudo-file is a verification problem
            assert problems and any(needle in p for p in problems), problems
    finally:
        drop_memory_store(key)
