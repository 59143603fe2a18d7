"""The spread of a run's steady-window results (app/run_stats.py) and sweeps with error bars
(app/sweep_slip.py): known answers on synthetic series, the short-window flag and warning,
the table, and a tiny real sweep extended by a slip, reported and overlaid."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest

from ooc_dem.app.advice import scenario_warnings
from ooc_dem.app.run_stats import (
    SMOOTH_BLOCK_ANGLE,
    block_period,
    read_summary_with_spread,
    short_window_flag,
    steady_spread,
)
from ooc_dem.app.runfiles import read_csv
from ooc_dem.app.stats import t_quantile_975
from ooc_dem.app.sweep_slip import CSV_COLUMNS, CSV_NAME, FIGURE_NAME
from ooc_dem.app.tables import print_table
from ooc_dem.model.scenario import load_scenario
from support.cli import cli_in_process, one_line_error

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _series(sc, block_means, rows_per_block, start, amplitude=5.0):
    """Series columns whose rows from about ``start`` (s of travel; moved to a row's
    boundary) are, block j (one lug passage of ``rows_per_block`` rows), block_means[j] plus
    a sine of the passage period (which a whole block averages out), and 0 before; and the
    blocks' (start, end)."""
    period = block_period(sc)
    step = period / rows_per_block
    n_before = int(round(start / step))
    n = n_before + len(block_means) * rows_per_block
    t_end = step * np.arange(1, n + 1)
    phase = np.sin(2.0 * np.pi * (t_end - step) / period)
    net = np.zeros(n)
    for j, m in enumerate(block_means):
        a = n_before + j * rows_per_block
        net[a : a + rows_per_block] = m + amplitude * phase[a : a + rows_per_block]
    return {
        "t_travel": t_end,
        "slip": np.full(n, 0.2),
        "vx": np.full(n, 0.08),
        "net_traction": net,
        "gross_traction": net + 3.0,
        "torque": 0.1 * (net + 3.0),
        "vertical_force": np.full(n, 19.6),
        "sinkage": np.full(n, 0.02),
    }, (n_before * step, n * step)


def test_steady_spread_known_answer():
    """Five passages of means 1..5 (and a sine of the passage period on top): the mean 3,
    the interval t(4) sd(1..5) / sqrt(5); gross = net + 3 has the same spread, DP/W is
    net / load, the slip (constant) none."""
    sc = load_scenario("quick")  # 18 lugs, omega 1 rad/s: a passage is 2 pi / 18 s
    assert block_period(sc) == pytest.approx(2 * math.pi / 18)
    cols, (start, end) = _series(sc, [1.0, 2.0, 3.0, 4.0, 5.0], 40, 0.43)
    spread = steady_spread(cols, sc, (start, end))
    net = spread["net_traction"]
    half = t_quantile_975(4) * float(np.std([1, 2, 3, 4, 5], ddof=1)) / math.sqrt(5)
    assert net["blocks"] == 5 and net["passages"] == 5 and "flag" not in net
    assert net["mean"] == pytest.approx(3.0, abs=1e-12)
    assert net["ci95"] == pytest.approx(half, rel=1e-12)
    assert net["std"] > np.std([1, 2, 3, 4, 5])  # the rows' spread includes the sine
    assert net["block_s"] == pytest.approx(2 * math.pi / 18)
    assert net["stats_window_s"] == pytest.approx([start, end], abs=1e-9)
    gross = spread["gross_traction"]
    assert gross["mean"] == pytest.approx(6.0) and gross["ci95"] == pytest.approx(half, rel=1e-9)
    assert spread["motion_resistance"]["mean"] == pytest.approx(3.0)
    assert spread["motion_resistance"]["ci95"] == pytest.approx(0.0, abs=1e-9)
    assert spread["dp_w"]["mean"] == pytest.approx(3.0 / sc.wheel.load)
    assert spread["dp_w"]["ci95"] == pytest.approx(half / sc.wheel.load, rel=1e-12)
    assert spread["slip"]["std"] == pytest.approx(0.0, abs=1e-15) and spread["slip"]["ci95"] == pytest.approx(0.0)
    assert spread["travel_distance"]["std"] is None
    assert spread["travel_distance"]["mean"] == pytest.approx(0.08 * (end - start))
    json.dumps(spread, allow_nan=False)  # JSON-safe: no nan or inf


def test_short_window_is_flagged():
    """Two passages: flagged (an interval of 1 degree of freedom); under one passage: the
    rows' mean and std, no interval, no block."""
    sc = load_scenario("quick")
    cols, (start, end) = _series(sc, [1.0, 3.0], 40, 0.43)
    two = steady_spread(cols, sc, (start, end))["net_traction"]
    assert two["blocks"] == 2 and two["flag"] == "window shorter than 3 lug passages"
    assert two["ci95"] == pytest.approx(t_quantile_975(1) * math.sqrt(2.0) / math.sqrt(2))
    part = steady_spread(cols, sc, (start, start + 0.5 * block_period(sc)))["net_traction"]
    assert part["blocks"] == 0 and part["ci95"] is None and part["std"] is not None
    assert part["flag"] == "window shorter than 3 lug passages"


def test_a_smooth_wheel_has_blocks_of_a_fixed_turn():
    sc = load_scenario("quick", ["wheel.n_lugs=0", "wheel.omega=2"])
    assert block_period(sc) == pytest.approx(SMOOTH_BLOCK_ANGLE / 2.0)
    cols, (start, end) = _series(sc, [1.0, 2.0, 3.0, 4.0], 10, 0.43)
    net = steady_spread(cols, sc, (start, end))["net_traction"]
    assert net["blocks"] == 4 and net["passages"] is None and "flag" not in net
    assert short_window_flag(sc, 2) == "window shorter than 3 blocks"
    still = load_scenario("quick", ["wheel.omega=0"])
    assert math.isinf(block_period(still))
    assert steady_spread(cols, still, (start, end))["net_traction"]["blocks"] == 0


def test_short_window_warned_before_the_run():
    """A steady window cut to 0.17 s by the travel (under half a lug passage) is warned of;
    quick's own 1.57 s (4.5 passages) is not."""
    short = load_scenario("quick", ["wheel.travel_time=0.6"])
    got = [w for w in scenario_warnings(short) if "lug passages" in w]
    assert len(got) == 1 and "0.49 lug passages" in got[0] and "fewer than 3" in got[0], got
    assert not [w for w in scenario_warnings(load_scenario("quick")) if "lug passages" in w]
    cp = cli_in_process("check", "quick", "--set", "wheel.travel_time=0.6")
    assert cp.returncode == 0 and "0.49 lug passages" in cp.stderr


def test_table_shows_the_interval_and_dp_w():
    sc = load_scenario("quick")
    cols, (start, end) = _series(sc, [1.0, 2.0, 3.0, 4.0, 5.0], 40, 0.43)
    summary = {"scenario": "quick", "net_traction": {"steady": {"value": 3.0, "window_s": [start, end]}}}
    for key in ("slip", "gross_traction", "torque", "sinkage", "motion_resistance"):
        summary[key] = {"steady": {"value": 1.0, "window_s": [start, end]}}
    from ooc_dem.app.run_stats import summary_spread

    summary_spread(summary, cols, sc)
    text = print_table(summary)
    assert "3.000 ± 1.963" in text, text
    assert "DP/W (-)" in text and f"{3.0 / 19.6:.4f} ± " in text
    assert "5 lug passages" in text and "flagged" not in text
    summary["net_traction"]["steady"]["flag"] = "window shorter than 3 lug passages"
    assert "steady window flagged: window shorter than 3 lug passages" in print_table(summary)


# ------------------------------------------------------------------------- a real sweep

# a tiny rig: 300 discs, a 36-lug wheel at 8 rad/s (a passage every 21.8 ms), 0.1 s of
# travel, the steady window 0.02-0.1 s: 3 whole passages; a few seconds a run after compile
TINY = [
    "soil.n=300",
    "bin.length=0.35",
    "wheel.settle_time=0.02",
    "wheel.travel_time=0.1",
    "wheel.omega=8",
    "wheel.n_lugs=36",
    "output.steady_start=0.02",
    "output.steady_end=0.1",
    "output.series_interval=0.001",
]


def _sets(extra=()):
    return [a for kv in [*TINY, *extra] for a in ("--set", kv)]


def _sweep(out, slips, extra=()):
    return cli_in_process("sweep", "quick", *_sets(extra), "--slips", slips, "--out", out, "--no-progress")


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "a"
    cp = _sweep(out, "0.1,0.3")
    assert cp.returncode == 0, cp.stderr
    return out, cp


def test_sweep_writes_the_spread(tiny_sweep):
    out, cp = tiny_sweep
    assert "slip 0.100 (ran): drawbar pull" in cp.stdout and " ± " in cp.stdout
    cols = read_csv(out / CSV_NAME, CSV_COLUMNS)
    assert list(cols["slip"]) == [0.1, 0.3]
    assert np.isfinite(cols["drawbar_pull_ci95"]).all() and (cols["drawbar_pull_ci95"] > 0).all()
    assert list(cols["blocks"]) == [3, 3]
    for r, s in zip(json.loads((out / "sweep.json").read_text())["rows"], (0.1, 0.3)):
        summary = json.loads((out / f"slip_{s:.3f}" / "summary.json").read_text())
        steady = summary["net_traction"]["steady"]
        # the curve's drawbar pull is the step accumulator's steady mean, bit for bit
        assert r["drawbar_pull"] == steady["value"] and r["drawbar_pull_ci95"] == steady["ci95"]
        assert summary["dp_w"]["steady"]["value"] == steady["value"] / 19.6
        assert cols["dp_w"][[0.1, 0.3].index(s)] == pytest.approx(steady["value"] / 19.6, rel=1e-15)
    assert (out / FIGURE_NAME).read_bytes()[:8] == PNG_MAGIC


def test_sweep_extended_reported_and_overlaid(tiny_sweep, tmp_path):
    base, _ = tiny_sweep
    out = tmp_path / "a"
    shutil.copytree(base, out)
    before = (out / "slip_0.100" / "summary.json").read_bytes()
    cp = _sweep(out, "0.2,0.1")
    assert cp.returncode == 0, cp.stderr
    assert "slip 0.100 (reused)" in cp.stdout and "slip 0.200 (ran)" in cp.stdout
    assert (out / "slip_0.100" / "summary.json").read_bytes() == before  # not run again
    cols = read_csv(out / CSV_NAME, CSV_COLUMNS)
    assert list(cols["slip"]) == [0.1, 0.2, 0.3]
    assert json.loads((out / "sweep.json").read_text())["slips"] == [0.1, 0.3, 0.2]

    # report on the sweep: the curve written again, the table printed
    (out / FIGURE_NAME).unlink()
    (out / CSV_NAME).unlink()
    cp = cli_in_process("report", out)
    assert cp.returncode == 0, cp.stderr
    assert "Drawbar pull – slip — quick" in cp.stdout and "0.200" in cp.stdout and " ± " in cp.stdout
    assert (out / FIGURE_NAME).read_bytes()[:8] == PNG_MAGIC
    assert list(read_csv(out / CSV_NAME, CSV_COLUMNS)["slip"]) == [0.1, 0.2, 0.3]

    # another scenario (a shorter steady window) is refused in one line, nothing run
    one_line_error(_sweep(out, "0.4", ["output.steady_start=0.05"]), "another scenario", "--out")
    assert not (out / "slip_0.400").exists()

    # which, as its own sweep, is flagged (2 passages) and warned of, and overlays with the first
    short = tmp_path / "short"
    cp = _sweep(short, "0.1", ["output.steady_start=0.05"])
    assert cp.returncode == 0, cp.stderr
    assert "2.29 lug passages" in cp.stderr
    summary = json.loads((short / "slip_0.100" / "summary.json").read_text())
    assert summary["net_traction"]["steady"]["flag"] == "window shorter than 3 lug passages"
    cp = cli_in_process("report", out, short, "--out", tmp_path / "overlay.png")
    assert cp.returncode == 0, cp.stderr
    assert "window shorter than 3 lug passages" in cp.stdout
    assert (tmp_path / "overlay.png").read_bytes()[:8] == PNG_MAGIC
    one_line_error(cli_in_process("report", out, short), "--out")
    one_line_error(cli_in_process("report", out, out / "slip_0.100", "--out", tmp_path / "o.png"), "not a sweep")


def test_a_run_made_before_the_spread_gets_it_from_its_series(tiny_sweep, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(tiny_sweep[0] / "slip_0.100", run)
    summary = json.loads((run / "summary.json").read_text())
    fresh = summary["net_traction"]["steady"]
    old = json.loads(json.dumps(summary))
    del old["dp_w"]
    for entry in old.values():
        if isinstance(entry, dict) and isinstance(entry.get("steady"), dict):
            entry["steady"] = {k: entry["steady"][k] for k in ("value", "window_s") if k in entry["steady"]}
    (run / "summary.json").write_text(json.dumps(old))
    got = read_summary_with_spread(run)["net_traction"]["steady"]
    assert got["blocks"] == fresh["blocks"]
    # series.csv keeps 10 significant digits
    assert got["ci95"] == pytest.approx(fresh["ci95"], rel=1e-8)
    cp = cli_in_process("report", run)
    assert cp.returncode == 0 and " ± " in cp.stdout and "DP/W" in cp.stdout, cp.stderr


def test_a_foreign_sweep_file_is_one_line(tmp_path):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "sweep.json").write_text('{"scenario": "quick", "slips": ["fast"]}')
    one_line_error(cli_in_process("report", bad), "sweep.json", "slips")
    one_line_error(_sweep(bad, "0.1"), "sweep.json", "slips")
