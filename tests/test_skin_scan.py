"""tools/skin_scan.py: the skin changes the time, never the bits."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
from support.cli import run_cli

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

TOOL = Path(__file__).resolve().parents[1] / "tools" / "skin_scan.py"


def _scan(*args):
    return subprocess.run([sys.executable, str(TOOL), *map(str, args)], capture_output=True, text=True, timeout=900)


@pytest.mark.parametrize(
    "scenario, steps, skins, scan_steps",
    [("quick", 2000, "0.0006,0.00002", 500), ("quick-3d", 1500, "0.001,0.0001", 300)],
)
def test_every_skin_gives_the_same_bits(tmp_path, scenario, steps, skins, scan_steps):
    """A scenario's wheel on its bed (2D and 3D), advanced from its last epoch with a wide
    and a narrow skin: the same canonical state hash, more rebuilds and fewer candidate
    pairs with the narrow one. (In 3D a history slot beyond hist_n may keep a stale spring
    that depends on the rebuilds: no part of the state, and not of its hash.)"""
    run = tmp_path / "run"
    run_cli("run", scenario, "--steps", steps, "--out", run, "--no-progress", "--no-figures", check=True)
    cp = _scan(run, "--skins", skins, "--steps", scan_steps, "--repeat", 1)
    assert cp.returncode == 0, cp.stderr
    out = json.loads(cp.stdout)
    wide, narrow = out["rows"]
    assert out["same_bits"] and wide["state_hash"] == narrow["state_hash"]
    assert narrow["rebuilds"] > wide["rebuilds"]
    assert narrow["candidate_pairs_per_particle"] < wide["candidate_pairs_per_particle"]


def test_refusals(tmp_path):
    """Bad input: one line on stderr, exit code 2."""
    cp = _scan(tmp_path, "--skins", "0.0001")
    assert cp.returncode == 2 and "not a run store" in cp.stderr and len(cp.stderr.splitlines()) == 1
    (tmp_path / "scenario.toml").write_text("")
    cp = _scan(tmp_path, "--skins", "-0.001")
    assert cp.returncode == 2 and "positive" in cp.stderr
    cp = _scan(tmp_path, "--skins", "abc")
    assert cp.returncode == 2 and "--skins" in cp.stderr
