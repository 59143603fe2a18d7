"""Running `ooc-dem` under the mpiexec of this interpreter's environment."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

# one numba thread a rank: ranks are the parallelism (and 3 ranks share 2 cores here)
ENV = {"NUMBA_NUM_THREADS": "1"}


def mpiexec() -> str:
    """The mpiexec of this interpreter's environment (the mpich wheel puts it beside python)."""
    here = os.path.join(os.path.dirname(sys.executable), "mpiexec")
    found = here if os.path.exists(here) else shutil.which("mpiexec")
    assert found, "no mpiexec: install the test extra (pip install '.[test]' brings the mpich wheel)"
    return found


def run_mpi(ranks: int, *args, timeout=240, check=True):
    env = {**os.environ, **ENV}
    cp = subprocess.run(
        [mpiexec(), "-n", str(ranks), sys.executable, "-m", "ooc_dem.cli", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )
    if check and cp.returncode != 0:
        raise AssertionError(
            f"mpiexec -n {ranks} ooc-dem {' '.join(map(str, args))} failed "
            f"({cp.returncode}):\n{cp.stdout[-2000:]}\n{cp.stderr[-3000:]}"
        )
    return cp
