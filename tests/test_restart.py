"""Checkpoint/restart: SIGKILL at random moments, resume, same final bits.

The trials use the machinery of ``tools/torture.py`` (the same code that runs the
200-trial torture): an uninterrupted reference run per configuration gives the final
hash and its wall time T; each trial starts the same run in a real subprocess,
SIGKILLs it after a delay drawn uniformly from [0, T] (interpreter start-up, bed
setup, stepping, writing or committing an epoch), resumes it to the end and
requires the reference hash and a passing `checkpoint verify`.
"""

import argparse
import importlib.util
import random
from pathlib import Path

import pytest

from support.cli import cli_in_process, run_cli

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]

# (torture mode name, steps, checkpoint every, block): sized so that an uninterrupted run
# spends most of its wall time stepping and committing rather than starting the interpreter
CONFIGS = {
    "monolithic": ("monolithic", 4800, 60, 10),
    "ooc-hdf5": ("ooc-hdf5", 600, 60, 10),  # an epoch per sweep: 60 commits
    "ooc-zarr": ("ooc-zarr", 600, 60, 20),  # zarr commits are slower: 30 of them
}
TRIALS = ["monolithic"] * 8 + ["ooc-hdf5"] * 6 + ["ooc-zarr"] * 6


def _torture_module():
    spec = importlib.util.spec_from_file_location("ooc_torture", ROOT / "tools" / "torture.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def torture(tmp_path_factory):
    mod = _torture_module()
    work = tmp_path_factory.mktemp("torture")
    runners, refs = {}, {}
    for name, (mode, steps, every, block) in CONFIGS.items():
        args = argparse.Namespace(
            scenario="bed-1200",
            steps=steps,
            checkpoint_every=every,
            domains=3,
            block=block,
            kills=1,
            timeout=600,
            keep=False,
        )
        t = mod.Torture(args, work / name)
        refs[name] = t.reference(mode)
        t.reference_hash = refs[name]["hash"]
        runners[name] = t
    return runners, refs


def test_references_agree_across_backends(torture):
    _, refs = torture
    assert refs["ooc-hdf5"]["hash"] is not None
    assert refs["ooc-hdf5"]["hash"] == refs["ooc-zarr"]["hash"]


@pytest.mark.parametrize("trial", range(len(TRIALS)))
def test_sigkill_then_resume_gives_same_bits(torture, trial):
    runners, refs = torture
    name = TRIALS[trial]
    rec = runners[name].trial(CONFIGS[name][0], trial, random.Random(1000 + trial), refs[name]["wall_s"])
    assert rec["ok"], rec


def test_most_kills_land_mid_run(torture):
    """The delays are drawn over the run's own wall time, so kills do land (not after the end)."""
    runners, refs = torture
    rng = random.Random(7)
    landed = 0
    for i in range(3):
        rec = runners["monolithic"].trial("monolithic", 100 + i, rng, refs["monolithic"]["wall_s"])
        assert rec["ok"], rec
        landed += rec["exit_at_kill"][0] == -9
    assert landed >= 2


def test_resume_finished_run_is_noop(tmp_path):
    out = tmp_path / "run"
    run_cli("run", "bed-1200", "--out", out, "--steps", "30", "--no-progress", check=True)
    h = cli_in_process("checkpoint", "hash", out, check=True).stdout.strip()
    cp = run_cli("resume", out, "--no-progress")
    assert cp.returncode == 0 and "already finished" in cp.stdout
    assert cli_in_process("checkpoint", "hash", out, check=True).stdout.strip() == h


@pytest.mark.parametrize("mode", [["--mode", "monolithic"], ["--mode", "ddm", "--domains", "3"]])
def test_resume_extends_run_to_same_bits(tmp_path, mode):
    """Run 30 steps (committing every 10), then resume to 60: equals a straight
    monolithic 60-step run."""
    a, b = tmp_path / "a", tmp_path / "b"
    run_cli(
        "run", "bed-1200", "--out", a, "--steps", "30", "--checkpoint-every", "10", *mode, "--no-progress", check=True
    )
    run_cli("resume", a, "--steps", "60", "--no-progress", check=True)
    run_cli("run", "bed-1200", "--out", b, "--steps", "60", "--no-progress", check=True)
    ha = cli_in_process("checkpoint", "hash", a, check=True).stdout.strip()
    hb = cli_in_process("checkpoint", "hash", b, check=True).stdout.strip()
    assert ha == hb


@pytest.mark.slow
def test_ctrl_c_names_the_run_directory_and_the_step_resume_continues_from(tmp_path):
    """SIGINT (Ctrl-C) after the first committed epoch: exit 130, one line naming the run
    directory and the step of the last committed epoch, which is where `resume` continues."""
    import signal
    import subprocess
    import sys
    import time

    from support.stores import committed_step

    out = tmp_path / "run"
    cmd = [
        sys.executable,
        "-m",
        "ooc_dem.cli",
        "run",
        "quick",
        "--steps",
        "400000",
        "--checkpoint-every",
        "200",
        "--no-progress",
        "--no-figures",
        "--out",
        str(out),
    ]
    # a suite started in the background of a non-interactive shell inherits SIGINT ignored,
    # and Python keeps an ignored SIGINT ignored: the run is given the default disposition
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.time() + 600
    while time.time() < deadline and proc.poll() is None and committed_step(out) < 400:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    at = committed_step(out)
    assert f"ooc-dem resume {out}` continues from step {at} " in lines[0], lines[0]
    assert at >= 400 and at % 200 == 0
