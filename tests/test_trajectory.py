"""Trajectories: frames written by every mode, kill-safe and resumable, exported
as an XDMF time series (read back with VTK's vtkXdmfReader) and animated to GIF and MP4."""

import os
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from support.cli import cli_in_process, one_line_error, run_cli
from ooc_dem.app.trajectory import TrajectoryWriter, wheel_outline
from ooc_dem.app.trajectory_format import ROW_FIELDS, TRAJECTORY_FILE, frame_name
from ooc_dem.app.trajectory_read import Trajectory
from ooc_dem.app.trajectory_format import TRAJECTORY_DIR

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

STEPS = 600
# 123 steps: a multiple neither of the block K = 10 nor of the epoch interval (250): the frame
# steps cut the advances (and the out-of-core sweeps) where nothing else would
FRAME = ["--set", "output.snapshot_interval=0.00123"]
FRAME_STEPS = [0, 123, 246, 369, 492]
COMMON = ["--steps", STEPS, "--checkpoint-every", 250, "--no-progress", "--no-figures"]
MODES = {
    "monolithic": ["--mode", "monolithic"],
    "ddm": ["--mode", "ddm", "--domains", "3", "--block", "10"],
    "ooc": ["--mode", "ooc", "--domains", "3", "--block", "10"],
}


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
    run_cli(
        "run",
        "quick",
        "--out",
        out["noframes"],
        *MODES["ooc"],
        *COMMON,
        "--set",
        "output.snapshot_interval=0",
        check=True,
    )
    return out


def _hash(run):
    return cli_in_process("checkpoint", "hash", run, check=True).stdout.strip()


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
    folder = runs["ooc"] / TRAJECTORY_DIR
    assert sorted(p.name for p in folder.iterdir()) == [frame_name(s) for s in FRAME_STEPS]
    with h5py.File(folder / frame_name(123), "r") as f:
        assert (np.diff(f["id"][:]) < 0).any()  # slab order, not id order
    assert not (runs["noframes"] / TRAJECTORY_DIR).exists()


def test_frames_change_no_bits(runs):
    """Cutting the advances at the frame steps leaves every result bit as it was."""
    hashes = {name: _hash(runs[name]) for name in runs}
    assert len(set(hashes.values())) == 1, hashes
    # and the frame at the last frame step is that state's discs where the epoch agrees
    last = frames_of(runs["monolithic"])[-1]
    assert last["wheel_state"].shape == (6,) and np.isfinite(last["pos"]).all()


def _published(folder) -> tuple[int, bool]:
    """(published frame files, whether a temporary frame file exists) of a folder another
    process is writing (names only: no HDF5 file is opened)."""
    try:
        names = os.listdir(folder)
    except FileNotFoundError:
        return 0, False
    return (sum(n.startswith("frame-") and n.endswith(".h5") for n in names), any(".h5.tmp-" in n for n in names))


@pytest.mark.parametrize("mode", ["monolithic", "ooc"])
def test_sigkill_anywhere_then_resume_gives_the_same_frames(tmp_path, mode):
    """A run SIGKILLed at 5 random moments (a real subprocess, a frame every 3 steps so that
    kills land while frame files are being written; twice right when a temporary frame
    file appears; out-of-core: its slab parts written as the sweep passes), each time
    resumed, ends with exactly the frames of an uninterrupted run:
    the same steps, no duplicates, no gaps, every array equal (np.array_equal); no
    temporary is left and the final state is the same."""
    steps, every = 1000, 3
    args = [
        *MODES[mode],
        "--steps",
        steps,
        "--checkpoint-every",
        200,
        "--no-progress",
        "--no-figures",
        "--set",
        f"output.snapshot_interval={every * 1e-5}",
    ]
    ref_dir = tmp_path / "ref"
    run_cli("run", "quick", "--out", ref_dir, *args, check=True)
    ref = frames_of(ref_dir)
    assert [f["step"] for f in ref] == list(range(0, steps + 1, every))
    out = tmp_path / "killed"
    folder = out / TRAJECTORY_DIR
    rng = np.random.default_rng(19)
    n_ref = len(ref)
    targets = np.sort(rng.choice(np.arange(15, n_ref - 40), 5, replace=False))
    cmd = [sys.executable, "-m", "ooc_dem.cli", "run", "quick", "--out", str(out), *map(str, args)]
    seen_temp = []
    prev = 0
    for k, target in enumerate(targets):
        target = max(int(target), prev + 10)  # frames this process wrote (a resume only drops)
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.time() + 600
        while time.time() < deadline and proc.poll() is None and _published(folder)[0] < target:
            time.sleep(0.005)
        if k in (1, 3):  # right inside a frame's write: as soon as its temporary appears
            while time.time() < deadline and proc.poll() is None and not _published(folder)[1]:
                time.sleep(0.0005)
        else:
            time.sleep(float(rng.uniform(0.0, 0.05)))
        proc.send_signal(signal.SIGKILL)
        rc = proc.wait()
        assert rc == -signal.SIGKILL, f"kill {k}: the run finished first (rc {rc}): make it longer"
        prev, temp = _published(folder)
        seen_temp.append(temp)
        cmd = [sys.executable, "-m", "ooc_dem.cli", "resume", str(out), "--no-progress", "--no-figures"]
    assert any(seen_temp), "no kill landed inside a frame's write"
    cp = run_cli("resume", out, "--no-progress", "--no-figures")
    assert cp.returncode == 0, cp.stderr[-2000:]
    assert_same_frames(ref, frames_of(out))
    assert not [n for n in os.listdir(folder) if ".tmp-" in n]
    assert _hash(out) == _hash(ref_dir)


def _quick_frames(quick_scenario):
    import dataclasses

    return dataclasses.replace(
        quick_scenario, output=dataclasses.replace(quick_scenario.output, snapshot_interval=1e-4)
    )


def _part(rng, step, ids):
    return {
        "id": ids,
        "pos": rng.random((len(ids), 2)) + step,
        "vel": rng.random((len(ids), 2)),
        "spin": rng.random((len(ids), 1)),
        "r": rng.random(len(ids)),
        "mat": np.zeros(len(ids), np.int32),
    }


def test_writer_publishes_only_whole_frames_and_truncates_on_reopen(tmp_path, quick_scenario):
    """Only published (renamed) frame files count: an unfinished frame's temporary is
    invisible, and reopening at a step drops the later frames and the leftovers, then
    writes on without a gap."""
    sc = _quick_frames(quick_scenario)
    rng = np.random.default_rng(1)
    n = 50
    w = TrajectoryWriter.create(tmp_path, sc, 2, n)
    assert w.every == 10
    written = {}
    for step in (0, 10, 20, 30):
        ids = rng.permutation(n)
        parts = [_part(rng, step, ids[:20]), _part(rng, step, ids[20:])]
        w.write_frame(step, step * 1e-5, np.full(6, step, float), parts)
        written[step] = parts
    w.write_part(40, _part(rng, 40, np.arange(n)))  # a frame half-way: not ended
    folder = tmp_path / TRAJECTORY_DIR
    assert [p for p in os.listdir(folder) if p.startswith(frame_name(40) + ".tmp-")]
    with Trajectory.of_run(tmp_path) as t:
        assert list(t.steps) == [0, 10, 20, 30]
        f = t[2]
        cat = {k: np.concatenate([p[k] for p in written[20]]) for k in ROW_FIELDS}
        order = np.argsort(cat["id"])
        for k in ROW_FIELDS:
            assert np.array_equal(f[k], cat[k][order].astype(f[k].dtype)), k
        assert np.array_equal(f["wheel_state"], np.full(6, 20.0)) and f["time"] == 20e-5
    w.close()
    assert sorted(os.listdir(folder)) == [frame_name(s) for s in (0, 10, 20, 30)]
    w = TrajectoryWriter.reopen(tmp_path, sc, 2, n, step=20)  # resumed from the epoch at 20
    assert w.committed == 3 and not w.due(20) and w.due(30)
    assert sorted(os.listdir(folder)) == [frame_name(s) for s in (0, 10, 20)]
    w.write_frame(30, 30e-5, np.zeros(6), [_part(rng, 30, np.arange(n))])
    w.close()
    with Trajectory.of_run(tmp_path) as t:
        assert list(t.steps) == [0, 10, 20, 30] and t.rows(3) == (0, n)
    # a frame file that does not belong (garbage: not ours) is set aside on resume, with a gap
    (folder / frame_name(10)).write_bytes(b"garbage")
    w = TrajectoryWriter.reopen(tmp_path, sc, 2, n, step=40)
    assert w.steps == [0, 20, 30] and w.due(40)
    w.close()
    assert (folder / f"{frame_name(10)}.damaged").read_bytes() == b"garbage"


def test_half_written_temporary_is_ignored_then_removed_on_resume(tmp_path, quick_scenario):
    """A kill in the middle of a frame's write leaves a torn temporary file (here: half of a
    frame's bytes) under the temporary name pattern: the reader does not see it, a resume
    deletes it, and deletes nothing else (a run directory is untrusted: other names stay)."""
    sc = _quick_frames(quick_scenario)
    rng = np.random.default_rng(2)
    n = 40
    w = TrajectoryWriter.create(tmp_path, sc, 2, n)
    for step in (0, 10):
        w.write_frame(step, step * 1e-5, np.zeros(6), [_part(rng, step, np.arange(n))])
    w.close()
    folder = tmp_path / TRAJECTORY_DIR
    whole = (folder / frame_name(10)).read_bytes()
    torn = folder / f"{frame_name(20)}.tmp-k1ll3d_x"
    torn.write_bytes(whole[: len(whole) // 2])
    others = {
        "notes.txt": b"mine",
        f"{frame_name(20)}.tmp-": b"x",
        "frame-20.h5": b"y",
        f"{frame_name(30)}.h5.bak": b"z",
    }
    for name, data in others.items():
        (folder / name).write_bytes(data)
    (folder / f"{frame_name(40)}.tmp-dir").mkdir()  # our pattern, but not a file
    with Trajectory.of_run(tmp_path) as t:
        assert list(t.steps) == [0, 10] and len(list(t)) == 2
    w = TrajectoryWriter.reopen(tmp_path, sc, 2, n, step=10)
    assert w.steps == [0, 10] and w.due(20)
    w.close()
    assert not torn.exists()
    for name, data in others.items():
        assert (folder / name).read_bytes() == data
    assert (folder / f"{frame_name(40)}.tmp-dir").is_dir()
    with Trajectory.of_run(tmp_path) as t:
        assert list(t.steps) == [0, 10]


def test_xdmf_time_series_reads_in_vtk_and_meshio(tmp_path, runs):
    """export-trajectory: XDMF 3 time series that vtkXdmfReader (ParaView) and meshio read at
    every time: 1500 disc points a frame, sorted by id, with their arrays, and the wheel's
    outline as a fan of triangles in a second series."""
    vtk = pytest.importorskip("vtk")
    meshio = pytest.importorskip("meshio")
    from ooc_dem.model.scenario import load_scenario

    run = runs["ooc"]
    out = tmp_path / "traj.xdmf"
    cp = cli_in_process("export-trajectory", run, "--out", out, check=True)
    assert "5 frames" in cp.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["traj-wheel.h5", "traj-wheel.xdmf", "traj.h5", "traj.xdmf"]
    sc = load_scenario("quick")
    r = vtk.vtkXdmfReader()
    r.SetFileName(str(out))
    r.UpdateInformation()
    times = r.GetOutputInformation(0).Get(vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS())
    rw = vtk.vtkXdmfReader()
    rw.SetFileName(str(tmp_path / "traj-wheel.xdmf"))
    rw.UpdateInformation()
    with Trajectory.of_run(run) as t, meshio.xdmf.TimeSeriesReader(out) as m:
        assert np.array_equal(times, t.times) and m.num_steps == len(t)
        points, cells = m.read_points_cells()  # the first frame's: meshio's reader shares one mesh
        assert np.array_equal(points, t[0]["pos"]) and len(cells[0].data) == 1500
        for i, tv in enumerate(times):
            fr = t[i]
            r.UpdateTimeStep(tv)
            discs = r.GetOutputDataObject(0)
            assert discs.GetNumberOfPoints() == 1500
            j = 777
            assert discs.GetPoint(j)[:2] == tuple(fr["pos"][j])
            pd = discs.GetPointData()
            assert pd.GetArray("radius").GetValue(j) == fr["r"][j]
            assert pd.GetArray("id").GetValue(j) == fr["id"][j]
            assert pd.GetArray("velocity").GetNumberOfComponents() == 3
            time, data, _ = m.read_data(i)
            assert time == tv and np.array_equal(data["radius"], fr["r"]) and np.array_equal(data["id"], fr["id"])
            ws = t.wheel_states[i]
            poly = wheel_outline(
                ws[0], ws[1], ws[4], sc.wheel.radius, sc.wheel.n_lugs, sc.wheel.lug_tip_radius, sc.wheel.lug_thickness
            )
            rw.UpdateTimeStep(tv)
            wheel = rw.GetOutputDataObject(0)
            assert wheel.GetNumberOfPoints() == len(poly) + 1 and wheel.GetNumberOfCells() == len(poly)
            assert np.allclose(wheel.GetPoint(1)[:2], poly[0], rtol=0, atol=1e-15)


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
    assert not np.array_equal(pictures[0], pictures[-1])  # the soil (and the text) moved
    assert not list(tmp_path.glob(".film*"))  # no temporary left


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
    one_line_error(
        cli_in_process("animate", runs["noframes"], "--out", tmp_path / "a.gif"), "no trajectory/", "snapshot_interval"
    )
    one_line_error(
        cli_in_process("export-trajectory", tmp_path / "nowhere", "--out", tmp_path / "a.xdmf"), "not a run directory"
    )
    one_line_error(
        cli_in_process("export-trajectory", runs["ooc"], "--out", runs["ooc"] / "a.xdmf"), "inside the ooc-dem store"
    )
    one_line_error(cli_in_process("animate", runs["ooc"], "--out", tmp_path / "a.avi"), ".mp4 or .gif")
    one_line_error(cli_in_process("export-trajectory", runs["ooc"], "--out", tmp_path / "a.txt"), ".xdmf")
    one_line_error(cli_in_process("check", "quick", "--set", "output.snapshot_interval=-1"), "output.snapshot_interval")
    bad = tmp_path / "bad"
    (bad / TRAJECTORY_DIR).mkdir(parents=True)
    target = bad / TRAJECTORY_DIR / frame_name(123)
    target.write_bytes(b"\x89HDF\r\n\x1a\n" + os.urandom(2000))
    one_line_error(cli_in_process("animate", bad, "--out", tmp_path / "b.gif"), "not a readable HDF5 file")
    good = runs["monolithic"] / TRAJECTORY_DIR / frame_name(123)
    for edit, needle in (
        (lambda f: f.attrs.__setitem__("step", 99), "its name says 123"),
        (lambda f: f.attrs.__setitem__("format", "x"), "not an ooc-dem trajectory"),
        (lambda f: f["id"].__setitem__(1, f["id"][0]), "disc id twice"),
        (lambda f: f.attrs.__setitem__("n_discs", -3), "is not a count"),
        (lambda f: f["r"].resize(7, axis=0), "rows"),
        (lambda f: f.__setitem__("mat2", f["mat"][:]) or f.__delitem__("mat"), "no dataset 'mat'"),
        (lambda f: f.attrs.__setitem__("dim", 3), "dtype"),
    ):
        target.write_bytes(good.read_bytes())
        with h5py.File(target, "r+") as f:
            edit(f)
        one_line_error(cli_in_process("animate", bad, "--out", tmp_path / "c.gif", "--no-progress"), needle)
    target.unlink()
    target.symlink_to(good)  # a frame name that is a symlink
    one_line_error(cli_in_process("export-trajectory", bad, "--out", tmp_path / "e.xdmf"), "not a regular file")
    link = tmp_path / "linked"
    link.mkdir()
    (link / TRAJECTORY_DIR).symlink_to(runs["monolithic"] / TRAJECTORY_DIR)
    one_line_error(cli_in_process("export-trajectory", link, "--out", tmp_path / "d.xdmf"), "not a directory")
    old = tmp_path / "old"
    old.mkdir()
    (old / TRAJECTORY_FILE).symlink_to(good)  # version 1 file: the old rule still holds
    one_line_error(cli_in_process("export-trajectory", old, "--out", tmp_path / "f.xdmf"), "outside the run directory")


def test_version_1_single_file_is_read_and_migrated_on_resume(tmp_path, quick_scenario):
    """A run directory of an earlier engine (one RUN/trajectory.h5, format version 1) is still
    read; resumed, its frames up to the resumed step are copied into trajectory/, equal."""
    sc = _quick_frames(quick_scenario)
    rng = np.random.default_rng(3)
    n, steps = 30, [0, 10, 20, 30]
    parts = [_part(rng, s, rng.permutation(n)) for s in steps]
    with h5py.File(tmp_path / TRAJECTORY_FILE, "w") as f:
        for k, v in {
            "format": "ooc-dem trajectory",
            "format_version": 1,
            "dim": 2,
            "frame_every_steps": 10,
            "dt": sc.physics.dt,
            "scenario_hash": sc.hash(),
            "n_discs": n,
            "frames": len(steps),
        }.items():
            f.attrs[k] = v
        for k in ROW_FIELDS:
            f[k] = np.concatenate([p[k] for p in parts]).astype({"id": "<i8", "mat": "<i4"}.get(k, "<f8"))
        f["frame_step"] = np.array(steps, "<i8")
        f["frame_time"] = np.array(steps, "<f8") * 1e-5
        f["frame_start"] = np.arange(len(steps), dtype="<i8") * n
        f["frame_rows"] = np.full(len(steps), n, "<i8")
        f["wheel_state"] = np.zeros((len(steps), 6))
    old = frames_of(tmp_path)
    assert [f["step"] for f in old] == steps
    assert np.array_equal(old[1]["pos"], parts[1]["pos"][np.argsort(parts[1]["id"])])
    w = TrajectoryWriter.reopen(tmp_path, sc, 2, n, step=20)
    assert w.steps == [0, 10, 20] and w.due(30)
    w.close()
    assert sorted(os.listdir(tmp_path / TRAJECTORY_DIR)) == [frame_name(s) for s in steps[:3]]
    assert_same_frames(old[:3], frames_of(tmp_path))
