"""tools/influence_zone.py (domain sensitivity): the lateral extent of the soil
the 3D wheel moves, from a run's trajectory frames. The binning and the zone's edges are
checked on displacements made by hand (known answers), then the tool on a real quick-3d
run's frames (the wheel rolling), and its refusals (exit code 2)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

import ooc_dem

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

PATH = Path(__file__).resolve().parents[1] / "tools" / "influence_zone.py"


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("influence_zone", PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_profile_and_edges_of_a_known_field(tool):
    """Spheres on a lateral line, displaced by exp(-e / 0.02) m beyond the wheel's face
    (1 m under it): the bins' means and the 2 % / 5 % edges are where that law puts them."""
    z = np.linspace(-0.5, 0.5, 20001)
    pos0 = np.zeros((z.size, 3))
    pos0[:, 0] = 0.2
    pos0[:, 2] = z
    half = 0.05
    e = np.abs(z) - half
    amp = np.where(e < 0, 1.0, np.exp(-np.maximum(e, 0) / 0.02))
    pos1 = pos0.copy()
    pos1[:, 1] = -amp  # pushed down
    outside = pos0[:, 0] + 1.0  # x outside the wheel's stretch: not counted
    rows = tool.lateral_profile(pos0, pos1, (0.1, 0.3), 0.0, half, 0.01)
    assert rows[0]["e_lo"] == pytest.approx(-0.05) and rows[-1]["e_hi"] == pytest.approx(0.46)
    assert sum(r["n"] for r in rows) == z.size
    assert tool.lateral_profile(np.c_[outside, pos0[:, 1:]], pos1, (0.1, 0.3), 0.0, half, 0.01) == []
    k = np.floor(e / 0.01)
    for r in rows:
        ez = e[k == round(r["e_lo"] / 0.01)]
        assert ez.size == r["n"]
        want = np.where(ez < 0, 1.0, np.exp(-np.maximum(ez, 0) / 0.02)).mean()
        assert r["disp"] == pytest.approx(want, rel=1e-9)
        assert r["dy"] == pytest.approx(-want, rel=1e-9) and r["dx"] == 0.0 and r["dz_out"] == 0.0
    zone = tool.zone_edges(rows, [0.02, 0.05], None)
    assert zone["under_wheel"] == pytest.approx(1.0)
    assert zone["floor"] < 1e-6
    # the edge is the first bin whose mean, exp(-a / 0.02) (0.02 / 0.01) (1 - exp(-0.5)) for a
    # bin [a, a + 0.01), falls below p: a > 0.02 ln(0.787 / p), within a bin of 0.02 ln(1 / p)
    for p in (0.02, 0.05):
        a = [r["e_lo"] for r in rows if r["e_lo"] >= 0 and np.exp(-r["e_lo"] / 0.02) * 2.0 * (1.0 - np.exp(-0.5)) < p]
        assert zone["edges"][f"{p:g}"] == a[0]
        assert abs(a[0] - 0.02 * np.log(1.0 / p)) < 0.01


def test_tool_on_a_rolling_quick3d_run(tool, tmp_path, capsys):
    """A real run's frames (quick-3d, the wheel rolling from t = 0.1 s): the profile holds
    every sphere that started over the axle's stretch (counted again from the frame files
    with h5py), the soil under the wheel moves more than the floor, and the figure is
    written. (quick-3d's bin is too narrow for a zone: tests/ check the edges above.)"""
    import h5py

    out = tmp_path / "q3"
    ooc_dem.run("quick-3d", out, steps=10000, overrides={"output.snapshot_interval": 0.05})
    png = tmp_path / "zone.png"
    assert tool.main([str(out), "--t0", "0.1", "--png", str(png)]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["t0"] == pytest.approx(0.1) and rep["t1"] == pytest.approx(0.2)
    with (
        h5py.File(out / "trajectory" / "frame-000000005000.h5", "r") as f0,
        h5py.File(out / "trajectory" / "frame-000000010000.h5", "r") as f1,
    ):
        x = f0["pos"][:, 0]
        z = f0["pos"][:, 2] - 0.06  # from the wheel's mid-plane
        xw0, xw1 = f0.attrs["wheel_state"][0], f1.attrs["wheel_state"][0]
    assert rep["wheel_x"] == [xw0, xw1] and xw1 > xw0  # it travelled
    assert sum(r["n"] for r in rep["profile"]) == int(((x >= xw0) & (x <= xw1)).sum()) > 0
    assert rep["under_wheel"] > rep["floor"] > 0
    assert rep["profile"][0]["e_lo"] < 0 < rep["profile"][-1]["e_lo"] <= rep["wall_gap_m"]
    ahead = rep["ahead"]
    front = xw1 + 0.110  # quick-3d's lug tips
    assert ahead["front_x"] == pytest.approx(front)
    assert sum(r["n"] for r in ahead["profile"]) == int(((x >= front) & (np.abs(z) <= 0.03)).sum())
    assert png.stat().st_size > 10_000
    # one frame twice: the wheel did not travel, nothing to measure
    assert tool.main([str(out), "--t0", "0.1", "--t1", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "t = 0.1-0.1 s" in err and "no spheres" in err and len(err.strip().splitlines()) == 1


def test_refusals(tool, tmp_path, capsys):
    assert tool.main([str(tmp_path / "nothing")]) == 2
    assert "influence_zone:" in capsys.readouterr().err
    assert tool.main([str(tmp_path), "--bin", "0"]) == 2
    assert "--bin" in capsys.readouterr().err
    assert tool.main([str(tmp_path), "--fractions", "2"]) == 2
    assert "--fractions" in capsys.readouterr().err
    out = tmp_path / "q2"
    ooc_dem.run("quick", out, steps=20)
    assert tool.main([str(out)]) == 2
    assert "3D wheel run" in capsys.readouterr().err
