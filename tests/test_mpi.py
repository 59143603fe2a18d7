"""MPI mode (engine/mpi.py) with real `mpiexec` processes (the mpich wheel of the test
extra): R ranks give serial DDM's bits, resume across rank counts, and a rank killed
with SIGKILL takes the job down."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import psutil
import pytest

from support.cli import one_line_error, run_cli
from support.mpi import ENV, mpiexec, run_mpi
from support.stores import committed_step

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

# bed-600: 4 equal slabs; the wheel run: a fast slip-controlled wheel set down on the
# quick bed, so that its slab is redefined within 600 steps (test_ddm's wheel case)
BED = ["bed-600"]
BED_STEPS = 60
WHEEL = [
    "quick",
    "--set",
    "wheel.omega=4.0",
    "--set",
    "wheel.control=slip",
    "--set",
    "wheel.slip=0.2",
    "--set",
    "wheel.settle_time=0.0",
    "--set",
    "wheel.drop_gap=0.0",
    "--set",
    "decomposition.margin=0.001",
]
WHEEL_STEPS = 600
# out-of-core commits an epoch per sweep: sweeps of 10 steps (the bits do not depend on K)
OOC_WHEEL = [*WHEEL, "--block", "10", "--set", "output.snapshot_interval=0.002"]  # + frames every 200 steps
OOC_WHEEL_STEPS = 600
QUIET = ["--no-progress", "--no-figures"]


def summary(run) -> dict:
    return json.loads((run / "summary.json").read_text())


def final_state(run) -> dict:
    import ooc_dem

    return ooc_dem.open_run(run).state()


def assert_same_run(a, b):
    sa, sb = final_state(a), final_state(b)
    assert sa.keys() == sb.keys()
    for k in sa:
        assert np.array_equal(sa[k], sb[k]), f"state array {k!r} differs"
    assert summary(a)["state_hash"] == summary(b)["state_hash"]


def _references(tmp_path_factory, mode: str, wheel: list, wheel_steps: int):
    """Serial runs of `mode` to compare with: the bare bed and the wheel run."""
    root = tmp_path_factory.mktemp(f"serial-{mode}")
    run_cli("run", *BED, "--mode", mode, "--steps", BED_STEPS, "--out", root / "bed", *QUIET, check=True, env=ENV)
    run_cli("run", *wheel, "--mode", mode, "--steps", wheel_steps, "--out", root / "wheel", *QUIET, check=True, env=ENV)
    return root


@pytest.fixture(scope="module")
def serial_ooc(tmp_path_factory):
    """Serial out-of-core references (mpi-ooc's epochs and bits are out-of-core's)."""
    return _references(tmp_path_factory, "ooc", OOC_WHEEL, OOC_WHEEL_STEPS)


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    """Serial DDM references (mpi's bits are serial DDM's)."""
    return _references(tmp_path_factory, "ddm", WHEEL, WHEEL_STEPS)


@pytest.mark.parametrize("ranks", [2, 3])
def test_bare_bed_ranks_give_the_serial_bits(serial, tmp_path, ranks):
    out = tmp_path / "mpi"
    run_mpi(ranks, "run", *BED, "--mode", "mpi", "--steps", BED_STEPS, "--out", out, *QUIET)
    assert_same_run(serial / "bed", out)
    eng = summary(out)["engine"]
    assert eng["ranks"] == ranks and sorted(set(eng["rank_domains"])) == list(range(ranks))


@pytest.mark.parametrize("ranks", [2, 3])
def test_wheel_run_ranks_give_the_serial_bits(serial, tmp_path, ranks):
    """With re-decompositions (the wheel leaves its slab): the ranks' ranges are re-cut."""
    out = tmp_path / "mpi"
    run_mpi(ranks, "run", *WHEEL, "--mode", "mpi", "--steps", WHEEL_STEPS, "--out", out, *QUIET)
    assert_same_run(serial / "wheel", out)
    s, ref = summary(out), summary(serial / "wheel")
    assert s["engine"]["redecompositions"] >= 2, s["engine"]  # the initial one and >= 1 on the way
    assert s["engine"]["redecompositions"] == ref["engine"]["redecompositions"]
    assert s["engine"]["bounds"] == ref["engine"]["bounds"]
    assert s["slip"] == ref["slip"] and s["net_traction"] == ref["net_traction"]


def test_share_out_is_scattered_only_when_a_sub_domain_is_too_large_to_cut():
    from ooc_dem.engine.mpi import rank_domains, rank_intervals, rank_segments

    # the paper2008 wheel slab mid-bin holds half the discs: contiguous ranges split 5416 | 1570
    # (or 2014 | 4972), the wheel slab alone against the two sides 3400 | 3586
    assert rank_domains(np.array([2014, 3400, 1572]), 2).tolist() == [1, 0, 1]
    # cuttable counts stay contiguous (fewer exchange partners), even with a tiny gain
    assert rank_domains(np.array([10, 3460, 3516]), 2).tolist() == [0, 0, 1]
    assert rank_domains(np.array([100] * 6), 3).tolist() == [0, 0, 1, 1, 2, 2]
    assert rank_domains(np.array([0, 10, 0]), 2).tolist() == [0, 1, 1]
    bounds = np.array([-np.inf, 0.2, 0.5, np.inf])
    owner = np.array([1, 0, 1])
    assert rank_intervals(owner, bounds, 1).tolist() == [[-np.inf, 0.2], [0.5, np.inf]]
    assert rank_intervals(owner, bounds, 0).tolist() == [[0.2, 0.5]]
    lb, glob = rank_segments(owner, bounds, 1)  # own, ghost (rank 0's slab), own
    assert lb.tolist() == bounds.tolist() and glob.tolist() == [0, -1, 2]
    lb, glob = rank_segments(np.array([0, 0, 1, 1]), np.array([-np.inf, 1.0, 2.0, 3.0, np.inf]), 0)
    assert lb.tolist() == [-np.inf, 1.0, 2.0, np.inf] and glob.tolist() == [0, 1, -1]


def test_scattered_share_out_gives_the_serial_bits(tmp_path):
    """The wheel's slab mid-bin holds two thirds of the quick bed: rank 0 gets it alone and
    rank 1 both sides (two intervals, a ghost between them); same bits as serial DDM."""
    args = ["quick", "--set", "wheel.x0=0.2", "--domains", "3", "--steps", 300, *QUIET]
    run_cli("run", *args, "--mode", "ddm", "--out", tmp_path / "ddm", check=True, env=ENV)
    run_mpi(2, "run", *args, "--mode", "mpi", "--out", tmp_path / "mpi")
    assert summary(tmp_path / "mpi")["engine"]["rank_domains"] == [1, 0, 1]
    assert_same_run(tmp_path / "ddm", tmp_path / "mpi")


def test_spheres_on_ranks_give_the_serial_bits(tmp_path):
    """3D kernels have no one-thread twin: each rank advances its sub-domains with their own
    steppers after the same exchange and refresh (serial DDM's per-sub-domain sweep); the
    wheel rolling on the quick-3d bed ends on serial DDM's bits."""
    args = [
        "quick-3d",
        "--set",
        "wheel.settle_time=0.01",
        "--set",
        "wheel.drop_gap=0",
        "--steps",
        600,
        "--block",
        4,
        *QUIET,
    ]
    run_cli("run", *args, "--mode", "ddm", "--out", tmp_path / "ddm", check=True, env=ENV)
    run_mpi(2, "run", *args, "--mode", "mpi", "--out", tmp_path / "mpi")
    assert sorted(set(summary(tmp_path / "mpi")["engine"]["rank_domains"])) == [0, 1]
    assert_same_run(tmp_path / "ddm", tmp_path / "mpi")


@pytest.mark.parametrize("first,then", [(2, 3), (3, 1)])
def test_resume_with_another_rank_count(serial, tmp_path, first, then):
    """An epoch written by R ranks resumes on R' ranks (1: a plain process, no mpiexec,
    as serial DDM: `resume --mode ddm`)."""
    out = tmp_path / "mpi"
    run_mpi(first, "run", *BED, "--mode", "mpi", "--steps", BED_STEPS // 2, "--out", out, *QUIET)
    if then == 1:
        run_cli("resume", out, "--mode", "ddm", "--steps", BED_STEPS, *QUIET, check=True, env=ENV)
        assert summary(out)["mode"] == "ddm"
    else:
        run_mpi(then, "resume", out, "--steps", BED_STEPS, *QUIET)
        assert summary(out)["engine"]["ranks"] == then
    assert_same_run(serial / "bed", out)


def test_resume_a_serial_run_on_ranks(serial, tmp_path):
    """`resume --mode mpi`: a serial DDM run continues on 2 ranks to the same bits (the
    other way round: test_resume_with_another_rank_count[3-1]). Other modes keep their
    own (one-line refusal)."""
    out = tmp_path / "ddm"
    run_cli("run", *BED, "--mode", "ddm", "--steps", BED_STEPS // 2, "--out", out, *QUIET, check=True, env=ENV)
    run_mpi(2, "resume", out, "--mode", "mpi", "--steps", BED_STEPS, *QUIET)
    assert summary(out)["mode"] == "mpi" and summary(out)["engine"]["ranks"] == 2
    assert_same_run(serial / "bed", out)
    mono = tmp_path / "mono"
    run_cli("run", *BED, "--steps", 5, "--out", mono, *QUIET, check=True, env=ENV)
    one_line_error(run_cli("resume", mono, "--mode", "mpi", "--steps", 10, *QUIET), "--mode 'mpi'", "monolithic")


@pytest.mark.parametrize("mode,serial_mode", [("mpi", "ddm"), ("mpi-ooc", "ooc")])
def test_sigkilled_rank_takes_the_job_down_and_the_run_resumes(tmp_path, mode, serial_mode):
    out = tmp_path / "mpi"
    env = {**os.environ, **ENV}
    job = subprocess.Popen(
        [
            mpiexec(),
            "-n",
            "2",
            sys.executable,
            "-m",
            "ooc_dem.cli",
            "run",
            *BED,
            "--mode",
            mode,
            "--steps",
            "1000000",
            "--checkpoint-every",
            "10",
            "--out",
            str(out),
            *QUIET,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        deadline = time.time() + 180
        while committed_step(out) < 10:
            assert job.poll() is None, job.communicate()
            assert time.time() < deadline, "the job committed no epoch beyond step 0 in 180 s"
            time.sleep(0.2)
        ranks = [
            c
            for c in psutil.Process(job.pid).children(recursive=True)
            if c.environ().get("PMI_RANK") is not None and "ooc_dem.cli" in " ".join(c.cmdline())
        ]
        worker = [c for c in ranks if c.environ()["PMI_RANK"] == "1"]
        assert len(worker) == 1, [(c.pid, c.cmdline()) for c in ranks]
        worker[0].send_signal(signal.SIGKILL)
        t0 = time.time()
        rc = job.wait(timeout=30)
        assert rc != 0
        assert time.time() - t0 < 30
    finally:
        if job.poll() is None:
            job.kill()
            job.wait()
    # the last committed epoch resumes (here on one rank) to the serial bits of that step
    stop = committed_step(out) + 20
    run_cli("resume", out, "--steps", stop, *QUIET, check=True, env=ENV)
    ref = tmp_path / "serial"
    run_cli("run", *BED, "--mode", serial_mode, "--steps", stop, "--out", ref, *QUIET, check=True, env=ENV)
    assert_same_run(ref, out)


# a short slip sweep of the quick wheel (set down without a drop, 5000 steps of travel)
SWEEP = [
    "quick",
    "--set",
    "wheel.settle_time=0.0",
    "--set",
    "wheel.drop_gap=0.0",
    "--set",
    "wheel.travel_time=0.05",
    "--set",
    "wheel.drawbar_ramp=0.01",
    "--set",
    "output.steady_start=0.02",
    "--set",
    "output.steady_end=0.05",
]


def test_sweep_fans_its_runs_out_over_the_ranks(tmp_path):
    """`mpiexec -n 2 ooc-dem sweep`: the three runs are shared by two ranks (run i on rank
    i mod 2) and give the curve of the sweep in one process, byte for byte, and each run's
    final state."""
    one, two = tmp_path / "one", tmp_path / "two"
    slips = "0.1,0.4,0.7"
    run_cli("sweep", *SWEEP, "--slips", slips, "--out", one, "--no-progress", check=True, env=ENV)
    cp = run_mpi(2, "sweep", *SWEEP, "--slips", slips, "--out", two, "--no-progress")
    assert "(rank 1)" in cp.stdout and "(rank 0)" in cp.stdout
    assert (two / "drawbar_pull_slip.csv").read_bytes() == (one / "drawbar_pull_slip.csv").read_bytes()
    assert json.loads((two / "sweep.json").read_text())["ranks"] == 2
    for s in slips.split(","):
        assert_same_run(one / f"slip_{float(s):.3f}", two / f"slip_{float(s):.3f}")


def test_sweep_on_ranks_refuses_bad_input_in_one_line(tmp_path):
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "x").write_text("")
    cp = run_mpi(2, "sweep", *SWEEP, "--slips", "0.1,0.4", "--out", tmp_path / "taken", "--no-progress", check=False)
    assert cp.returncode == 2
    one_line_error(cp, "directory exists and is not empty")


@pytest.mark.parametrize("backend", ["hdf5", "zarr"])
def test_each_rank_writes_its_own_part_of_every_epoch(serial, tmp_path, backend):
    """Two-phase commit: rank r's sub-domains are in part r of each epoch (its own file,
    written by that rank), rank 0's and the globals in the main file; the manifest names
    them all, `checkpoint verify` checks them, and the bits are serial DDM's."""
    out = tmp_path / "mpi"
    run_mpi(
        3,
        "run",
        *BED,
        "--mode",
        "mpi",
        "--steps",
        BED_STEPS,
        "--checkpoint-every",
        20,
        "--backend",
        backend,
        "--out",
        out,
        *QUIET,
    )
    assert_same_run(serial / "bed", out)
    owner = summary(out)["engine"]["rank_domains"]
    of = lambda r: [d for d, q in enumerate(owner) if q == r]
    m = json.loads((out / "MANIFEST.json").read_text())
    for e in (m["current"], m["previous"]):
        parts = e["parts"]
        owners = [r for r in range(1, 3) if of(r)]
        assert len(parts) == len(owners) >= 1
        for k, r in enumerate(owners, start=1):
            assert parts[k - 1]["path"].endswith(f".p{k}.{'h5' if backend == 'hdf5' else 'zip'}")
            mine = sorted(int(d) for d, info in e["domains"].items() if info.get("part") == k)
            assert mine == of(r)
        assert sorted(int(d) for d, info in e["domains"].items() if "part" not in info) == of(0)
    cp = run_cli("checkpoint", "verify", out)
    assert cp.returncode == 0 and "verified" in cp.stdout, cp.stderr
    if backend == "hdf5":
        import h5py

        d = of(owners[0])[0]
        with h5py.File(out / m["current"]["parts"][0]["path"], "r") as f:
            assert f"d{d:04d}" in f["domains"]


@pytest.mark.parametrize("ranks,backend", [(2, "hdf5"), (3, "zarr")])
def test_out_of_core_ranks_give_the_serial_out_of_core_bits(serial_ooc, tmp_path, ranks, backend):
    """`--mode mpi-ooc`: each rank streams its own slabs from the shared store and writes
    its part of every epoch; the bare bed and the wheel run (re-decomposed on the way) end
    on serial out-of-core's bits."""
    for case, args, steps in (("bed", BED, BED_STEPS), ("wheel", OOC_WHEEL, OOC_WHEEL_STEPS)):
        out = tmp_path / case
        run_mpi(ranks, "run", *args, "--mode", "mpi-ooc", "--backend", backend, "--steps", steps, "--out", out, *QUIET)
        assert_same_run(serial_ooc / case, out)
        s, ref = summary(out), summary(serial_ooc / case)
        assert s["mode"] == "mpi-ooc" and s["engine"]["ranks"] == ranks
        assert s["engine"]["redecompositions"] == ref["engine"]["redecompositions"]
        m = json.loads((out / "MANIFEST.json").read_text())
        assert len(m["current"].get("parts", [])) >= 1  # written by the ranks, not gathered
    assert summary(tmp_path / "wheel")["engine"]["redecompositions"] >= 2
    assert summary(tmp_path / "wheel")["slip"] == summary(serial_ooc / "wheel")["slip"]
    # the trajectory: rank 0 streams each frame from the committed epoch, the same frames
    import h5py

    frames = sorted(p.name for p in (serial_ooc / "wheel" / "trajectory").iterdir())
    assert frames == sorted(p.name for p in (tmp_path / "wheel" / "trajectory").iterdir())
    assert len(frames) == OOC_WHEEL_STEPS // 200 + 1
    for name in frames:
        with (
            h5py.File(serial_ooc / "wheel" / "trajectory" / name) as a,
            h5py.File(tmp_path / "wheel" / "trajectory" / name) as b,
        ):
            ia, ib = np.argsort(a["id"][()]), np.argsort(b["id"][()])
            for k in ("id", "pos", "vel", "spin", "r", "mat"):
                assert np.array_equal(a[k][()][ia], b[k][()][ib]), (name, k)


def test_out_of_core_switches_between_one_process_and_ranks(serial_ooc, tmp_path):
    """ooc -> mpi-ooc on 2 ranks -> ooc again: the same epochs, the same bits."""
    out = tmp_path / "run"
    run_cli("run", *BED, "--mode", "ooc", "--steps", BED_STEPS // 3, "--out", out, *QUIET, check=True, env=ENV)
    run_mpi(2, "resume", out, "--mode", "mpi-ooc", "--steps", 2 * BED_STEPS // 3, *QUIET)
    assert summary(out)["mode"] == "mpi-ooc"
    run_cli("resume", out, "--mode", "ooc", "--steps", BED_STEPS, *QUIET, check=True, env=ENV)
    assert summary(out)["mode"] == "ooc"
    assert_same_run(serial_ooc / "bed", out)
    one_line_error(run_cli("resume", out, "--mode", "ddm", "--steps", BED_STEPS + 10, *QUIET), "--mode 'ddm'", "ooc")


@pytest.mark.parametrize("mode", ["mpi", "mpi-ooc"])
def test_bad_input_on_ranks_is_one_line_and_exit_2(tmp_path, mode):
    """The bad-input rule holds under mpiexec too: rank 0's one-line error and exit code 2,
    no abort notice of the MPI beside it."""
    cp = run_mpi(
        2, "run", *BED, "--mode", mode, "--set", "output.no_such_key=1", "--out", tmp_path / "run", *QUIET, check=False
    )
    one_line_error(cp, "output.no_such_key: unknown key")
