"""The memory budget (``--memory``) and the planner's byte model against real runs, and runs
under a hard memory limit (a memory cgroup made by ooc_dem.engine.memlimit).

Every measurement is a real ``ooc-dem`` subprocess; its peak RSS is the kernel's (wait4's
ru_maxrss and /proc VmHWM of the command itself, memlimit.run_limited)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ooc_dem.engine import budget
from ooc_dem.app.run import RunError, RunOptions, plan_run
from ooc_dem.engine.memlimit import _own_cgroup, parse_size, run_limited
from ooc_dem.model.scenario import load_scenario

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
# the planner's estimate of a whole run's peak (baseline included) against the measured peak
TOLERANCE = 0.20


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "ooc_dem.cli", *map(str, args)]


def _check(*args) -> dict:
    cp = subprocess.run(_cli("check", *args), capture_output=True, text=True, env=ENV)
    assert cp.returncode == 0, cp.stderr
    return json.loads(cp.stdout)


@pytest.mark.parametrize("scenario,memory", [("bed-100000", "270MB"), ("bed3d-30000", "260MB")])
def test_budget_chooses_slabs_whose_measured_peak_is_the_estimate(tmp_path, scenario, memory):
    """2D discs and 3D spheres: `--memory` picks D and K, the run says so, and a real run's
    peak RSS is the planner's estimate within TOLERANCE and within the budget."""
    plan = _check(scenario, "--mode", "ooc", "--memory", memory)
    limit = parse_size(memory)
    assert plan["memory_budget_bytes"] == limit
    assert plan["memory_bytes"] <= limit and plan["domains"] > 1
    steps = plan["block"]  # one whole sweep
    # the same run first: numba's cache and the bed cache warm (the byte model's baseline is
    # a warm one; on a fresh machine the first run compiles, ~100 MB more, and settles the
    # bed's tile)
    warm = run_limited(
        _cli(
            "run",
            scenario,
            "--mode",
            "ooc",
            "--memory",
            memory,
            "--steps",
            steps,
            "--out",
            tmp_path / "warm",
            "--no-progress",
            "--no-figures",
        ),
        env=ENV,
    )
    assert warm.returncode == 0, warm.stderr
    res = run_limited(
        _cli(
            "run",
            scenario,
            "--mode",
            "ooc",
            "--memory",
            memory,
            "--steps",
            steps,
            "--out",
            tmp_path / "run",
            "--no-progress",
            "--no-figures",
        ),
        env=ENV,
    )
    assert res.returncode == 0, res.stderr
    said = res.stderr.strip().splitlines()[0]  # the run states its choice
    assert said.startswith(
        f"ooc-dem: memory budget {budget.fmt_bytes(limit)}: ooc with D = {plan['domains']} "
        f"sub-domains, K = {plan['block']} step"
    ), said
    assert said.endswith(f"; expected peak {budget.fmt_bytes(plan['memory_bytes'])}"), said
    stored = json.loads((tmp_path / "run" / "MANIFEST.json").read_text())["meta"]["run"]
    assert (stored["domains"], stored["block"]) == (plan["domains"], plan["block"])  # resume keeps them
    peak = res.peak_rss_bytes
    assert abs(plan["memory_bytes"] - peak) <= TOLERANCE * peak, (plan["memory_bytes"], peak)
    assert peak <= limit


def test_fixed_slab_memory_is_independent_of_n():
    """The same budget on beds 4x apart: the slab (so the estimated peak) stays, D grows with N
    (the set-up's bounds and the state hash stream: budget.BYTE_MODELS' terms of the whole
    bed are 0). Beds large enough that D is well above 1 on both (at D = 2 the smaller bed's
    slab is N/2, below what the budget allows, and D cannot scale); the slabs then differ by
    no more than D's integer rounding, 1/D of the smaller bed's."""
    small, big = load_scenario("bed-4000000"), load_scenario("bed-16000000")
    got = [plan_run(sc, RunOptions(mode="ooc", memory=parse_size("400MB"), block=20, steps=20)) for sc in (small, big)]
    assert got[1].domains >= 3.5 * got[0].domains
    assert abs(got[1].memory_bytes - got[0].memory_bytes) <= 0.02 * got[0].memory_bytes
    assert all(p.memory_bytes <= parse_size("400MB") and p.block == 20 for p in got)
    slab = [budget.state_peak(sc, "ooc", "hdf5", p.domains, p.block, True)["slab"] for sc, p in zip((small, big), got)]
    assert abs(slab[1] - slab[0]) <= slab[0] / got[0].domains


def test_budget_too_small_names_the_parts():
    with pytest.raises(
        RunError,
        match=r"--memory 100.0 MB: out-of-core needs at least about .* "
        r"\(interpreter and kernels .* \+ a slab of D = \d+ with its halo .*",
    ):
        plan_run(load_scenario("bed-100000"), RunOptions(mode="ooc", memory=100_000_000, steps=1))
    with pytest.raises(RunError, match=r"the monolithic run needs about .*; --mode ooc chooses"):
        plan_run(load_scenario("bed-1000000"), RunOptions(mode="monolithic", memory=parse_size("500MB"), steps=1))


def test_memory_flag_refuses_a_non_size():
    cp = subprocess.run(
        _cli("check", "bed-7000", "--mode", "ooc", "--memory", "lots"), capture_output=True, text=True, env=ENV
    )
    assert cp.returncode == 2 and len(cp.stderr.strip().splitlines()) == 1
    assert "--memory: 'lots' is not a size" in cp.stderr


def test_byte_models_per_dimension():
    """3D spheres cost more than 2D discs in every term (state, neighbours, history)."""
    m2, m3 = budget.byte_model(2), budget.byte_model(3)
    assert m3.state > m2.state and m3.monolithic > m2.monolithic and m3.resident > m2.resident
    assert m2.state == 272  # state.bytes_per_disc(2) at the 2D history capacity 8


def _cgroups_of(pid: int) -> list[Path]:
    version, parent = _own_cgroup()
    return sorted(parent.glob(f"ooc-dem-{pid}-*"))


def _profile(tmp_path, limit: str):
    out = tmp_path / "prof"
    proc = subprocess.Popen(
        _cli(
            "profile",
            "bed-2000",
            "--modes",
            "ooc",
            "--domains",
            "2",
            "--block",
            "2",
            "--steps",
            "4",
            "--memory-limit",
            limit,
            "--out",
            out,
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    stdout, stderr = proc.communicate(timeout=300)
    return proc, stdout, stderr, out


def test_profile_under_a_memory_limit_well_above_the_need(tmp_path):
    proc, stdout, stderr, out = _profile(tmp_path, "1GB")
    assert proc.returncode == 0, stderr
    run = json.loads((out / "memory.json").read_text())["runs"][0]
    lim = run["memory_limit"]
    assert lim["memory_limit_bytes"] == 10**9 and lim["oom_killed"] is False
    assert 0 < lim["peak_rss_bytes"] <= 10**9 and 0 < lim["cgroup_peak_bytes"] <= 10**9
    assert 0 < lim["sampled_peak_anon_bytes"] <= lim["cgroup_peak_bytes"]
    assert lim["rss_samples"] >= 2
    assert lim["peak_rss_bytes"] >= run["peak_rss_bytes"]  # outside the run's own window too
    assert "under the 1000.0 MB limit" in stdout
    assert _cgroups_of(proc.pid) == []  # the cgroup is removed afterwards


def test_profile_far_below_the_need_is_reported_as_killed_by_the_limit(tmp_path):
    proc, stdout, stderr, out = _profile(tmp_path, "60MB")
    assert proc.returncode == 137, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("ooc-dem: error: mode ooc was killed by the memory limit (OOM): limit 60.0 MB")
    doc = json.loads((out / "memory.json").read_text())
    assert doc["oom_killed"]["oom_killed"] is True and doc["oom_killed"]["returncode"] == -9
    assert doc["oom_killed"]["cgroup_peak_bytes"] <= 60 * 10**6
    assert _cgroups_of(proc.pid) == []


def test_run_limited_without_a_limit_measures_only():
    res = run_limited([sys.executable, "-c", "import numpy as np; a = np.ones(25_000_000); a[::512] = 2"])
    assert res.returncode == 0 and res.limit_bytes is None and res.cgroup_version is None
    assert res.peak_rss_bytes >= 200 * 10**6 and not res.oom_killed


@pytest.mark.parametrize(
    "text,value",
    [("2GB", 2 * 10**9), ("512MiB", 512 * 2**20), ("1.5G", 1.5e9), ("1e9", 10**9), ("300 MB", 300 * 10**6)],
)
def test_parse_size(text, value):
    assert parse_size(text) == int(value)


@pytest.mark.parametrize("text", ["", "GB", "-1GB", "2XB", "nan", "inf"])
def test_parse_size_refuses(text):
    with pytest.raises(ValueError):
        parse_size(text)


def test_run_limited_measures_the_child_not_the_parents_peak():
    """A parent that once held 400 MB spawns a small child: the child's peak is its own (a
    vfork'ed child's ru_maxrss starts at its parent's peak; run_limited's launcher forks it from
    a bare interpreter instead)."""
    big = np.ones(50_000_000)
    big[::512] = 2
    del big
    res = run_limited([sys.executable, "-c", "pass"])
    assert res.returncode == 0
    assert res.peak_rss_bytes < 60 * 10**6, res.peak_rss_bytes


def test_run_limited_reports_exit_codes_and_a_missing_command():
    assert run_limited([sys.executable, "-c", "import sys; sys.exit(3)"]).returncode == 3
    res = run_limited(["/nonexistent/ooc-dem-no-such-command"])
    assert res.returncode == 127 and "cannot run /nonexistent/ooc-dem-no-such-command" in res.stderr
