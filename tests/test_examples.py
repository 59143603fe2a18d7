"""The tutorial's examples (examples/, docs/tutorial.md) run as a user runs them, at their own
small sizes, in a fresh directory: `ooc-dem` and `python` are this interpreter and this tree."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"


def run_example(tmp_path: Path, *cmd: str) -> str:
    """Run an example with `ooc-dem` and `python` on PATH resolving to this interpreter and
    this source tree; returns its stdout (stderr on failure)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "ooc-dem").write_text(f'#!/bin/sh\nexec "{sys.executable}" -m ooc_dem.cli "$@"\n')
    (bin_dir / "python").write_text(f'#!/bin/sh\nexec "{sys.executable}" "$@"\n')
    for f in bin_dir.iterdir():
        f.chmod(0o755)
    env = dict(os.environ)
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["MPLBACKEND"] = "Agg"
    cp = subprocess.run(list(cmd), cwd=tmp_path, env=env, capture_output=True, text=True, timeout=1200)
    assert cp.returncode == 0, f"{cmd} failed ({cp.returncode}):\n{cp.stdout[-2000:]}\n{cp.stderr[-3000:]}"
    return cp.stdout


@pytest.mark.slow
def test_own_wheel(tmp_path):
    out = run_example(tmp_path, str(EXAMPLES / "01_my_wheel.sh"), "run")
    plan = json.JSONDecoder().raw_decode(out[out.index("{") :])[0]  # the plan: the first JSON document
    assert plan["scenario"] == "my-wheel" and plan["n_discs"] == 2900
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert 0.0 < summary["slip"]["steady"]["value"] < 1.0
    assert "net_traction" in out and (tmp_path / "run" / "figures" / "series.png").is_file()


@pytest.mark.slow
def test_slip_sweep_with_error_bars(tmp_path):
    """The sweep, extended by one slip (its two runs reused), re-plotted by report: three
    points, each with a 95 % interval."""
    import csv

    out = run_example(tmp_path, str(EXAMPLES / "02_slip_sweep.sh"), "sweep")
    with open(tmp_path / "sweep" / "drawbar_pull_slip.csv") as f:
        rows = list(csv.DictReader(f))
    assert [float(r["slip"]) for r in rows] == [0.1, 0.3, 0.5]
    for r in rows:
        assert float(r["drawbar_pull_ci95"]) > 0.0
    assert (tmp_path / "sweep" / "drawbar_pull_slip.png").is_file()
    assert " ± " in out


@pytest.mark.slow
def test_out_of_core_under_a_budget(tmp_path):
    out = run_example(tmp_path, str(EXAMPLES / "03_out_of_core.sh"), "ooc")
    plan = json.JSONDecoder().raw_decode(out[out.index("{") :])[0]  # the plan: the first JSON document
    assert plan["mode"] == "ooc" and plan["domains"] > 1 and plan["memory_bytes"] <= plan["memory_budget_bytes"]
    assert "final states: BIT-IDENTICAL" in out


@pytest.mark.slow
def test_stop_and_resume(tmp_path):
    out = run_example(tmp_path, str(EXAMPLES / "04_stop_and_resume.sh"), "resume")
    assert out.count("final states: BIT-IDENTICAL") == 2


def test_results_in_pandas_and_paraview(tmp_path):
    out = run_example(tmp_path, sys.executable, str(EXAMPLES / "05_results.py"), "runs/quick-short")
    export = tmp_path / "runs" / "quick-short-export"
    assert (export / "trajectory.xdmf").is_file() and (export / "final.vtp").is_file()
    assert "9 trajectory frames" in out and "net_traction" in out
