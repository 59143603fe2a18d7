"""Plate sinkage (app/sinkage.py, `ooc-dem sinkage`): the Bekker fit, the footing's plates,
a small 2D test and the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from support.cli import cli_in_process, one_line_error
from ooc_dem.app.sinkage import SinkageError, SinkageOptions, bekker, footing, run_sinkage
from ooc_dem.model.scenario import load_scenario
from ooc_dem.physics.layout import AX_X, AX_Y, AX_Z

SMALL = ["soil.n=400", "bin.length=0.15", "wheel.enabled=false"]


def test_bekker_fit_recovers_its_parameters():
    """Curves p = (k_c / b + k_phi) z^n of two widths give back k_c, k_phi and n."""
    k_c, k_phi, n = 2.0e4, 8.0e5, 1.1
    tests = []
    for b in (0.02, 0.05):
        z = np.linspace(0.0, 0.01, 50)
        tests.append({"width": b, "series": {"sinkage": z.tolist(), "pressure": ((k_c / b + k_phi) * z**n).tolist()}})
    fit = bekker(tests, 0.01, 0.1)
    assert fit["n"] == pytest.approx(n, rel=1e-9)
    assert fit["k_c"] == pytest.approx(k_c, rel=1e-6)
    assert fit["k_phi"] == pytest.approx(k_phi, rel=1e-9)
    assert fit["r2_log_p"] == pytest.approx(1.0)


@pytest.mark.parametrize("dim", [2, 3])
def test_the_footing_is_a_bottom_face_and_side_faces(dim):
    sc = load_scenario("quick" if dim == 2 else "quick-3d")
    t = footing(sc, 0.04, 0.05, 0.2, 0.01)
    assert len(t) == (3 if dim == 2 else 5)
    assert t[0]["axis"] == AX_Y and t[0]["side"] == -1 and t[0]["hi1"] - t[0]["lo1"] == pytest.approx(0.04)
    assert np.all(t["vy"] == -0.01)
    sides = t[1:]
    assert sorted(sides["axis"].tolist()) == ([AX_X, AX_X] if dim == 2 else [AX_X, AX_X, AX_Z, AX_Z])
    assert np.all(sides["lo1"][sides["axis"] == AX_X] == 0.05)  # they start at the bottom face


def test_a_plate_sinks_into_a_2d_bed():
    """Two plates (2 and 4 cm) pressed 8 mm into a bed of 400 discs: the pressure grows
    with the sinkage, and the Bekker fit has n in (0.3, 2.5), k_phi > 0 and R^2 (of log p)
    > 0.5: 5 to 10 grains under a plate make p fluctuate by half its value (measured: n =
    0.93, k_c = -4.5e3 N/m^(n+1), k_phi = 5.0e5 N/m^(n+2), R^2 = 0.69)."""
    res = run_sinkage(load_scenario("quick", SMALL), SinkageOptions(widths=(0.02, 0.04), depth=0.008, speed=0.02))
    for t in res["tests"]:
        z = np.asarray(t["series"]["sinkage"])
        p = np.asarray(t["series"]["pressure"])
        assert z[-1] == pytest.approx(0.008, abs=2e-4)
        assert p[z > 0.006].mean() > 2 * p[(z > 0.001) & (z < 0.003)].mean() > 0
    fit = res["bekker"]
    assert 0.3 < fit["n"] < 2.5 and fit["k_phi"] > 0 and fit["r2_log_p"] > 0.5, fit


def test_cli_sinkage(tmp_path):
    out = tmp_path / "s"
    sets = sum((["--set", s] for s in SMALL), [])
    cp = cli_in_process(
        "sinkage", "quick", *sets, "--widths", "0.02,0.04", "--depth", "0.004", "--speed", "0.04", "--out", out,
        "--no-progress",
    )  # fmt: skip
    assert cp.returncode == 0, cp.stderr
    assert "Bekker: n =" in cp.stdout
    doc = json.loads((out / "sinkage.json").read_text())
    assert doc["widths"] == [0.02, 0.04] and set(doc["bekker"]) >= {"n", "k_c", "k_phi"}
    assert (out / "figures" / "sinkage.png").stat().st_size > 1000


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--widths", "0.02"], ">= 2"),
        (["--widths", "0.02,x"], "--widths"),
        (["--widths", "0.02,0.3"], "half the bin"),
        (["--depth", "0.05"], "--depth"),
    ],
)
def test_cli_sinkage_refuses_bad_input(tmp_path, args, needle):
    sets = sum((["--set", s] for s in SMALL), [])
    cp = cli_in_process("sinkage", "quick", *sets, "--out", tmp_path / "o", "--no-progress", *args)
    one_line_error(cp, needle)


def test_options_are_checked():
    with pytest.raises(SinkageError, match="distinct"):
        SinkageOptions(widths=(0.02, 0.02)).check()
