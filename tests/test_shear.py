"""The direct shear box (app/shear.py, `ooc-dem shear`): the Mohr-Coulomb fit, the box of
plates, and known answers on small 2D samples."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from support.cli import cli_in_process, one_line_error
from ooc_dem.app.shear import ShearError, ShearOptions, box_plates, mohr_coulomb, run_shear
from ooc_dem.model.scenario import load_scenario
from ooc_dem.physics.layout import AX_X, AX_Y, AX_Z, PLATE_FORCE

FRICTIONLESS = ["contact.soil_soil.friction=0", "contact.soil_soil.rolling_friction=0"]  # the box is frictionless
FAST = {"inertial": 5e-3}  # I = 5e-3 at the smallest stress: quasi-static enough for these checks


def test_mohr_coulomb_fit_is_least_squares_with_its_standard_errors():
    """The fit's line and standard errors are scipy's linregress's; an exact line has zero
    errors; two points give the line and no errors."""
    from scipy.stats import linregress

    sigma = [5e3, 10e3, 20e3, 40e3]
    tau = [4.1e3, 6.2e3, 12.9e3, 24.0e3]
    fit = mohr_coulomb(sigma, tau)
    ref = linregress(sigma, tau)
    assert fit["tan_phi"] == pytest.approx(ref.slope, rel=1e-12)
    assert fit["c"] == pytest.approx(ref.intercept, rel=1e-9)
    assert fit["tan_phi_se"] == pytest.approx(ref.stderr, rel=1e-9)
    assert fit["c_se"] == pytest.approx(ref.intercept_stderr, rel=1e-9)
    assert fit["phi_deg"] == pytest.approx(math.degrees(math.atan(ref.slope)), rel=1e-12)
    assert fit["phi_se_deg"] == pytest.approx(math.degrees(ref.stderr / (1 + ref.slope**2)), rel=1e-9)
    exact = mohr_coulomb([1e3, 2e3, 4e3], [1500.0, 2000.0, 3000.0])
    assert exact["c"] == pytest.approx(1000.0) and exact["tan_phi"] == pytest.approx(0.5)
    assert exact["c_se"] == pytest.approx(0.0, abs=1e-9) and exact["r2"] == pytest.approx(1.0)
    two = mohr_coulomb([1e3, 2e3], [1500.0, 2000.0])
    assert two["c_se"] is None and two["phi_se_deg"] is None
    with pytest.raises(ShearError, match="distinct"):
        mohr_coulomb([1e3, 1e3], [1.0, 2.0])


@pytest.mark.parametrize("dim", [2, 3])
def test_the_split_box_is_made_of_plates(dim):
    """The box: the lower half's end faces and the top face of its right wall, the upper
    half's end faces, the bottom face of its left wall and the force-controlled lid (3D: each
    half's side faces too); the upper half's rows are the ones that move."""
    from ooc_dem.app.shear import Box

    box = Box(dim=dim, length=0.1, width=0.1, split=0.02, lid=0.045, top=0.2, d_mean=0.004, r_max=0.0022)
    pl = box_plates(box, travel=0.01, load=50.0, mass=0.1, vmax=0.05)
    t = pl.table
    assert len(t) == (7 if dim == 2 else 11)
    assert t[pl.lid]["axis"] == AX_Y and t[pl.lid]["side"] == -1 and t[pl.lid]["mode"] == PLATE_FORCE
    assert t[pl.lid]["load"] == 50.0 and t[pl.lid]["mass"] == 0.1
    assert pl.lid in pl.upper
    ends = [k for k in range(len(t)) if t[k]["axis"] == AX_X]
    assert len(ends) == 4 and len([k for k in ends if k in pl.upper]) == 2
    # the faces meet at the split: the lower end faces reach it, the upper ones start there
    for k in ends:
        assert (t[k]["lo1"] == 0.02) if k in pl.upper else (t[k]["hi1"] == 0.02)
    # the corner faces cover the travel
    horizontal = [k for k in range(len(t)) if t[k]["axis"] == AX_Y and k != pl.lid]
    assert all(t[k]["hi1"] - t[k]["lo1"] > 0.01 for k in horizontal)
    assert len([k for k in range(len(t)) if t[k]["axis"] == AX_Z]) == (0 if dim == 2 else 4)


def test_options_are_checked():
    for bad, match in (
        (ShearOptions(sigmas=(1e4,)), ">= 2"),
        (ShearOptions(sigmas=(1e4, 1e4)), "distinct"),
        (ShearOptions(sigmas=(1e4, -1.0)), "finite stress"),
        (ShearOptions(displacement=0.9), "displacement"),
    ):
        with pytest.raises(ShearError, match=match):
            bad.check()


def test_frictionless_grains_have_a_low_friction_angle():
    """Frictionless, cohesionless discs: the residual friction angle is low. Known value:
    the quasi-static internal friction of frictionless grains, tan(phi) ~ 0.1 (phi ~ 6 deg;
    Peyneau & Roux 2008, PRE 78 011307, for spheres; frictionless discs are reported near
    it); checked as phi_residual = 6 +- 6 deg (in [0, 12] deg: 400 grains fluctuate;
    measured 9.0 +- 0.6), and the same sample with the quick soil's friction (mu = 0.5,
    rolling 0.1) well above it (> 15 deg; measured 22.1 +- 0.6)."""
    opts = ShearOptions(grains=400, displacement=0.15, **FAST)
    smooth = run_shear(load_scenario("quick", FRICTIONLESS), opts)
    rough = run_shear(load_scenario("quick"), opts)
    phi0 = smooth["residual_fit"]["phi_deg"]
    phi1 = rough["residual_fit"]["phi_deg"]
    assert 0.0 <= phi0 <= 12.0, smooth["residual_fit"]
    assert phi1 > 15.0, rough["residual_fit"]
    for t in smooth["tests"]:
        # the lid held its stress: the mean over the residual window within 5 % of sigma on
        # the corrected area (the area shrinks by up to 15 %)
        u = t["series"]["displacement"][-1]
        assert t["residual"]["sigma"] == pytest.approx(t["sigma"] / (1 - 0.875 * u / smooth["box"]["length"]), rel=0.05)
        assert t["inertial_number"] <= 5e-3 + 1e-12


def test_doubling_the_cohesion_raises_c():
    """The cohesion of the Mohr-Coulomb fit grows with the grains' cohesion (simplified JKR,
    k_c doubled from 2e5 to 4e5 J/m^3 on the same poured sample): c of the peak fit, by more
    than the two fits' standard errors together (measured: 7.4 +- 1.6 kPa, 18.6 +- 0.6 kPa;
    cohesionless 0.2 +- 0.05 kPa)."""
    opts = ShearOptions(grains=400, displacement=0.15, **FAST)
    fits = [
        run_shear(load_scenario("quick", [f"contact.soil_soil.cohesion={kc}"]), opts)["peak_fit"] for kc in (2e5, 4e5)
    ]
    assert fits[1]["c"] - fits[0]["c"] > fits[0]["c_se"] + fits[1]["c_se"], fits


def test_cli_shear_writes_the_report_and_figures(tmp_path):
    out = tmp_path / "shear"
    cp = cli_in_process(
        "shear", "quick", "--grains", "150", "--sigma", "5e3,10e3,20e3", "--inertial", "5e-3",
        "--displacement", "0.05", "--out", out, "--no-progress",
    )  # fmt: skip
    assert cp.returncode == 0, cp.stderr
    assert "peak: c =" in cp.stdout and "residual: c =" in cp.stdout
    doc = json.loads((out / "shear.json").read_text())
    assert [t["sigma"] for t in doc["tests"]] == [5e3, 10e3, 20e3]
    assert doc["grains"] == 150 and doc["dim"] == 2
    for t in doc["tests"]:
        s = t["series"]
        assert len(s["displacement"]) == len(s["tau"]) == len(s["sigma"]) == len(s["dilation"]) > 10
        assert np.all(np.diff(s["displacement"]) > 0)
    for f in ("shear_tau_displacement.png", "shear_mohr_coulomb.png"):
        assert (out / "figures" / f).stat().st_size > 1000
    # the same test again gives the same bits (a poured sample, cached or not, is the same)
    again = run_shear(
        load_scenario("quick"), ShearOptions(grains=150, inertial=5e-3, displacement=0.05), use_cache=False
    )
    assert again["tests"] == doc["tests"]


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--sigma", "5e3"], ">= 2"),
        (["--sigma", "5e3,abc"], "--sigma"),
        (["--sigma", "5e3,-1"], "finite stress"),
        (["--displacement", "0.8"], "--displacement"),
        (["--set", "soil.n=-3"], "soil.n"),
    ],
)
def test_cli_shear_refuses_bad_input(tmp_path, args, needle):
    cp = cli_in_process("shear", "quick", "--out", tmp_path / "o", "--no-progress", *args)
    one_line_error(cp, needle)


def test_3d_box_shears_spheres():
    """3D: the same box with its side faces, on quick-3d's spheres (Hertz-Mindlin, mu = 0.5,
    rolling 0.1): the lid holds each stress and the residual friction angle is a frictional
    soil's (measured 35 deg with 1000 spheres; here 400, checked in [20, 50] deg)."""
    res = run_shear(load_scenario("quick-3d"), ShearOptions(grains=400, displacement=0.08, **FAST))
    assert res["dim"] == 3 and res["box"]["width"] == res["box"]["length"]
    assert 20.0 <= res["residual_fit"]["phi_deg"] <= 50.0, res["residual_fit"]
    for t in res["tests"]:
        assert t["residual"]["sigma"] == pytest.approx(t["sigma"] / (1 - 0.07), rel=0.05)
