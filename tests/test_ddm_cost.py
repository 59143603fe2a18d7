"""tools/ddm_cost.py: serial DDM against monolithic at a run's last epoch."""

import pytest
import json
import subprocess
import sys
from pathlib import Path

from support.cli import run_cli

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

TOOL = Path(__file__).resolve().parents[1] / "tools" / "ddm_cost.py"


def _cost(*args):
    return subprocess.run([sys.executable, str(TOOL), *map(str, args)], capture_output=True, text=True, timeout=900)


def test_ddm_and_monolithic_from_one_epoch(tmp_path):
    """The quick scenario's wheel on its bed: DDM and monolithic reach the same state from
    the run's last epoch; the local sets hold more rows than discs; every part is timed."""
    run = tmp_path / "run"
    run_cli("run", "quick", "--steps", 1000, "--out", run, "--no-progress", "--no-figures", check=True)
    cp = _cost(run, "--domains", 3, "--steps", 40, "--threads", 2, "--repeat", 1, "--blocks", "1,4")
    assert cp.returncode == 0, cp.stderr
    out = json.loads(cp.stdout)
    assert out["same_state"] is True
    assert out["step"] == 1000 and len(out["rows"]) == 3
    assert sum(out["rows"]) > out["discs"] and out["rows_per_disc"] > 1.0
    assert out["mono_us"] > 0 and out["ddm_us"] > 0 and out["refresh_us"] > 0
    assert set(out["blocked_us"]) == {"1", "4"} and min(out["blocked_us"].values()) > 0


def test_refusals(tmp_path):
    """Bad input: one line on stderr, exit code 2."""
    cp = _cost(tmp_path)
    assert cp.returncode == 2 and "not a run store" in cp.stderr and len(cp.stderr.splitlines()) == 1
    (tmp_path / "scenario.toml").write_text("")
    cp = _cost(tmp_path, "--domains", 1)
    assert cp.returncode == 2 and "--domains" in cp.stderr and len(cp.stderr.splitlines()) == 1
    cp = _cost(tmp_path, "--blocks", "x")
    assert cp.returncode == 2 and "--blocks" in cp.stderr and len(cp.stderr.splitlines()) == 1
