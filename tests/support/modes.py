"""One scenario run in every mode, for the mode-equivalence tests: monolithic on the
machine's threads and on one, serial DDM (3 domains), out-of-core (3 domains, K = 10), MPI
on 2 ranks, and an out-of-core run SIGKILLed after its first commit and resumed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

import ooc_dem

from .cli import run_cli
from .mpi import ENV, mpiexec
from .runs import kill_after_first_commit


def set_args(overrides: list[str]) -> list[str]:
    """``--set`` arguments of the overrides."""
    out: list[str] = []
    for o in overrides:
        out += ["--set", o]
    return out


def runs_in_every_mode(name: str, overrides: list[str], steps: int, every: int, work: Path, timeout: float = 900):
    """The runs, by mode name (a RunResult each); ``every``: the out-of-core checkpoint interval."""
    kw = dict(overrides=overrides, steps=steps)
    out = {"monolithic": ooc_dem.run(name, work / "mono", **kw)}
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        out["monolithic-1-thread"] = ooc_dem.run(name, work / "mono1", **kw)
    finally:
        numba.set_num_threads(old)
    out["ddm-3"] = ooc_dem.run(name, work / "ddm", mode="ddm", domains=3, **kw)
    out["ooc-hdf5-10"] = ooc_dem.run(name, work / "ooc", mode="ooc", domains=3, block=10, checkpoint_every=every, **kw)
    cp = subprocess.run(
        [mpiexec(), "-n", "2", sys.executable, "-m", "ooc_dem.cli", "run", name, *set_args(overrides)]
        + ["--mode", "mpi", "--domains", "3", "--steps", str(steps), "--out", str(work / "mpi")]
        + ["--no-progress", "--no-figures"],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **ENV},
    )
    assert cp.returncode == 0, cp.stderr[-3000:]
    out["mpi-2-ranks"] = ooc_dem.open_run(work / "mpi")
    return out


def killed_and_resumed(name: str, overrides: list[str], steps: int, every: int, out: Path, timeout: float = 600):
    """The out-of-core run of ``runs_in_every_mode`` SIGKILLed after its first commit and
    resumed (skips the test when it finished before it could be killed)."""
    cmd = [sys.executable, "-m", "ooc_dem.cli", "run", name, *set_args(overrides)]
    cmd += ["--mode", "ooc", "--domains", "3", "--block", "10", "--steps", str(steps)]
    cmd += ["--checkpoint-every", str(every), "--out", str(out), "--no-progress", "--no-figures"]
    if not kill_after_first_commit(cmd, out, timeout=timeout):
        pytest.skip("the run finished before it could be killed")
    run_cli("resume", out, "--no-progress", "--no-figures", check=True)
    return ooc_dem.open_run(out)


def assert_same_state(a, b, what: str) -> None:
    """Every state array of two runs equal, bit for bit."""
    sa, sb = a.state(), b.state()
    assert sa.keys() == sb.keys()
    for k in sa:
        assert np.array_equal(sa[k], sb[k]), (what, k)
