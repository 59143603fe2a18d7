"""`check` and `run` warn (stderr, exit 0) of a scenario that passes every check but will not
measure what it should (app/advice.py); and docs/cli.md is current. All fast: no stepping."""

import json
from pathlib import Path

import pytest

from ooc_dem.app.advice import bed_depth, scenario_warnings
from ooc_dem.app.plan import RunOptions, plan_run
from ooc_dem.model.scenario import load_scenario, scenario_tables
from support.cli import cli_in_process, error_lines

ROOT = Path(__file__).resolve().parent.parent
WARNING = "ooc-dem: warning: "


def _warnings(stderr: str) -> list[str]:
    return [ln[len(WARNING) :] for ln in stderr.splitlines() if ln.startswith(WARNING)]


def _checked(*args) -> list[str]:
    cp = cli_in_process("check", *args)
    assert cp.returncode == 0, cp.stderr
    json.loads(cp.stdout)  # stdout stays the plan
    assert error_lines(cp.stderr) == [], cp.stderr
    return _warnings(cp.stderr)


@pytest.fixture
def partial(tmp_path):
    """A 3D file that sets only the dimension (and a time step the 2D contacts allow in 3D):
    the rest is paper2008's 2D bin, discs and wheel, a bed of 6986 small spheres some 6.5 mm
    deep under a wheel as wide as the bin."""
    f = tmp_path / "partial.toml"
    f.write_text("[physics]\ndim = 3\ndt = 5e-6\n", encoding="utf-8")
    return f


def test_the_partial_3d_file_is_warned_of(partial):
    got = _checked(partial)
    assert any(w.startswith("bed about 6.") and "expected sinkage" in w and "0.3 wheel.radius" in w for w in got), got
    assert any(w.startswith("side walls 0 mm") and "zone of influence" in w and "bin.width >= 0.35" in w for w in got)
    assert any('base = "quick-3d"' in w and "soil.n" in w and "bin.width" in w for w in got), got


def test_a_base_file_is_not_told_to_name_a_base(tmp_path):
    f = tmp_path / "wide.toml"
    f.write_text('base = "quick-3d"\n[bin]\nwidth = 0.3\n', encoding="utf-8")
    got = _checked(f)
    assert not any("base =" in w for w in got) and not any(w.startswith("side walls") for w in got), got


def test_3d_keys_in_a_2d_file(tmp_path):
    f = tmp_path / "flat.toml"
    f.write_text("[bin]\nwidth = 0.3\n", encoding="utf-8")
    got = _checked(f)
    assert any("bin.width" in w and "physics.dim is not set" in w for w in got), got


def test_the_2d_builtins_are_quiet():
    for name in ("quick", "paper2008", "bed", "repose2d"):
        assert _checked(name) == [], name


def test_the_narrow_3d_builtins_say_so():
    got = _checked("quick-3d")
    assert any(w.startswith("side walls 30 mm") for w in got), got
    assert any("1.0 mean grain diameters" in w for w in got), got  # 10 mm lugs, 10 mm spheres


def test_steady_window_past_the_travel():
    got = _checked("quick", "--set", "wheel.travel_time=0.3")
    assert any("steady window" in w and "0.43 .. 2" in w for w in got), got
    got = _checked("quick", "--set", "wheel.travel_time=1.0")
    assert any("cover only 0.57 s" in w for w in got), got


def test_control_keys_the_control_ignores():
    got = _checked("quick", "--set", "wheel.torque=2.0", "--set", "wheel.speed=0.1")
    line = "wheel.torque = 2.0, wheel.speed = 0.1: have no effect with wheel.control = 'drawbar'"
    assert any(w.startswith(line) for w in got), got
    got = _checked("quick", "--set", "wheel.control=torque", "--set", "wheel.speed=0.1")
    assert any(w.startswith("wheel.speed = 0.1: has no effect with wheel.control = 'torque'") for w in got), got
    for ok in (
        ["wheel.control=torque", "wheel.torque=2.0", "wheel.carriage=speed", "wheel.speed=0.1"],
        ["wheel.control=towed", "wheel.speed=0.1", "wheel.inertia=0.02"],
    ):
        got = _checked("quick", *[a for o in ok for a in ("--set", o)])
        assert not any("no effect with wheel.control" in w for w in got), got


def test_out_of_core_with_k_1_gets_a_k():
    got = _checked("quick", "--mode", "ooc", "--domains", "2", "--block", "1")
    assert any("K = 1" in w and "--block 2" in w for w in got), got
    got = _checked("quick", "--mode", "ooc", "--domains", "6")  # slabs too narrow for K > 1
    assert any("K = 1" in w and "--domains 2 --block 2" in w for w in got), got
    assert not any("K = 1" in w for w in _checked("quick", "--mode", "ooc", "--domains", "2"))


def test_shallow_bed_and_short_lugs(tmp_path):
    got = _checked("quick", "--set", "soil.n=300")
    assert any(w.startswith("bed about 11.") and "soil.n >= 1" in w for w in got), got
    got = _checked("quick", "--set", "soil.r_min=0.004", "--set", "soil.r_max=0.0045", "--set", "soil.n=400")
    assert any("mean grain diameters" in w for w in got), got


def test_bed_depth_estimate_matches_the_builtins():
    # paper2008's bed is ~0.18 m deep, paper2008-3d's ~7 cm (their scenario files)
    assert 0.17 < bed_depth(load_scenario("paper2008")) < 0.19
    assert 0.065 < bed_depth(load_scenario("paper2008-3d")) < 0.08


def test_run_prints_the_warnings_before_it_starts(partial, tmp_path):
    out = tmp_path / "taken"
    out.mkdir()
    (out / "something").write_text("x")
    cp = cli_in_process("run", partial, "--out", out)  # refused at the start: nothing runs
    assert cp.returncode == 2
    assert len(error_lines(cp.stderr)) == 1 and "not empty" in error_lines(cp.stderr)[0]
    sc = load_scenario(partial)
    tables, base = scenario_tables(partial)
    want = scenario_warnings(sc, plan_run(sc, RunOptions()), tables, base)
    assert _warnings(cp.stderr) == want and len(want) == 3
    assert cp.stderr.index(WARNING) < cp.stderr.index("ooc-dem: error:")


def test_check_estimates_the_wall_time_by_its_stated_cost_model():
    """`check` prints the run's estimated wall time: particles x steps x the fitted ns of the
    dimension and law, with the basis named."""
    import json

    from ooc_dem.app.plan import COST_NS

    cp = cli_in_process("check", "quick", "--steps", "1000")
    assert cp.returncode == 0, cp.stderr
    est = json.loads(cp.stdout)["estimated_wall_time"]
    assert est["seconds"] == round(1500 * 1000 * COST_NS[(2, "linear")] * 1e-9, 1)
    assert "fitted cost model" in est["basis"] and "docs/benchmarks.md" in est["basis"]


def test_check_prints_derived_numbers_without_float_noise():
    """steps x dt is 46.00000000000001 s in binary; `check` prints what a person reads."""
    import json

    cp = cli_in_process("check", "paper2008-3d")
    assert cp.returncode == 0, cp.stderr
    plan = json.loads(cp.stdout)
    assert plan["simulated_time_s"] == 46.0 and "46.0," in cp.stdout
    assert len(repr(plan["dt_critical_s"]).replace("e-05", "")) <= 14
