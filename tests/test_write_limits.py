"""Full disks and file-size limits on every writer, for real: each writer (epoch commit in a
run and a resume, HDF5 and zarr; exports in every format; trajectory frames; films) runs in
a subprocess under RLIMIT_FSIZE for a geometric series of limits, from 1 KB to above the
full size. Each must exit 0 (the limit was high enough) or 2 with one line on stderr, never
die of a signal (HDF5 used to crash with SIGSEGV after a failed write), leave no temporary
behind, and leave every committed epoch intact and the run resumable. The checks before
writing (free space and the limit against the estimated size) are also switched off in a
second pass, so that the failure is met in the middle of the write. A small tmpfs gives a
real full disk (ENOSPC)."""

import json
import os
import resource
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from support.cli import one_line_error

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
# 1 KB, 8 KB, ... 2 MB: an epoch of `quick` is 250 kB, a frame 110 kB, its GIF 400 kB
LIMITS = [1 << (10 + 3 * k) for k in range(5)]
STEPS = [
    "--steps",
    "100",
    "--checkpoint-every",
    "50",
    "--set",
    "output.snapshot_interval=0.0005",
    "--no-progress",
    "--no-figures",
]

# the CLI with every check before writing switched off (the names each writer calls)
_NO_PRECHECK = """
import sys
import ooc_dem.storage.writeguard as wg, ooc_dem.storage.store as st, ooc_dem.app.export as ex, ooc_dem.app.trajectory as tr
import ooc_dem.app.animate as an, ooc_dem.storage.atomic as at, ooc_dem.app.trajectory_export as te
none = lambda *a, **k: None
wg.check_room = ex.check_room = tr.check_room = an.check_room = at.check_room = te.check_room = none
st.shortfall = none
from ooc_dem.cli import main
sys.exit(main(sys.argv[1:]))
"""


ENV = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def limited(cmd, limit: int | None, timeout=300):
    """Run cmd under RLIMIT_FSIZE = limit (None: unlimited), set in the child before exec."""

    def limit_files():
        if limit is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return subprocess.run(
        list(map(str, cmd)), capture_output=True, text=True, timeout=timeout, env=ENV, preexec_fn=limit_files
    )


def cli_limited(args, limit: int | None, precheck: bool = True):
    """`ooc-dem args` in a fresh interpreter under the limit (precheck=False: the checks
    before writing switched off)."""
    head = [sys.executable, "-m", "ooc_dem.cli"] if precheck else [sys.executable, "-c", _NO_PRECHECK]
    return limited([*head, *args], limit)


def assert_clean_outcome(cp, *dirs):
    """Exit 0, or the one-line refusal (exit 2, never a signal); no temporary in dirs."""
    if cp.returncode != 0:
        one_line_error(cp)
    left = temporaries(*dirs)
    assert not left, f"temporaries left behind: {left}"


def temporaries(*dirs):
    return [str(p) for d in dirs for p in Path(d).rglob("*.tmp*")]


def sweep(job, limits=LIMITS):
    """job(limit) for every limit, two at a time; returns {limit: result}."""
    with ThreadPoolExecutor(max_workers=2) as pool:
        return dict(zip(limits, pool.map(job, limits)))


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A quick run with two epochs and three trajectory frames (unlimited), and its state hash."""
    root = tmp_path_factory.mktemp("limits")
    run = root / "run"
    cp = cli_limited(["run", "quick", "--out", run, *STEPS], None)
    assert cp.returncode == 0, cp.stderr[-2000:]
    return run


def _manifest(store):
    return json.loads((Path(store) / "MANIFEST.json").read_text())


def _hash(store) -> str:
    cp = cli_limited(["checkpoint", "hash", store], None)
    assert cp.returncode == 0, cp.stderr[-2000:]
    return cp.stdout.split()[-1]


def test_export_of_the_issue_under_a_100_kb_file_size_limit_is_one_line(base, tmp_path):
    """`ulimit -f 100; ooc-dem checkpoint export RUN --out e.xdmf` used to end in SIGSEGV
    after 30-odd lines of HDF5 errors, leaving e.h5.tmp-* behind."""
    for precheck in (True, False):
        cp = cli_limited(["checkpoint", "export", base, "--out", tmp_path / "e.xdmf"], 100 << 10, precheck)
        line = one_line_error(cp)
        assert "File too large" in line or "file-size limit" in line, line
        assert not list(tmp_path.iterdir()), list(tmp_path.iterdir())


@pytest.mark.parametrize("precheck", [True, False], ids=["checked-before", "failing-during"])
def test_every_export_format_under_every_file_size_limit(base, tmp_path, precheck):
    formats = {"xdmf": "e.xdmf", "vtk": "e.vtk", "vtp": "e.vtp", "vtu": "e.vtu", "csv": "e.csv"}

    def job(limit):
        out = {}
        for fmt, name in formats.items():
            d = tmp_path / f"{fmt}-{limit}"
            d.mkdir()
            cp = cli_limited(["checkpoint", "export", base, "--out", d / name], limit, precheck)
            assert_clean_outcome(cp, d)
            out[fmt] = cp.returncode
            if cp.returncode == 2:
                assert not list(d.iterdir()), (fmt, limit, list(d.iterdir()))  # nothing published
        return out

    codes = sweep(job)
    # the smallest limit refuses every format, the largest lets every one through
    assert set(codes[LIMITS[0]].values()) == {2} and set(codes[LIMITS[-1]].values()) == {0}, codes


@pytest.mark.parametrize("precheck", [True, False], ids=["checked-before", "failing-during"])
def test_trajectory_export_under_every_file_size_limit(base, tmp_path, precheck):
    """export-trajectory's four files (the particles' and the wheel's XDMF + HDF5): all
    published, or a one-line refusal and none of them."""

    def job(limit):
        d = tmp_path / f"t-{limit}"
        d.mkdir()
        cp = cli_limited(["export-trajectory", base, "--out", d / "t.xdmf"], limit, precheck)
        assert_clean_outcome(cp, d)
        names = sorted(p.name for p in d.iterdir())
        assert names == ([] if cp.returncode else ["t-wheel.h5", "t-wheel.xdmf", "t.h5", "t.xdmf"]), (limit, names)
        return cp.returncode

    codes = sweep(job)
    assert codes[LIMITS[0]] == 2 and codes[LIMITS[-1]] == 0, codes


@pytest.mark.parametrize("backend", ["hdf5", "zarr"])
def test_epoch_commits_under_every_file_size_limit_keep_the_run_resumable(base, tmp_path, backend):
    """A run and a resume writing epochs (and frames) under each limit: committed epochs stay
    intact and an unlimited resume then reaches the uninterrupted run's state."""
    if backend == "hdf5":
        full = base
    else:
        full = tmp_path / "full"
        cp = cli_limited(["run", "quick", "--out", full, "--backend", backend, *STEPS], None)
        assert cp.returncode == 0, cp.stderr[-2000:]
    want = _hash(full)

    def job(limit):
        run = tmp_path / f"run-{limit}"
        cp = cli_limited(["run", "quick", "--out", run, "--backend", backend, *STEPS], limit)
        assert_clean_outcome(cp, run)
        # a resume under the limit of a copy of the finished run, on to step 200
        res = tmp_path / f"resume-{limit}"
        shutil.copytree(full, res)
        cp2 = cli_limited(["resume", res, "--steps", "200", "--no-progress", "--no-figures"], limit)
        assert_clean_outcome(cp2, res)
        return cp.returncode, cp2.returncode

    results = sweep(job)
    assert results[LIMITS[0]] == (2, 2) and results[LIMITS[-1]] == (0, 0), results
    for limit, (rc_run, rc_resume) in results.items():
        run, res = tmp_path / f"run-{limit}", tmp_path / f"resume-{limit}"
        # what was committed is intact: the resumed copy still holds step 100 or later
        cp = cli_limited(["checkpoint", "verify", res], None)
        assert cp.returncode == 0 and _manifest(res)["current"]["step"] >= 100, (limit, cp.stdout, cp.stderr)
        if rc_run == 2 and (run / "MANIFEST.json").exists() and _manifest(run)["current"]:
            cp = cli_limited(["resume", run, "--no-progress", "--no-figures"], None)
            assert cp.returncode == 0, (limit, cp.stderr[-2000:])
            assert _hash(run) == want, limit


def test_trajectory_frames_under_every_file_size_limit(tmp_path):
    """The frame writer alone (a 1500-disc frame is 110 kB; epochs are larger, so a run under a
    limit fails at its epochs first): refused before, or failing during the write."""
    code = """
import sys, numpy as np
{patch}
from ooc_dem.model.scenario import load_scenario
from ooc_dem.app.trajectory import TrajectoryWriter
sc = load_scenario("quick", overrides=["output.snapshot_interval=0.0005"])
n = 1500
w = TrajectoryWriter.create({out}, sc, 2, n)
rows = {{"id": np.arange(n), "pos": np.random.rand(n, 2), "vel": np.zeros((n, 2)),
         "spin": np.zeros((n, 1)), "r": np.full(n, 0.002), "mat": np.zeros(n, np.int32)}}
try:
    for step in (0, 50, 100):
        w.write_part(step, {{k: v[:700] for k, v in rows.items()}})
        w.write_part(step, {{k: v[700:] for k, v in rows.items()}})
        w.end(step, step * 1e-5, np.zeros(6))
except OSError as e:
    print(f"ooc-dem: error: {{e.filename}}: {{e.strerror}}", file=sys.stderr)
    sys.exit(2)
"""

    def job(args):
        limit, precheck = args
        out = tmp_path / f"run-{limit}-{precheck}"
        out.mkdir()
        patch = "" if precheck else "import ooc_dem.app.trajectory as tr; tr.check_room = lambda *a, **k: None"
        src = code.format(patch=patch, out=repr(str(out)))
        cp = limited([sys.executable, "-c", src], limit)
        assert_clean_outcome(cp, out)
        frames = sorted(p.name for p in (out / "trajectory").iterdir())
        return cp.returncode, frames

    cases = [(lim, pre) for lim in LIMITS for pre in (True, False)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = dict(zip(cases, pool.map(job, cases)))
    for (limit, pre), (rc, frames) in results.items():
        assert rc == (0 if limit > 200_000 else 2), (limit, pre, rc)
        assert len(frames) == (3 if rc == 0 else 0), (limit, pre, frames)  # whole frames only


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
def test_films_under_every_file_size_limit_are_complete_or_absent(base, tmp_path, suffix):
    pytest.importorskip("imageio_ffmpeg" if suffix == ".mp4" else "imageio")

    def job(limit):
        d = tmp_path / f"film-{limit}"
        d.mkdir()
        cp = cli_limited(["animate", base, "--out", d / f"a{suffix}", "--no-progress"], limit, False)
        assert_clean_outcome(cp, d)
        files = list(d.iterdir())
        assert files == ([d / f"a{suffix}"] if cp.returncode == 0 else []), (limit, cp.stderr, files)
        return cp.returncode

    codes = sweep(job)
    assert codes[LIMITS[0]] == 2 and codes[LIMITS[-1]] == 0, codes


def test_a_truncated_mp4_is_never_published(base, tmp_path):
    """imageio's writer ignored ffmpeg's failure: under a 40 kB limit the 80 kB film was
    published cut short, exit 0. Now the encoder's exit status decides."""
    out = tmp_path / "a.mp4"
    line = one_line_error(cli_limited(["animate", base, "--out", out, "--no-progress"], 40 << 10), "encoder failed")
    assert "SIGXFSZ" in line or "too large" in line, line
    assert not list(tmp_path.iterdir())


def test_a_run_writing_frames_onto_a_full_disk_stops_in_one_line_and_resumes(small_fs, base):
    """ENOSPC for real: the sizes put the end of the disk at an epoch, then at frames (a run
    writing frames onto a full disk used to die of SIGSEGV leaving frame-*.h5.tmp-*)."""
    want = _hash(base)
    for size in ("400k", "600k", "900k"):
        mnt = small_fs(size)
        run = mnt / "r"
        cp = cli_limited(["run", "quick", "--out", run, *STEPS], None)
        line = one_line_error(cp, "disk full or file too large")
        assert not temporaries(mnt), (size, line)
        subprocess.run(["mount", "-o", "remount,size=8m", str(mnt)], check=True)
        cp = cli_limited(["resume", run, "--no-progress", "--no-figures"], None)
        assert cp.returncode == 0, (size, cp.stderr[-2000:])
        assert _hash(run) == want, size
        frames = sorted(p.name for p in (run / "trajectory").iterdir())
        assert frames == [f"frame-{s:012d}.h5" for s in (0, 50, 100)], (size, frames)


@pytest.mark.parametrize("command", ["check", "run"])
def test_a_wheel_narrower_than_a_double_can_resolve_is_refused_by_check_and_run(tmp_path, command):
    """wheel.width = 1e-300 passed `check`, then `run` divided by zero in the bed's surface
    height (z0 + w/2 - (z0 - w/2) == 0): check and run share the validation and refuse it."""
    args = [command, "quick-3d", "--set", "wheel.width=1e-300"]
    if command == "run":
        args += ["--out", tmp_path / "r"]
    line = one_line_error(cli_limited(args, None), "wheel.width = 1e-300", "[1e-09, 1e+06]")
    assert line == "ooc-dem: error: wheel.width = 1e-300: must be a number in [1e-09, 1e+06]"
    assert not (tmp_path / "r").exists()
