"""`ooc-dem calibrate` (app/calibrate.py): from a lab sheet to the scenario's soil values.

The search is checked for what it promises: every value it reports was measured, the chosen
values are those of the evaluation nearest the targets, the fragment it writes is the
overrides it returns, and `ooc-dem shear` run with that fragment on the same grains measures
the same friction angle and cohesion, bit for bit."""

from __future__ import annotations

import json
import math
import tomllib

import pytest

from support.cli import cli_in_process, one_line_error
from ooc_dem.app.calibrate import (
    CalibrationError,
    LabSoil,
    calibration_lines,
    cohesion_guess,
    fragment_toml,
    read_calibration,
)
from ooc_dem.model.scenario import load_scenario


def test_cohesion_guess_is_rumpf_over_the_hertz_contact_area():
    """k = F / (pi r delta): the bond F = c pi d^2 / (phi_s Z tan(phi)) over the lens of the
    mean contact force's Hertz overlap (R* = r / 2), computed here by hand."""
    from ooc_dem.model.contacts import contact_table_3d
    from ooc_dem.physics.layout import T_SOIL

    sc = load_scenario("paper2008-3d")
    r = 0.5 * (sc.soil.r_min + sc.soil.r_max)
    d = 2 * r
    sigma, phi, c, solid = 6e3, 32.0, 250.0, 0.6
    estar = float(contact_table_3d(sc)[T_SOIL, T_SOIL]["estar"])
    force = sigma * math.pi * d * d / (solid * 6.0)
    delta = (3 * force / (4 * estar * math.sqrt(r / 2))) ** (2 / 3)
    bond = c * math.pi * d * d / (solid * 6.0 * math.tan(math.radians(phi)))
    assert cohesion_guess(sc, sigma, phi, c, solid) == pytest.approx(bond / (math.pi * r * delta), rel=1e-12)
    assert cohesion_guess(sc, sigma, phi, 2 * c, solid) == pytest.approx(2 * cohesion_guess(sc, sigma, phi, c, solid))


def test_the_fragment_is_the_overrides_as_toml():
    result = {
        "scenario": "quick",
        "targets": {"friction_angle": 30.0, "cohesion": 250.0, "bulk_density": 1600.0},
        "achieved": {"friction_angle": 30.2, "cohesion": 240.0, "bulk_density": 1590.0},
        "options": {"envelope": "peak", "sigmas": [3e3, 6e3]},
        "overrides": ["contact.soil_soil.friction=0.41", "contact.soil_soil.cohesion=72000.5", "bed.fill_friction=0.1"],
    }
    data = tomllib.loads(fragment_toml(result))
    assert data == {"contact": {"soil_soil": {"friction": 0.41, "cohesion": 72000.5}}, "bed": {"fill_friction": 0.1}}


@pytest.mark.parametrize(
    "args, words",
    [
        (["--friction-angle", "75"], "friction angle"),
        (["--friction-angle", "30", "--grains", "100"], "--grains"),
        (["--friction-angle", "30", "--sigma", "3e3"], "--sigma"),
        (["--friction-angle", "30", "--sigma", "3e3,x"], "--sigma"),
        (["--friction-angle", "30", "--evaluations", "1"], "--evaluations"),
        (["--friction-angle", "30", "--cohesion", "-5"], "--cohesion"),
        (["--friction-angle", "30", "--vary", "restitution"], "--vary"),
    ],
)
def test_calibrate_refuses_bad_targets_and_options_in_one_line(tmp_path, args, words):
    cp = cli_in_process("calibrate", "quick", *args, "--out", tmp_path / "c")
    one_line_error(cp, words)
    assert not (tmp_path / "c").exists()


def test_calibrate_refuses_an_occupied_out_and_reads_only_calibrations(tmp_path):
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "keep.txt").write_text("mine")
    cp = cli_in_process("calibrate", "quick", "--friction-angle", "30", "--out", tmp_path / "c")
    one_line_error(cp, "not empty")
    assert (tmp_path / "c" / "keep.txt").read_text() == "mine"
    assert read_calibration(tmp_path / "c") is None
    (tmp_path / "c" / "calibration.json").write_text("[1, 2]")
    with pytest.raises(CalibrationError, match="not a calibration"):
        read_calibration(tmp_path / "c")
    with pytest.raises(CalibrationError, match="friction angle"):
        LabSoil(friction_angle=0.0).check()


@pytest.mark.slow
def test_calibrate_chooses_the_nearest_measured_test_and_shear_reproduces_it(tmp_path):
    """A 2D soil calibrated with three shear tests: the chosen values are the test nearest
    the targets, its fit is the achieved result, the fragment holds the overrides, and
    `ooc-dem shear` run with them on the same grains and stresses gives the same fit."""
    out = tmp_path / "cal"
    grains, sigmas = 300, "2e3,4e3,8e3"
    cp = cli_in_process(
        "calibrate",
        "quick",
        "--friction-angle",
        "22",
        "--grains",
        grains,
        "--sigma",
        sigmas,
        "--evaluations",
        "3",
        "--no-progress",
        "--out",
        out,
        check=True,
    )
    result = read_calibration(out)
    assert result is not None
    evs = result["evaluations"]
    assert 1 <= len(evs) <= 3
    misses = [abs(e["phi_deg"] - 22.0) for e in evs]
    assert result["chosen"] == misses.index(min(misses))
    best = evs[result["chosen"]]
    assert result["achieved"]["friction_angle"] == best["phi_deg"]
    assert result["achieved"]["cohesion"] == best["c"]
    assert result["errors"]["friction_angle_deg"] == best["phi_deg"] - 22.0
    assert evs[0]["friction"] == load_scenario("quick").contact.soil_soil.friction  # the search starts there
    fragment = tomllib.loads((out / "calibrated.toml").read_text())
    assert fragment["contact"]["soil_soil"]["friction"] == best["friction"]
    assert "bed" in fragment and "fill_friction" in fragment["bed"]
    assert (out / "shear" / "shear.json").is_file()
    assert (out / "shear" / "figures" / "shear_mohr_coulomb.png").stat().st_size > 0
    assert any(line.startswith("friction angle") for line in calibration_lines(result))
    assert "set: contact.soil_soil.friction=" in cp.stdout

    sets = [a for o in result["overrides"] for a in ("--set", o)]
    cli_in_process(
        "shear",
        "quick",
        *sets,
        "--grains",
        grains,
        "--sigma",
        sigmas,
        "--no-figures",
        "--no-progress",
        "--out",
        tmp_path / "check",
        check=True,
    )
    fit = json.loads((tmp_path / "check" / "shear.json").read_text())["peak_fit"]
    assert fit["phi_deg"] == best["phi_deg"] and fit["c"] == best["c"]


@pytest.mark.slow
def test_calibrate_can_search_the_rolling_friction_instead(tmp_path):
    """--vary rolling_friction: the friction stays the scenario's in every test, the rolling
    friction moves and is the value written."""
    out = tmp_path / "cal"
    cli_in_process(
        "calibrate",
        "quick",
        "--friction-angle",
        "30",
        "--grains",
        300,
        "--sigma",
        "2e3,4e3,8e3",
        "--evaluations",
        "2",
        "--vary",
        "rolling_friction",
        "--no-progress",
        "--out",
        out,
        check=True,
    )
    result = read_calibration(out)
    assert result is not None
    quick = load_scenario("quick").contact.soil_soil
    assert [e["friction"] for e in result["evaluations"]] == [quick.friction] * len(result["evaluations"])
    assert result["evaluations"][0]["rolling_friction"] == quick.rolling_friction
    best = result["evaluations"][result["chosen"]]
    assert f"contact.soil_soil.rolling_friction={best['rolling_friction']!r}" in result["overrides"]
    assert not any(o.startswith("contact.soil_soil.friction=") for o in result["overrides"])


def test_friction_step_brackets_a_noisy_flat_friction_angle():
    """The shear tests of a loose sample (grain density 2900 kg/m^3, a sensitivity run of
    the Ding soil): phi 34.22 deg at mu 0.5 but 34.48 at 0.458 (noise: phi is flat in mu
    there), so a secant through them steps up, away from the 31.9 deg target. The bracketed
    step goes down, faster while the tests stay above, and inside the bracket once one
    is below."""
    from ooc_dem.app.calibrate import friction_step

    def tan(deg):
        return math.tan(math.radians(deg))

    target = tan(31.9)
    tested = [(0.5, tan(34.2222)), (0.4576, tan(34.4796))]
    x = friction_step(tested, target)
    assert x < 0.4576 * target / tan(34.4796) < 0.4576  # down, and by more than one ratio
    tested.append((0.01, tan(10.03)))
    x = friction_step(tested, target)
    assert 0.01 + 0.1 * 0.4476 <= x <= 0.4576 - 0.1 * 0.4476
    # noise inverts the bracket (a test below the target at a higher mu): bisect it
    assert friction_step([(0.3, tan(33.0)), (0.35, tan(31.0))], target) == pytest.approx(0.325, rel=1e-12)
    # regula falsi landing near an end of the bracket: bisect instead
    assert friction_step([(0.5, tan(40.0)), (0.1, tan(31.89))], target) == pytest.approx(0.3, rel=1e-12)


def test_friction_step_converges_on_a_monotone_angle():
    """phi(mu) rising steeply then flat (as the shear tests show), from the scenario's 0.5
    and the search's proportional first step: within the search's 0.5 deg of the target
    in at most 8 tests (the default), for a flat and a gentler curve."""
    from ooc_dem.app.calibrate import friction_step

    for phi in (
        lambda m: 10.0 + 26.0 * (1.0 - math.exp(-m / 0.08)),
        lambda m: 15.0 + 30.0 * (1.0 - math.exp(-m / 0.25)),
    ):
        target = math.tan(math.radians(31.9))
        tested = [(0.5, math.tan(math.radians(phi(0.5))))]
        x = 0.5 * target / tested[0][1]
        for _ in range(7):
            tested.append((x, math.tan(math.radians(phi(x)))))
            if abs(phi(x) - 31.9) < 0.5:
                break
            x = min(max(friction_step(tested, target, 0.01), 0.01), 3.0)
        assert abs(phi(tested[-1][0]) - 31.9) < 0.5, tested
