"""repose3d: the angle-of-repose measurement on synthetic cones of known angle,
the [repose] keys refused in one line, and a tiny heap run that writes the outputs
(docs/reference/repose3d.md)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

import ooc_dem
from ooc_dem.physics.layout import AX_X, AX_Y, AX_Z
from ooc_dem.app.repose import REPOSE_FIGURE, ReposeError, measure
from ooc_dem.model.scenario import ScenarioError, load_scenario

D = 0.0045  # sphere diameter of repose3d's soil (mean of r 2.0-2.5 mm)


def cone_heap(theta_deg, height_d=12.0, seed=0, roughness=0.0, toe=False, plateau=0.0):
    """Spheres of diameter D under a cone of angle theta and apex height height_d D (on
    a plateau of radius ``plateau``): the interior filled at random, below the surface,
    and a surface layer of two spheres per D^2 (horizontal projection) whose tops lie on
    the cone, displaced vertically by N(0, roughness D). ``toe``: a runout layer one
    sphere thick out to 1.6 times the base radius, as a collapsed column leaves."""
    rng = np.random.default_rng(seed)
    t = math.tan(math.radians(theta_deg))
    H = height_d * D
    R = plateau + H / t

    def surface(rho):
        return np.minimum(H, H - (rho - plateau) * t)

    n = int(3 * 0.6 * math.pi * R * R * H / (math.pi / 6 * D**3))
    rho, phi, top = R * np.sqrt(rng.random(n)), rng.uniform(-math.pi, math.pi, n), rng.random(n) * H
    keep = top <= surface(rho)
    rho, phi, top = rho[keep], phi[keep], top[keep]
    m = int(2 * math.pi * R * R / D**2)
    rs = R * np.sqrt(rng.random(m))
    rho = np.r_[rho, rs]
    phi = np.r_[phi, rng.uniform(-math.pi, math.pi, m)]
    top = np.r_[top, surface(rs) + rng.normal(0.0, roughness * D, m)]
    if toe:
        k = int(0.5 * math.pi * ((1.6 * R) ** 2 - R * R) / D**2)
        rho = np.r_[rho, np.sqrt(rng.uniform(R * R, (1.6 * R) ** 2, k))]
        phi = np.r_[phi, rng.uniform(-math.pi, math.pi, k)]
        top = np.r_[top, np.full(k, D)]
    top = np.maximum(top, D)
    pos = np.zeros((len(top), 3))
    pos[:, AX_X] = 0.3 + rho * np.cos(phi)
    pos[:, AX_Y] = top - 0.5 * D
    pos[:, AX_Z] = 0.25 + rho * np.sin(phi)
    return pos, np.full(len(top), 0.5 * D)


@pytest.mark.parametrize("theta", [20.0, 30.0, 38.0])
@pytest.mark.parametrize("kind", ["cone", "rough", "plateau_and_toe"])
def test_synthetic_cone_angle_recovered_within_half_a_degree(theta, kind):
    kw = {"cone": {}, "rough": {"roughness": 0.2}, "plateau_and_toe": {"plateau": 0.02, "toe": True, "roughness": 0.2}}[
        kind
    ]
    for seed in range(3):
        pos, r = cone_heap(theta, seed=seed, **kw)
        m = measure(pos, r, sectors=8, bin_width=0.005, fit_low=0.2, fit_high=0.8)
        assert abs(m["angle_deg"] - theta) < 0.5, (kind, seed, m["angle_deg"])
        assert m["sectors_fitted"] == 8
        assert abs(m["heap_height_m"] - 12 * D) < 2 * D
        assert np.allclose(m["axis_m"], [0.3, 0.25], atol=D)


def test_rougher_surface_still_within_a_degree():
    # a surface twice as rough (sd 0.4 D) with the toe: the 8-sector mean stays within 1 deg
    for theta in (20.0, 30.0, 38.0):
        for seed in range(3):
            pos, r = cone_heap(theta, seed=seed, roughness=0.4, toe=True)
            assert abs(measure(pos, r)["angle_deg"] - theta) < 1.0, (theta, seed)


def test_a_flat_layer_has_no_flank():
    rng = np.random.default_rng(1)
    n = 4000
    pos = np.c_[rng.uniform(0, 0.3, n), np.full(n, 0.5 * D), rng.uniform(0, 0.3, n)]
    with pytest.raises(ReposeError) as e:
        measure(pos, np.full(n, 0.5 * D))
    assert "sectors have a flank" in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(
    "overrides,needle",
    [
        (["repose.fit_low=0.9"], "repose.fit_low"),
        (["repose.fit_high=1.5"], "repose.fit_high"),
        (["repose.sectors=0"], "repose.sectors"),
        (["repose.bin_width=0.0001"], "repose.bin_width"),
        (["repose.column_radius=0.004"], "repose.column_radius"),
        (["bin.width=0.2"], "bin.width"),  # < 4 column radii
        (["bin.height=0.05"], "bin.height"),  # the column's loose fill does not fit
        (["bed.tile=500"], "bed.tile"),
        (["physics.dim=2", 'contact.soil_soil.law="linear"', 'contact.soil_wall.law="linear"'], "repose.enabled"),
        (["repose.radius=0.05"], "repose.radius"),  # unknown key
    ],
)
def test_bad_repose_values_are_one_line_errors(overrides, needle):
    with pytest.raises(ScenarioError) as e:
        load_scenario("repose3d", overrides)
    msg = str(e.value)
    assert needle in msg and "\n" not in msg, msg


def test_cli_refuses_a_bad_repose_value_with_exit_code_2():
    p = subprocess.run(
        [sys.executable, "-m", "ooc_dem.cli", "check", "repose3d", "--set", "repose.fit_low=0.8"],
        capture_output=True,
        text=True,
    )
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2 and len(lines) == 1 and "repose.fit_low" in lines[0], p.stderr


def test_repose_keys_leave_other_scenarios_hashes_alone():
    # the [repose] section at its defaults is not part of any hash (2D and bed3d stores keep theirs)
    sc = load_scenario("bed3d")
    assert "repose" not in sc._hash_dict()
    assert load_scenario("bed3d", ["repose.fit_low=0.1"]).hash() == sc.hash()  # measurement only
    rp = load_scenario("repose3d")
    assert rp.bed_hash() != load_scenario("repose3d", ["repose.column_radius=0.06"]).bed_hash()
    assert rp.hash() == load_scenario("repose3d", ["repose.sectors=12"]).hash()


# a heap of 400 spheres from a column of radius 20 mm, 0.16 s of collapse: seconds, with a flank
TINY = [
    "soil.n=400",
    "repose.column_radius=0.02",
    "bin.length=0.12",
    "bin.width=0.12",
    "bin.height=0.15",
    "output.run_steps=4000",
    "bed.settle_speed=0.02",
]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("repose") / "mono"
    return load_scenario("repose3d", TINY), ooc_dem.run(load_scenario("repose3d", TINY), out=out, figures=True), out


def test_tiny_heap_run_writes_the_angle_and_the_figure(tiny_run):
    sc, res, out = tiny_run
    summary = json.loads((out / "summary.json").read_text())
    rp = summary["repose"]
    assert rp["n_spheres"] == 400 and rp["unit"] == "deg" and rp["friction"] == 0.5
    png = out / "figures" / REPOSE_FIGURE
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the summary's angle is the measurement of the final committed state, read back
    state = res.state()
    again = measure(
        state["pos"], state["r"], sc.repose.sectors, sc.repose.bin_width, sc.repose.fit_low, sc.repose.fit_high
    )
    assert rp["angle_deg"] == again["angle_deg"] and 0.0 < rp["angle_deg"] < 60.0
    assert rp["sector_fits"] == again["sector_fits"]
    # the column stood at the bin's centre and the heap stayed there
    assert np.allclose(rp["axis_m"], [0.06, 0.06], atol=0.005)


@pytest.mark.slow
def test_tiny_heap_measured_alike_in_every_mode(tiny_run, tmp_path):
    # serial DDM ends in the monolithic run's bits; the heap's measurement (from the state in
    # id order) is then the same to the bit as well
    sc, res, _ = tiny_run
    a = res.summary
    b = ooc_dem.run(sc, out=tmp_path / "ddm", mode="ddm", domains=2).summary
    assert a["state_hash"] == b["state_hash"]
    assert a["repose"] == b["repose"]


def test_resume_writes_a_missing_repose_figure(tiny_run, capsys):
    # a kill between the last commit and the outputs: resume writes them from the state
    from ooc_dem import cli

    _, res, out = tiny_run
    before = json.loads((out / "summary.json").read_text())
    (out / "figures" / REPOSE_FIGURE).unlink()
    assert cli.main(["resume", str(out), "--no-progress"]) == 0
    assert "figures" in capsys.readouterr().out
    assert (out / "figures" / REPOSE_FIGURE).read_bytes()[:4] == b"\x89PNG"
    assert json.loads((out / "summary.json").read_text())["repose"] == before["repose"]
