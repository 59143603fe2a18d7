"""Checkpoint/restart: SIGKILL at random moments, resume, same final bits (issue 6)."""
import os
import random
import signal
import subprocess
import sys
import time

import pytest

from conftest import run_cli

STEPS = 1200
CKPT = 60


def _cmd(out, mode, backend):
    return [sys.executable, "-m", "ooc_dem.cli", "run", "bed-1200", "--out", str(out), "--steps", str(STEPS),
            "--checkpoint-every", str(CKPT), "--mode", mode, "--backend", backend, "--domains", "3",
            "--block", "10", "--no-progress", "--no-figures"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "run"
    subprocess.run(_cmd(out, "monolithic", "hdf5"), check=True, capture_output=True)
    return run_cli("checkpoint", "hash", out, check=True).stdout.strip()


def kill_and_resume(out, mode, backend, delay):
    proc = subprocess.Popen(_cmd(out, mode, backend), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    time.sleep(delay)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    for _ in range(20):
        cp = run_cli("resume", out, "--no-progress", "--no-figures")
        if cp.returncode == 0:
            return run_cli("checkpoint", "hash", out, check=True).stdout.strip(), True
        # killed before the first commit: nothing to resume, a fresh start is the user's move
        assert "MANIFEST" in cp.stderr or "not an ooc-dem" in cp.stderr or "no committed" in cp.stderr, cp.stderr
        import shutil
        shutil.rmtree(out, ignore_errors=True)
        subprocess.run(_cmd(out, mode, backend), check=True, capture_output=True)
        return run_cli("checkpoint", "hash", out, check=True).stdout.strip(), False
    raise AssertionError("resume never finished")


CASES = [("monolithic", "hdf5")] * 8 + [("ooc", "hdf5")] * 6 + [("ooc", "zarr")] * 6


@pytest.mark.parametrize("trial", range(len(CASES)))
def test_sigkill_then_resume_gives_same_bits(reference, tmp_path, trial):
    mode, backend = CASES[trial]
    rng = random.Random(1000 + trial)
    delay = rng.uniform(1.0, 6.0)   # from interpreter start-up through the whole run
    h, resumed = kill_and_resume(tmp_path / "run", mode, backend, delay)
    assert h == reference, (mode, backend, delay, resumed)


def test_resume_finished_run_is_noop(tmp_path):
    out = tmp_path / "run"
    run_cli("run", "bed-1200", "--out", out, "--steps", "30", "--no-progress", check=True)
    h = run_cli("checkpoint", "hash", out, check=True).stdout.strip()
    cp = run_cli("resume", out, "--no-progress")
    assert cp.returncode == 0 and "already finished" in cp.stdout
    assert run_cli("checkpoint", "hash", out, check=True).stdout.strip() == h


def test_resume_extends_run_to_same_bits(tmp_path):
    """Run 30 steps, then resume to 60: equals a straight 60-step run."""
    a, b = tmp_path / "a", tmp_path / "b"
    run_cli("run", "bed-1200", "--out", a, "--steps", "30", "--no-progress", check=True)
    run_cli("resume", a, "--steps", "60", "--no-progress", check=True)
    run_cli("run", "bed-1200", "--out", b, "--steps", "60", "--no-progress", check=True)
    ha = run_cli("checkpoint", "hash", a, check=True).stdout.strip()
    hb = run_cli("checkpoint", "hash", b, check=True).stdout.strip()
    assert ha == hb
