"""`ooc-dem experiment`: the experiment file's refusals, the steady-window statistics on
synthetic series with known answers, the Ding 2011 file's plan, and a small made-up
experiment end to end, killed mid-run and continued (the resumed run's series equal to an
uninterrupted one's, finished runs reused)."""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from ooc_dem.app.stats import difference, t_quantile_975, window_stats
from support.cli import cli_in_process, one_line_error, run_cli
from support.runs import kill_after_first_commit

ROOT = Path(__file__).resolve().parents[1]
SMALL = ROOT / "tests" / "data" / "experiment_small.toml"
DING = ROOT / "experiments" / "ding2011.toml"


# ---------------------------------------------------------------------- statistics


def test_t_quantile_known_values():
    for dof, q in ((1, 12.7062047), (2, 4.3026527), (4, 2.7764451), (10, 2.2281389), (30, 2.0422725)):
        assert abs(t_quantile_975(dof) - q) < 1e-6
    assert abs(t_quantile_975(10**6) - 1.959964) < 1e-5  # the normal quantile, approached
    with pytest.raises(ValueError):
        t_quantile_975(0)


def _sine(periods: float, rows_per_period: int, mean=3.0, amp=2.0, noise=0.0, rng=None):
    period = 0.25
    step = period / rows_per_period
    n = int(round(periods * rows_per_period))
    t = 0.1 + step * np.arange(1, n + 1)  # each row ends at its time
    y = mean + amp * np.sin(2 * np.pi * (t - 0.1) / period + 0.3)
    if noise:
        y = y + rng.normal(0.0, noise, n)
    return t, y, period


def test_window_over_whole_passages_gives_the_exact_mean():
    t, y, period = _sine(7.6, 20)
    st = window_stats(t, y, 0.1, t[-1], period)
    assert st.passages == 7 and st.blocks == 7 and st.rows == 140
    assert abs(st.mean - 3.0) < 1e-12
    assert abs(st.std - 2.0 / math.sqrt(2.0)) < 0.01
    assert st.ci95 < 1e-9  # every whole passage has the same mean
    two = window_stats(t, y, 0.1, t[-1], period, passages_per_block=2)
    assert two.blocks == 3 and two.passages == 6 and abs(two.mean - 3.0) < 1e-12


def test_block_interval_covers_the_true_mean():
    rng = np.random.default_rng(7)
    covered = 0
    trials = 400
    for _ in range(trials):
        t, y, period = _sine(8.0, 10, noise=1.0, rng=rng)
        st = window_stats(t, y, 0.1, t[-1], period)
        assert st.blocks == 8
        covered += abs(st.mean - 3.0) <= st.ci95
    assert 0.9 <= covered / trials <= 0.99, covered


def test_difference_of_two_means():
    rng = np.random.default_rng(3)
    t, a, period = _sine(8.0, 10, mean=5.0, noise=0.5, rng=rng)
    _, b, _ = _sine(8.0, 10, mean=2.0, noise=0.5, rng=rng)
    sa, sb = window_stats(t, a, 0.1, t[-1], period), window_stats(t, b, 0.1, t[-1], period)
    d, ci = difference(sa, sb)
    assert d == sa.mean - sb.mean
    assert max(sa.ci95, sb.ci95) < ci < sa.ci95 + sb.ci95 + 1e-12
    assert abs(d - 3.0) < ci


def test_too_short_a_window_has_no_interval():
    t, y, period = _sine(1.5, 20)
    st = window_stats(t, y, 0.1, t[-1], period)
    assert st.blocks == 1 and math.isnan(st.ci95) and abs(st.mean - 3.0) < 1e-12


# ------------------------------------------------------------------------- the file

BAD_FILES = [
    ("[dem]\n", "[dem]\ncolour = 3\n", "[dem].colour"),
    ("[conventions]\n", "[frobnicate]\nx = 1\n[conventions]\n", "[frobnicate]"),
    ("r_min = 0.003", "r_min = -0.003", "[dem].r_min"),
    ('slip_radius = "lug_tip"', 'slip_radius = "hub"', "slip_radius"),
    ("lug_thickness = 0.003\n", "", "lug_thickness"),
    ("drawbar_pull = [0.5, 0.8]", "drawbar_pull = [0.5]", "drawbar_pull"),
    ("[measured.lugged]", "[measured.tracked]", "tracked"),
    ('name = "lugged"', 'name = "smooth"', "smooth"),
    ("friction_angle = 30.0", "friction_angle = 95.0", "friction_angle"),
    ("steady_end = 0.4", "steady_end = 0.6", "steady_end"),
    ("side_margin = 0.02", "side_margin = 0.02\nbin_length = 0.1", "bin_length"),
    ("dt = 2.0e-5", "dt = 1.0e-3", "physics.dt"),
    (
        'calibrated = ["contact.soil_soil.friction=0.5", "bed.fill_friction=0.3"]',
        'calibrated = "nowhere.json"',
        "calibrated",
    ),
    ("slips = [0.2, 0.4]", "slips = [0.2, 1.4]", "slips"),
    ('name = "small"', 'name = "../small"', "name"),
    ("omega = 4.0", 'omega = "fast"', "omega"),
]


@pytest.mark.parametrize("old,new,needle", BAD_FILES, ids=[n for _, _, n in BAD_FILES])
def test_bad_experiment_file_is_one_line_exit_2(old, new, needle, tmp_path):
    text = SMALL.read_text()
    assert old in text
    f = tmp_path / "bad.toml"
    f.write_text(text.replace(old, new, 1))
    cp = cli_in_process("experiment", f, "--out", tmp_path / "out", "--plan")
    one_line_error(cp, needle)
    assert not (tmp_path / "out").exists()


def test_bad_options_are_one_line(tmp_path):
    one_line_error(cli_in_process("experiment", SMALL, "--out", tmp_path / "o", "--only", "tank", "--plan"), "tank")
    one_line_error(cli_in_process("experiment", SMALL, "--out", tmp_path / "o", "--slips", "0.3", "--plan"), "--slips")
    one_line_error(cli_in_process("experiment", tmp_path / "none.toml", "--out", tmp_path / "o"), "no such file")
    bad = tmp_path / "bad.toml"
    bad.write_text("[experiment\n")
    one_line_error(cli_in_process("experiment", bad, "--out", tmp_path / "o"), "invalid TOML")


def test_small_plan():
    cp = cli_in_process("experiment", SMALL, "--out", "unused", "--plan", check=True)
    plan = json.loads(cp.stdout)
    assert plan["spheres"] < 3000 and len(plan["runs"]) == 4
    lugged = [r for r in plan["runs"] if r["wheel"] == "lugged"]
    # lug-tip slip convention: v = (1 - s) R_tip omega, so the engine's (rim) slip is lower
    assert lugged[0]["engine_slip"] == pytest.approx(1 - 0.8 * 0.055 / 0.05)
    assert lugged[0]["carriage_speed_m_s"] == pytest.approx(0.8 * 0.055 * 4.0)


def test_ding2011_plans():
    """The Ding 2011 file is valid and sized as stated (spheres, bin width beyond the influence zone)."""
    cp = cli_in_process("experiment", DING, "--out", "unused", "--plan", check=True)
    plan = json.loads(cp.stdout)
    assert 30_000 < plan["spheres"] <= 55_000
    assert plan["bin_m"][1] >= 0.165 + 2 * 0.13 - 1e-9
    assert len(plan["runs"]) == 10


# --------------------------------------------------------------- end to end, stopped


def _series(run: Path) -> np.ndarray:
    return np.loadtxt(run / "series.csv", delimiter=",", skiprows=1)


@pytest.mark.slow
def test_small_experiment_killed_and_continued(tmp_path):
    """The small experiment killed during its first run, then continued: the stopped run
    resumes (its series equal to an uninterrupted run's), the others run, the report is
    written; a third invocation reuses every run; under mpiexec -n 2 the same runs."""
    ref = tmp_path / "ref"
    run_cli("experiment", SMALL, "--out", ref, "--only", "smooth", "--slips", "0.2", "--no-progress", check=True)
    out = tmp_path / "out"
    first = out / "smooth" / "slip_0.200"
    cmd = [sys.executable, "-m", "ooc_dem.cli", "experiment", str(SMALL), "--out", str(out), "--no-progress"]
    assert kill_after_first_commit(cmd, first), "the run finished before it could be killed"
    assert not (first / "summary.json").exists()

    cp = run_cli("experiment", SMALL, "--out", out, "--no-progress", check=True)
    assert f"smooth slip 0.200: resumed ({first})" in cp.stdout
    assert cp.stdout.count(": ran (") == 3
    # NaN: the slip while the wheel settles (omega = 0)
    assert np.array_equal(_series(first), _series(ref / "smooth" / "slip_0.200"), equal_nan=True)
    state = [json.loads((d / "summary.json").read_text())["state_hash"] for d in (first, ref / "smooth" / "slip_0.200")]
    assert state[0] == state[1]

    for name in ("comparison.csv", "comparison.md", "experiment.json", "figures/experiment.png"):
        assert (out / name).is_file(), name
    with open(out / "comparison.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["wheel"], float(r["slip"])) for r in rows] == [
        ("smooth", 0.2),
        ("smooth", 0.4),
        ("lugged", 0.2),
        ("lugged", 0.4),
    ]
    for r in rows:
        assert int(r["blocks"]) == 3
        assert math.isfinite(float(r["drawbar_pull"])) and float(r["drawbar_pull_ci95"]) > 0
        assert float(r["slip_achieved"]) == pytest.approx(float(r["slip"]), abs=1e-9)
        assert float(r["vertical_force"]) == pytest.approx(5.0, rel=0.2)  # the wheel carries its load
    lugged = [r for r in rows if r["wheel"] == "lugged"]
    assert all(r["lug_gain"] and r["lug_gain_measured"] for r in lugged)
    doc = json.loads((out / "experiment.json").read_text())
    assert doc["calibration"]["given"] is True and len(doc["runs"]) == 4
    assert all(r["spheres"] == doc["geometry"]["n"] and r["wall_time_s"] > 0 for r in doc["runs"])

    stamps = {p: p.stat().st_mtime_ns for p in out.glob("*/slip_*/summary.json")}
    cp = run_cli("experiment", SMALL, "--out", out, "--no-progress", check=True)
    assert cp.stdout.count(": reused (") == 4
    assert stamps == {p: p.stat().st_mtime_ns for p in out.glob("*/slip_*/summary.json")}

    # under mpiexec the runs fan out over the ranks, each the same run as in one process
    from support.mpi import run_mpi

    cp = run_mpi(2, "experiment", SMALL, "--out", tmp_path / "mpi", "--only", "lugged", "--no-progress")
    assert "lugged slip 0.400: ran" in cp.stdout and "(rank 1)" in cp.stdout
    for s in ("slip_0.200", "slip_0.400"):
        assert np.array_equal(_series(tmp_path / "mpi" / "lugged" / s), _series(out / "lugged" / s), equal_nan=True)


def test_changed_experiment_refuses_an_old_run(tmp_path):
    """A run directory of another scenario (the file changed) is refused, not continued."""
    out = tmp_path / "out"
    run = out / "smooth" / "slip_0.200"
    run.mkdir(parents=True)
    from ooc_dem.model.scenario import load_scenario

    (run / "scenario.toml").write_text(load_scenario("quick-3d").to_toml())
    one_line_error(cli_in_process("experiment", SMALL, "--out", out, "--no-progress"), "holds no experiment")
    (out / "experiment.toml").write_text(SMALL.read_text())
    one_line_error(cli_in_process("experiment", SMALL, "--out", out, "--no-progress"), "another scenario")


@pytest.mark.slow
def test_calibration_from_the_lab_properties_is_run_once(tmp_path):
    """Without [dem].calibrated the pipeline calibrates the soil from the lab properties
    (never the wheel data) with the file's [calibration] tests, reuses the finished
    calibration afterwards, and refuses one made for another soil."""
    from ooc_dem.app import experiment as ex
    from ooc_dem.app.calibrate import soil_key
    from ooc_dem.app.experiment_file import load_experiment
    from ooc_dem.app.experiment_setup import base_scenario

    f = tmp_path / "e.toml"
    text = "\n".join(ln for ln in SMALL.read_text().splitlines() if not ln.startswith("calibrated ="))
    f.write_text(text + "\n[calibration]\ngrains = 250\nsigmas = [1e3, 2e3, 4e3]\nevaluations = 2\n")
    exp = load_experiment(f)
    assert exp.dem.calibrated is None and exp.calibration.grains == 250
    said: list[str] = []
    ov, doc = ex.calibrated_overrides(exp, tmp_path / "out", said.append)
    assert doc["given"] is False and doc["targets"]["friction_angle"] == 30.0
    assert doc["targets"]["bulk_density"] == 1500.0 and doc["sample"]["grains"] == 250
    assert len(doc["evaluations"]) <= 2 and doc["soil_key"] == soil_key(base_scenario(exp))
    assert any(o.startswith("contact.soil_soil.friction=") for o in ov)
    assert any(o.startswith("bed.fill_friction=") for o in ov)
    mtime = (tmp_path / "out" / "calibration" / "calibration.json").stat().st_mtime_ns
    assert ex.calibrated_overrides(exp, tmp_path / "out", said.append)[0] == ov
    assert (tmp_path / "out" / "calibration" / "calibration.json").stat().st_mtime_ns == mtime
    assert any("reusing" in s for s in said)
    o = tmp_path / "o.toml"
    o.write_text(f.read_text().replace("r_min = 0.003", "r_min = 0.0029"))
    other = load_experiment(o)
    with pytest.raises(ex.ExperimentError, match="another soil"):
        ex.calibrated_overrides(other, tmp_path / "out", said.append)
