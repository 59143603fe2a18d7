"""Trajectories (issue 19): frames written by every mode, kill-safe and resumable, exported
as an XDMF time series (read back with VTK's vtkXdmfReader) and animated to GIF and MP4."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import one_line_error, run_cli
from ooc_dem.trajectory import ROW_FIELDS, TRAJECTORY_FILE, Trajectory, TrajectoryWriter, wheel_outline

STEPS = 600
# 123 steps: a multiple neither of the block K = 10 nor of the epoch interval (250): the frame
# steps cut the advances (and the out-of-core sweeps) where nothing else would
FRAME = ["--set", "output.snapshot_interval=0.00123"]
FRAME_STEPS = [0, 123, 246, 369, 492]
COMMON = ["--steps", STEPS, "--checkpoint-every", 250, "--no-progress", "--no-figures"]
MODES = {"monolithic": ["--mode", "monolithic"],
         "ddm": ["--mode", "ddm", "--domains", "3", "--block", "10"],
         "ooc": ["--mode", "ooc", "--domains", "3", "--block", "10"]}


def frames_of(run):
    with Trajectory.of_run(run) as t:
        return [t[i] for i in range(len(t))]


def assert_same_frames(a, b):
    assert [f["step"] for f in a] == [f["step"] for f in b]
    for fa, fb in zip(a, b):
        assert fa.keys() == fb.keys()
        for k in fa:
            assert np.array_equal(fa[k], fb[k]), (fa["step"], k)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("traj")
    out = {}
    for name, opts in MODES.items():
        out[name] = base / name
        run_cli("run", "quick", "--out", out[name], *opts, *COMMON, *FRAME, check=True)
    out["noframes"] = base / "noframes"
    run_cli("run", "quick", "--out", out["noframes"], *MODES["ooc"], *COMMON,
            "--set", "output.snapshot_interval=0", check=True)
    return out


def _hash(run):
    return run_cli("checkpoint", "hash", run, check=True).stdout.strip()


def test_modes_write_the_same_frames(runs):
    """Monolithic, serial DDM and out-of-core write the same frames (sorted by id), at the
    frame steps, with the whole bed in each; the out-of-core frame is written slab by slab
    (its rows are not in id order in the file)."""
    ref = frames_of(runs["monolithic"])
    assert [f["step"] for f in ref] == FRAME_STEPS
    assert all(len(f["id"]) == 1500 for f in ref)
    assert [f["time"] for f in ref] == [s * 1e-5 for s in FRAME_STEPS]
    for name in ("ddm", "ooc"):
        assert_same_frames(ref, frames_of(runs[name]))
    with h5py.File(runs["ooc"] / TRAJECTORY_FILE, "r") as f:
        assert (np.diff(f["id"][1500:3000]) < 0).any()   # slab order, not id order
    assert not (runs["noframes"] / TRAJECTORY_FILE).exists()


def test_frames_change_no_bits(runs):
    """Cutting the advances at the frame steps leaves every result bit as it was."""
    hashes = {name: _hash(runs[name]) for name in runs}
    assert len(set(hashes.values())) == 1, hashes
    # and the frame at the last frame step is that state's discs where the epoch agrees
    last = frames_of(runs["monolithic"])[-1]
    assert last["wheel_state"].shape == (6,) and np.isfinite(last["pos"]).all()


def _committed_frames(path) -> int:
    """The committed frame count of a trajectory another process is writing (0 if unreadable now)."""
    try:
        with h5py.File(path, "r", locking=False) as f:
            return int(f.attrs["frames"])
    except (OSError, KeyError, ValueError):
        return 0


def test_sigkill_then_resume_continues_the_same_trajectory(tmp_path):
    """A run SIGKILLed mid-way (a real subprocess) after frames beyond its last epoch, then
    resumed, has exactly the frames of an uninterrupted run: no duplicates, no gaps, every
    array equal (np.array_equal), and the same final state."""
    args = ["quick", *MODES["monolithic"], "--steps", 3000, "--checkpoint-every", 500,
            "--no-progress", "--no-figures", *FRAME]
    ref_dir = tmp_path / "ref"
    run_cli("run", *args[:1], "--out", ref_dir, *args[1:], check=True)
    ref = frames_of(ref_dir)
    assert [f["step"] for f in ref] == list(range(0, 3001, 123))
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "ooc_dem.cli", "run", "quick", "--out", str(out), *map(str, args[1:])]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    # kill once frame 9 (step 1107) is committed: after the epoch at 1000, so the resume
    # must drop frames 1107.. and write them again
    deadline = time.time() + 600
    while time.time() < deadline and proc.poll() is None:
        if _committed_frames(out / TRAJECTORY_FILE) >= 10:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    rc = proc.wait()
    assert rc == -signal.SIGKILL, "the run finished before the kill: make it longer"
    before = _committed_frames(out / TRAJECTORY_FILE)
    assert before >= 10
    cp = run_cli("resume", out, "--no-progress", "--no-figures")
    assert cp.returncode == 0, cp.stderr[-2000:]
    assert_same_frames(ref, frames_of(out))
    assert _hash(out) == _hash(ref_dir)


def test_writer_commits_only_whole_frames_and_truncates_on_reopen(tmp_path, quick_scenario):
    """The committed count decides: an unfinished frame's rows are invisible, and reopening
    at a step drops the later frames and the leftovers, then appends without a gap."""
    import dataclasses
    sc = dataclasses.replace(quick_scenario, output=dataclasses.replace(quick_scenario.output,
                                                                        snapshot_interval=1e-4))
    rng = np.random.default_rng(1)
    n = 50

    def part(step, ids):
        return {"id": ids, "pos": rng.random((len(ids), 2)) + step, "vel": rng.random((len(ids), 2)),
                "spin": rng.random((len(ids), 1)), "r": rng.random(len(ids)),
                "mat": np.zeros(len(ids), np.int32)}

    w = TrajectoryWriter.create(tmp_path, sc, 2, n)
    assert w.every == 10
    written = {}
    for step in (0, 10, 20, 30):
        ids = rng.permutation(n)
        parts = [part(step, ids[:20]), part(step, ids[20:])]
        w.write_frame(step, step * 1e-5, np.full(6, step, float), parts)
        written[step] = parts
    w.write_part(40, part(40, np.arange(n)))      # a frame killed half-way: never ended
    w.close()
    with Trajectory(tmp_path / TRAJECTORY_FILE) as t:
        assert list(t.steps) == [0, 10, 20, 30]
        f = t[2]
        cat = {k: np.concatenate([p[k] for p in written[20]]) for k in ROW_FIELDS}
        order = np.argsort(cat["id"])
        for k in ROW_FIELDS:
            assert np.array_equal(f[k], cat[k][order].astype(f[k].dtype)), k
    w = TrajectoryWriter.reopen(tmp_path, sc, 2, n, step=20)   # resumed from the epoch at 20
    assert w.committed == 3 and not w.due(20) and w.due(30)
    w.write_frame(30, 30e-5, np.zeros(6), [part(30, np.arange(n))])
    w.close()
    with h5py.File(tmp_path / TRAJECTORY_FILE, "r") as f:
        assert f.attrs["frames"] == 4 and f["id"].shape == (4 * n,)
    with Trajectory(tmp_path / TRAJECTORY_FILE) as t:
        assert list(t.steps) == [0, 10, 20, 30]
    # an unreadable file (a kill inside an HDF5 flush) is set aside, a new trajectory begins
    (tmp_path / TRAJECTORY_FILE).write_bytes(b"garbage")
    w = TrajectoryWriter.reopen(tmp_path, sc, 2, n, step=40)
    assert w.committed == 0 and w.due(40)
    w.close()
    assert (tmp_path / f"{TRAJECTORY_FILE}.damaged-40").read_bytes() == b"garbage"


def test_xdmf_time_series_reads_in_vtk(tmp_path, runs):
    """export-trajectory: an XDMF temporal collection that vtkXdmfReader reads at every time:
    1500 disc points with their arrays from trajectory.h5, and the wheel outline polygon."""
    vtk = pytest.importorskip("vtk")
    from ooc_dem.scenario import load_scenario
    run = runs["ooc"]
    out = tmp_path / "traj.xdmf"
    cp = run_cli("export-trajectory", run, "--out", out, check=True)
    assert "5 frames" in cp.stdout
    assert out.stat().st_size < 200_000   # references, not a copy of the data
    sc = load_scenario("quick")
    r = vtk.vtkXdmfReader()
    r.SetFileName(str(out))
    r.UpdateInformation()
    times = r.GetOutputInformation(0).Get(vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS())
    with Trajectory.of_run(run) as t, h5py.File(run / TRAJECTORY_FILE, "r") as raw:
        assert np.allclose(times, t.times, rtol=0, atol=1e-15)
        for i, tv in enumerate(times):
            r.UpdateTimeStep(tv)
            mb = r.GetOutputDataObject(0)
            assert mb.GetNumberOfBlocks() == 2
            discs, wheel = mb.GetBlock(0), mb.GetBlock(1)
            assert discs.GetNumberOfPoints() == 1500
            start, _ = t.rows(i)
            j = 777
            assert discs.GetPoint(j)[:2] == tuple(raw["pos"][start + j])
            pd = discs.GetPointData()
            assert pd.GetArray("radius").GetValue(j) == raw["r"][start + j]
            assert pd.GetArray("id").GetValue(j) == raw["id"][start + j]
            assert pd.GetArray("velocity").GetNumberOfComponents() == 3
            ws = t.wheel_states[i]
            poly = wheel_outline(ws[0], ws[1], ws[4], sc.wheel.radius, sc.wheel.n_lugs,
                                 sc.wheel.lug_tip_radius, sc.wheel.lug_thickness)
            assert wheel.GetNumberOfPoints() == len(poly) and wheel.GetNumberOfCells() == 1
            assert np.allclose(wheel.GetPoint(0)[:2], poly[0])


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
def test_animate_writes_a_readable_film(tmp_path, runs, suffix):
    """animate: one picture per frame, readable back with imageio (GIF without ffmpeg)."""
    imageio = pytest.importorskip("imageio.v2")
    out = tmp_path / f"film{suffix}"
    cp = run_cli("animate", runs["monolithic"], "--out", out, "--fps", "10", "--no-progress", check=True)
    assert "5 frames" in cp.stdout
    rd = imageio.get_reader(out)
    try:
        pictures = [np.asarray(p) for p in rd]
    finally:
        rd.close()
    assert len(pictures) == 5
    first = pictures[0]
    assert first.shape[1] == 1280 and first.shape[0] % 16 == 0
    assert not np.array_equal(pictures[0], pictures[-1])   # the soil (and the text) moved
    assert not list(tmp_path.glob(".film*"))   # no temporary left


def test_api_trajectory(runs):
    import ooc_dem
    res = ooc_dem.open_run(runs["ooc"])
    with res.trajectory() as t:
        assert len(t) == 5
        frames = list(t)
    assert all((np.diff(f["id"]) > 0).all() for f in frames)
    assert_same_frames(frames, frames_of(runs["monolithic"]))


def test_bad_input_is_one_line(tmp_path, runs):
    """No trajectory, a garbage or edited trajectory, an output inside the store, a bad
    suffix or key: exit 2 with one line."""
    one_line_error(run_cli("animate", runs["noframes"], "--out", tmp_path / "a.gif"),
                   "no trajectory.h5", "snapshot_interval")
    one_line_error(run_cli("export-trajectory", tmp_path / "nowhere", "--out", tmp_path / "a.xdmf"),
                   "not a run directory")
    one_line_error(run_cli("export-trajectory", runs["ooc"], "--out", runs["ooc"] / "a.xdmf"),
                   "inside the ooc-dem store")
    one_line_error(run_cli("animate", runs["ooc"], "--out", tmp_path / "a.avi"), ".mp4 or .gif")
    one_line_error(run_cli("export-trajectory", runs["ooc"], "--out", tmp_path / "a.txt"), ".xdmf")
    one_line_error(run_cli("check", "quick", "--set", "output.snapshot_interval=-1"),
                   "output.snapshot_interval")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / TRAJECTORY_FILE).write_bytes(b"\x89HDF\r\n\x1a\n" + os.urandom(2000))
    one_line_error(run_cli("animate", bad, "--out", tmp_path / "b.gif"), "not a readable HDF5 file")
    for edit, needle in ((lambda f: f.attrs.__setitem__("frames", 99), "frames committed"),
                         (lambda f: f.attrs.__setitem__("format", "x"), "not an ooc-dem trajectory"),
                         (lambda f: f["frame_start"].__setitem__(1, 7), "not contiguous"),
                         (lambda f: f["id"].__setitem__(1, f["id"][0]), "disc id twice"),
                         (lambda f: f.attrs.__setitem__("frames", -3), "is not a count")):
        (bad / TRAJECTORY_FILE).write_bytes((runs["monolithic"] / TRAJECTORY_FILE).read_bytes())
        with h5py.File(bad / TRAJECTORY_FILE, "r+") as f:
            edit(f)
        one_line_error(run_cli("animate", bad, "--out", tmp_path / "c.gif", "--no-progress"), needle)
    link = tmp_path / "linked"
    link.mkdir()
    (link / TRAJECTORY_FILE).symlink_to(runs["monolithic"] / TRAJECTORY_FILE)
    one_line_error(run_cli("export-trajectory", link, "--out", tmp_path / "d.xdmf"),
                   "outside the run directory")
