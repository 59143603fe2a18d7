"""The paper's rig: outputs, sign conventions, drawbar pull - slip curve."""

import json

import numpy as np
import pytest

from support.cli import run_cli
from support.runs import WHEEL_TEST

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow


def _settings(extra=()):
    out = []
    for s in [*WHEEL_TEST, *extra]:
        out += ["--set", s]
    return out


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """The README's main job, exactly: `ooc-dem run quick --out DIR`."""
    out = tmp_path_factory.mktemp("quick") / "run"
    cp = run_cli("run", "quick", "--out", out, check=True)
    return out, cp


def test_quick_outputs(quick_run):
    out, cp = quick_run
    assert "wheel slip" in cp.stdout and "state hash" in cp.stdout
    for f in (
        "series.csv",
        "summary.json",
        "initial.npz",
        "scenario.toml",
        "MANIFEST.json",
        "figures/series.png",
        "figures/deformation.png",
        "figures/displacement.png",
    ):
        assert (out / f).is_file(), f
        assert (out / f).stat().st_size > 0, f
    for png in (out / "figures").glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert png.stat().st_size > 10_000
    s = json.loads((out / "summary.json").read_text())
    units = {"slip": "-", "net_traction": "N", "gross_traction": "N", "sinkage": "m"}
    for key, unit in units.items():
        assert s[key]["unit"] == unit
        for win in ("whole_travel", "steady"):
            assert isinstance(s[key][win]["value"], float)
            a, b = s[key][win]["window_s"]
            assert 0 <= a < b
    assert s["slip"]["whole_travel"]["window_s"] == [0.0, 2.0]
    assert s["slip"]["steady"]["window_s"] == [0.43, 2.0]
    rows = np.genfromtxt(out / "series.csv", delimiter=",", skip_header=1)
    assert rows.shape[1] == 13 and len(rows) > 300
    # the wheel digs in and moves
    assert s["sinkage"]["steady"]["value"] > 0.005
    assert s["travel_distance"]["whole_travel"]["value"] > 0.02


def test_net_traction_balances_drawbar_load(quick_run):
    """Steady motion: mean net traction = drawbar load (10 N) within 5 %."""
    out, _ = quick_run
    s = json.loads((out / "summary.json").read_text())
    assert abs(s["net_traction"]["steady"]["value"] - 10.0) < 0.5
    # gross traction exceeds net traction by the motion resistance (> 0)
    assert s["gross_traction"]["steady"]["value"] > s["net_traction"]["steady"]["value"]
    assert 0.0 < s["slip"]["steady"]["value"] < 1.0


def test_report_regenerates(quick_run):
    out, _ = quick_run
    (out / "figures" / "series.png").unlink()
    cp = run_cli("report", out, check=True)
    assert "net traction" in cp.stdout and (out / "figures" / "series.png").is_file()


def test_slip_sign_and_drawbar_dependence(tmp_path):
    """Zero drawbar load: slip near 0 and net traction near 0; a 10 N load raises slip a lot."""
    res = {}
    for load in (0.0, 10.0):
        out = tmp_path / f"d{load:g}"
        run_cli(
            "run",
            "quick",
            "--out",
            out,
            "--no-figures",
            "--no-progress",
            *_settings([f"wheel.drawbar_load={load}"]),
            check=True,
        )
        res[load] = json.loads((out / "summary.json").read_text())
    s0 = res[0.0]["slip"]["steady"]["value"]
    s10 = res[10.0]["slip"]["steady"]["value"]
    assert abs(s0) < 0.15, s0
    assert abs(res[0.0]["net_traction"]["steady"]["value"]) < 1.0
    assert s10 > s0 + 0.3, (s0, s10)
    assert abs(res[10.0]["net_traction"]["steady"]["value"] - 10.0) < 1.5


def test_sweep_drawbar_pull_increases_with_slip(tmp_path):
    out = tmp_path / "sweep"
    run_cli("sweep", "quick", *_settings(), "--slips", "0.05,0.3,0.6", "--out", out, "--no-progress", check=True)
    data = np.genfromtxt(out / "drawbar_pull_slip.csv", delimiter=",", names=True)
    assert list(data["slip"]) == [0.05, 0.3, 0.6]
    assert np.all(np.diff(data["drawbar_pull"]) > 0), data["drawbar_pull"]
    assert (out / "drawbar_pull_slip.png").read_bytes()[:4] == b"\x89PNG"


def test_windows_of_a_run_stopped_early_say_what_they_cover():
    """`--duration` shorter than the travel: the windows end where the records do, not at
    the scenario's travel_time (the table's header and summary.json would claim 0–2 s)."""
    from ooc_dem.app.metrics import WheelMetrics
    from ooc_dem.physics.layout import N_REC, REC_T, REC_X
    from ooc_dem.model.scenario import load_scenario

    sc = load_scenario("quick")
    dt = sc.physics.dt
    steps = int(round((sc.wheel.settle_time + 0.5) / dt))  # 0.5 s of the 2 s travel
    rec = np.zeros((steps, N_REC))
    rec[:, REC_T] = np.arange(steps) * dt
    rec[:, REC_X] = np.arange(steps) * 1e-6
    m = WheelMetrics(sc, surface=0.0, total_steps=steps)
    m.add(rec, 0)
    s = m.summary()
    a, b = s["slip"]["whole_travel"]["window_s"]
    assert a == 0.0 and abs(b - 0.5) <= 2 * dt
    a, b = s["slip"]["steady"]["window_s"]
    assert a == pytest.approx(sc.output.steady_start) and abs(b - 0.5) <= 2 * dt
    # a run that covers its whole travel keeps the scenario's bounds exactly
    full = int(round((sc.wheel.settle_time + sc.wheel.travel_time) / dt))
    rec = np.zeros((full, N_REC))
    rec[:, REC_T] = np.arange(full) * dt
    m = WheelMetrics(sc, surface=0.0, total_steps=full)
    m.add(rec, 0)
    assert m.summary()["slip"]["whole_travel"]["window_s"] == [0.0, sc.wheel.travel_time]
