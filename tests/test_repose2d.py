"""repose2d: the angle of repose of a 2D heap (its two flanks) measured on synthetic
triangles of known angle, the 2D [repose] keys refused in one line, a tiny 2D heap run,
and the angle printed by `ooc-dem run` and `ooc-dem report` (docs/reference/repose3d.md,
"The 2D test")."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ooc_dem.app.repose import REPOSE_FIGURE, ReposeError, angle_line, measure
from ooc_dem.model.scenario import ScenarioError, load_scenario
from ooc_dem.physics.layout import AX_X, AX_Y
from tests.support.cli import cli_in_process

D = 0.004  # disc diameter of repose2d's soil (mean of r 1.8-2.2 mm)


def triangle_heap(theta_deg, height_d=25.0, seed=0, roughness=0.0, toe=False, plateau=0.0):
    """Discs of diameter D under a triangle of flank angle theta and apex height height_d D
    (on a plateau of half-width ``plateau``), axis at x = 0.3: the interior filled at
    random below the surface, and a surface layer of two discs per D along x whose tops
    lie on the triangle, displaced vertically by N(0, roughness D). ``toe``: a run-out
    layer one disc thick out to 1.6 times the half-base on either side."""
    rng = np.random.default_rng(seed)
    t = math.tan(math.radians(theta_deg))
    H = height_d * D
    L = plateau + H / t

    def surface(dx):
        return np.minimum(H, H - (np.abs(dx) - plateau) * t)

    n = int(2 * 0.8 * 2 * L * H / (math.pi / 4 * D**2))
    dx, top = rng.uniform(-L, L, n), rng.random(n) * H
    keep = top <= surface(dx)
    dx, top = dx[keep], top[keep]
    m = int(2 * 2 * L / D)
    xs = rng.uniform(-L, L, m)
    dx = np.r_[dx, xs]
    top = np.r_[top, surface(xs) + rng.normal(0.0, roughness * D, m)]
    if toe:
        k = int(2 * 0.6 * L / D)
        dx = np.r_[dx, rng.uniform(L, 1.6 * L, k) * rng.choice([-1.0, 1.0], k)]
        top = np.r_[top, np.full(k, D)]
    top = np.maximum(top, D)
    pos = np.zeros((len(top), 2))
    pos[:, AX_X] = 0.3 + dx
    pos[:, AX_Y] = top - 0.5 * D
    return pos, np.full(len(top), 0.5 * D)


# Tolerance: each flank is one profile (one point per 5 mm bin, 16-34 points on a 25 d
# heap), not the ~100 points of a 3D heap's eight sectors, so the fit's scatter is wider:
# over 10 seeds the measured angle was within 0.52 deg of the triangle's (mean error
# -0.19 .. +0.03 deg: no bias) for a smooth surface, a roughness of 0.2 D and a plateau
# with a toe; 0.75 deg leaves room for that scatter and still catches a bias of a degree.
@pytest.mark.parametrize("theta", [20.0, 30.0, 38.0])
@pytest.mark.parametrize("kind", ["triangle", "rough", "plateau_and_toe"])
def test_synthetic_triangle_angle_recovered_within_three_quarters_of_a_degree(theta, kind):
    kw = {
        "triangle": {},
        "rough": {"roughness": 0.2},
        "plateau_and_toe": {"plateau": 0.02, "toe": True, "roughness": 0.2},
    }
    for seed in range(3):
        pos, r = triangle_heap(theta, seed=seed, **kw[kind])
        m = measure(pos, r, bin_width=0.005, fit_low=0.2, fit_high=0.8)
        assert abs(m["angle_deg"] - theta) < 0.75, (kind, seed, m["angle_deg"])
        assert m["dim"] == 2 and m["sectors"] == 2 and m["sectors_fitted"] == 2
        # the two flanks each find the slope (neither is the other's mirror image)
        assert all(abs(f["angle_deg"] - theta) < 1.5 for f in m["sector_fits"])
        assert abs(m["heap_height_m"] - 25 * D) < 2 * D
        assert np.allclose(m["axis_m"], [0.3], atol=D)


def test_a_flat_2d_layer_has_no_flank_and_sectors_other_than_two_are_refused():
    rng = np.random.default_rng(1)
    pos = np.c_[rng.uniform(0, 0.3, 200), np.full(200, 0.5 * D)]
    with pytest.raises(ReposeError) as e:
        measure(pos, np.full(200, 0.5 * D))
    assert "flanks have" in str(e.value) and "\n" not in str(e.value)
    pos, r = triangle_heap(30.0)
    with pytest.raises(ReposeError, match="two flanks"):
        measure(pos, r, sectors=8)


def test_angle_line():
    assert angle_line({"angle_deg": 24.24, "sectors_fitted": 8, "angle_std_deg": 1.26}) == (
        "angle of repose 24.2 deg (8 sectors, sd 1.3 deg)"
    )
    assert angle_line({"angle_deg": 13.0, "dim": 2, "sectors_fitted": 2, "angle_std_deg": 3.0}) == (
        "angle of repose 13.0 deg (2 flanks, sd 3.0 deg)"
    )
    assert angle_line({"angle_deg": None, "note": "flat"}) is None and angle_line(None) is None


@pytest.mark.parametrize(
    "overrides,needle",
    [
        (["bin.length=0.4"], "bin.length"),  # < 4 column radii
        (["bin.height=0.1"], "bin.height"),  # the column's loose fill does not fit
        (["repose.column_radius=0.004"], "repose.column_radius"),
        (["repose.bin_width=0.0001"], "repose.bin_width"),
        (["bed.tile=500"], "bed.tile"),
    ],
)
def test_bad_2d_repose_values_are_one_line_errors(overrides, needle):
    with pytest.raises(ScenarioError) as e:
        load_scenario("repose2d", overrides)
    assert needle in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_repose2d_is_a_2d_column_of_a_few_thousand_discs():
    sc = load_scenario("repose2d")
    assert sc.dim == 2 and sc.repose.enabled and not sc.wheel.enabled and sc.soil.n <= 3000
    quick = load_scenario("quick").contact.soil_soil
    assert sc.contact.soil_soil == quick  # the 2D linear law of quick


# a heap of 300 discs from a column 0.114 m wide, 0.3 s of collapse: seconds, with two flanks
TINY = [
    "soil.n=300",
    "repose.column_radius=0.057",
    "bin.length=0.24",
    "output.run_steps=30000",
]


@pytest.fixture(scope="module")
def tiny_2d_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("repose2d") / "run"
    args = [a for kv in TINY for a in ("--set", kv)]
    cp = cli_in_process("run", "repose2d", *args, "--out", out, "--no-progress", check=True)
    return out, cp


def test_tiny_2d_heap_run_gives_an_angle_and_prints_it(tiny_2d_run):
    out, cp = tiny_2d_run
    rp = json.loads((out / "summary.json").read_text())["repose"]
    assert rp["n_discs"] == 300 and rp["dim"] == 2 and rp["sectors_fitted"] == 2
    assert 0.0 < rp["angle_deg"] < 60.0
    assert abs(rp["axis_m"][0] - 0.12) < 0.01  # the column stood at the floor's centre
    assert (out / "figures" / REPOSE_FIGURE).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    line = f"angle of repose {rp['angle_deg']:.1f} deg (2 flanks, sd {rp['angle_std_deg']:.1f} deg)"
    assert line in cp.stdout.splitlines(), cp.stdout


def test_report_prints_the_angle(tiny_2d_run):
    out, _ = tiny_2d_run
    rp = json.loads((out / "summary.json").read_text())["repose"]
    cp = cli_in_process("report", out, check=True)
    assert angle_line(rp) in cp.stderr.splitlines(), cp.stderr
    assert json.loads(cp.stdout)["repose"] == rp  # stdout stays the summary as JSON
