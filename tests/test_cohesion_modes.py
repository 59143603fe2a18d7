"""Cohesion leaves every mode the same bits: monolithic on 1 and 2 threads, serial DDM,
out-of-core, MPI on 2 ranks and a SIGKILLed out-of-core run resumed, in 2D (the wheel
on a cohesive soil) and 3D (a cohesive bed of spheres)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numba
import numpy as np
import pytest

import ooc_dem
from support.cli import run_cli
from support.stores import committed_step
from support.mpi import ENV, mpiexec

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

CASES = {
    "2d": (
        "quick",
        [
            "contact.soil_soil.cohesion=2000.0",
            "contact.soil_wheel.cohesion=1000.0",
            "contact.soil_soil.no_tension=false",
            "wheel.control=slip",
            "wheel.slip=0.2",
            "wheel.omega=4.0",
            "wheel.settle_time=0.0",
            "wheel.drop_gap=0.0",
        ],
        400,
    ),
    "3d": ("bed3d-3000", ["contact.soil_soil.cohesion=3000.0", "contact.soil_wall.cohesion=1000.0"], 80),
}


def _sets(overrides):
    out = []
    for o in overrides:
        out += ["--set", o]
    return out


@pytest.fixture(scope="module", params=sorted(CASES))
def runs(request, tmp_path_factory):
    name, overrides, steps = CASES[request.param]
    work = tmp_path_factory.mktemp(f"cohesion-{request.param}")
    kw = dict(overrides=overrides, steps=steps)
    out = {"monolithic": ooc_dem.run(name, work / "mono", **kw)}
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        out["monolithic-1-thread"] = ooc_dem.run(name, work / "mono1", **kw)
    finally:
        numba.set_num_threads(old)
    out["ddm-3"] = ooc_dem.run(name, work / "ddm", mode="ddm", domains=3, **kw)
    out["ooc-hdf5-10"] = ooc_dem.run(name, work / "ooc", mode="ooc", domains=3, block=10, checkpoint_every=20, **kw)
    cp = subprocess.run(
        [mpiexec(), "-n", "2", sys.executable, "-m", "ooc_dem.cli", "run", name, *_sets(overrides)]
        + ["--mode", "mpi", "--domains", "3", "--steps", str(steps), "--out", str(work / "mpi")]
        + ["--no-progress", "--no-figures"],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, **ENV},
    )
    assert cp.returncode == 0, cp.stderr[-3000:]
    out["mpi-2-ranks"] = ooc_dem.open_run(work / "mpi")
    out["_bare"] = ooc_dem.run(name, work / "bare", steps=steps)  # the same run without cohesion
    out["_args"] = (name, overrides, steps, work)
    return out


def _same(a, b, what):
    sa, sb = a.state(), b.state()
    assert sa.keys() == sb.keys()
    for k in sa:
        assert np.array_equal(sa[k], sb[k]), (what, k)


def test_cohesion_acts(runs):
    assert runs["monolithic"].summary["state_hash"] != runs["_bare"].summary["state_hash"]


def test_every_mode_gives_the_same_bits_with_cohesion(runs):
    ref = runs["monolithic"]
    for name, res in runs.items():
        if name.startswith("_") or name == "monolithic":
            continue
        assert res.summary["state_hash"] == ref.summary["state_hash"], name
        _same(ref, res, name)


def test_a_sigkilled_cohesive_run_resumes_to_the_same_bits(runs):
    name, overrides, steps, work = runs["_args"]
    out = work / "killed"
    cmd = [sys.executable, "-m", "ooc_dem.cli", "run", name, *_sets(overrides)]
    cmd += ["--mode", "ooc", "--domains", "3", "--block", "10", "--steps", str(steps)]
    cmd += ["--checkpoint-every", "20", "--out", str(out), "--no-progress", "--no-figures"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.time() + 600
    killed = False
    while time.time() < deadline and proc.poll() is None:
        if committed_step(out) > 0:
            proc.send_signal(signal.SIGKILL)
            killed = True
            break
        time.sleep(0.05)
    proc.wait(timeout=60)
    if not killed:
        pytest.skip("the run finished before it could be killed")
    assert proc.returncode == -9
    run_cli("resume", out, "--no-progress", "--no-figures", check=True)
    _same(runs["ooc-hdf5-10"], ooc_dem.open_run(out), "killed and resumed")
