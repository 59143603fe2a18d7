"""Figures, tables and deformation fields on a small synthetic run directory."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ooc_dem.model.fields import displacements, gridded_displacement, layer_index
from ooc_dem.app.plots import make_figures
from ooc_dem.app.sweep_slip import sweep_plot
from ooc_dem.app.tables import print_table
from ooc_dem.app.runfiles import read_series
from ooc_dem.model.scenario import load_scenario

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SERIES_HEADER = (
    "t [s],t_travel [s],x [m],y [m],vx [m/s],omega [rad/s],slip [-],net_traction [N],"
    "vertical_force [N],torque [N m],gross_traction [N],sinkage [m],drawbar [N]"
)


def assert_png(path, min_bytes=10_000):
    assert path.exists(), path
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC, f"{path} is not a PNG"
    assert len(data) > min_bytes, f"{path}: only {len(data)} bytes"


def _summary(scenario="quick"):
    def q(unit, whole, steady):
        return {
            "unit": unit,
            "whole_travel": {"value": whole, "window_s": [0.0, 2.0]},
            "steady": {"value": steady, "window_s": [0.43, 2.0]},
        }

    s = {
        "scenario": scenario,
        "mode": "monolithic",
        "backend": "hdf5",
        "wall_time_s": 12.345,
        "slip": q("-", 0.7304, 0.7421),
        "net_traction": q("N", 9.952, 10.011),
        "gross_traction": q("N", 12.721, 12.9),
        "torque": q("N m", 1.2721, 1.29),
        "sinkage": q("m", 0.0215, 0.0232),
        "motion_resistance": {
            "unit": "N",
            "whole_travel": {"value": 2.769, "window_s": [0.0, 2.0]},
            "steady": {"value": 2.889, "window_s": [0.43, 2.0]},
        },
    }
    s["sinkage"]["static"] = {"value": 0.0081, "window_s": [-0.02, 0.0]}
    return s


@pytest.fixture
def run_dir(tmp_path):
    """A fake run: 200-disc bed in 5 rows, a 2.2 s series, summary, scenario and a final state."""
    sc = load_scenario("quick")
    out = tmp_path / "run"
    out.mkdir()
    (out / "scenario.toml").write_text(sc.to_toml())
    rng = np.random.default_rng(1)
    nx, ny, r0 = 40, 5, 0.005
    ids, xs, ys, rs = [], [], [], []
    for j in range(ny):
        for i in range(nx):
            ids.append(1000 + j * nx + i)
            xs.append(r0 + 2 * r0 * i + (r0 if j % 2 else 0.0) * 0.5)
            ys.append(r0 + 1.8 * r0 * j)
            rs.append(r0 * rng.uniform(0.9, 1.0))
    iid, ix, iy, ir = (np.array(a) for a in (ids, xs, ys, rs))
    surface = float((iy + ir).max())
    np.savez(out / "initial.npz", id=iid, x=ix, y=iy, r=ir, surface=np.float64(surface))

    # final state: soil under the wheel's path pushed back and down, returned in a permuted order
    near = (ix > 0.08) & (ix < 0.26)
    depth = surface - iy
    fx = ix - np.where(near, 0.012 * np.exp(-depth / 0.02), 0.0)
    fy = iy - np.where(near, 0.008 * np.exp(-depth / 0.03), 0.0)
    perm = rng.permutation(len(iid))
    R = sc.wheel.radius
    ws = np.array([0.21, surface + R - 0.01, 0.0, 0.0, -2.0, -1.0])
    final = (iid[perm], fx[perm], fy[perm], ir[perm], ws)

    t = np.arange(1, 441) * 0.005
    tt = t - sc.wheel.settle_time
    trav = tt >= 0
    omega = np.where(trav, 1.0, 0.0)
    slip = np.where(trav, 0.73 + 0.03 * np.sin(2 * np.pi * 2.86 * tt), np.nan)
    vx = np.where(trav, (1 - np.nan_to_num(slip)) * R, 0.0)
    x = sc.wheel.x0 + np.cumsum(vx) * 0.005
    db = -sc.wheel.drawbar_load * np.clip(tt / sc.wheel.drawbar_ramp, 0, 1)
    net = -db + 0.5 * np.sin(2 * np.pi * 2.86 * tt)
    torque = np.where(trav, 1.27 + 0.1 * np.sin(2 * np.pi * 2.86 * tt), 0.0)
    sink = 0.008 + 0.012 * np.clip(tt, 0, None) / 2.0
    y = surface + R - sink
    rows = np.column_stack([t, tt, x, y, vx, omega, slip, net, 19.6 + 0 * t, torque, torque / R, sink, db])
    np.savetxt(out / "series.csv", rows, delimiter=",", header=SERIES_HEADER, comments="", fmt="%.10g")
    (out / "summary.json").write_text(json.dumps(_summary(), indent=2))
    return out, final, (iid, ix, iy, fx, fy)


def test_make_figures_writes_valid_pngs(run_dir):
    out, final, _ = run_dir
    paths = make_figures(out, final=final)
    names = sorted(p.name for p in paths)
    assert names == ["deformation.png", "displacement.png", "series.png"]
    for p in paths:
        assert p.parent == out / "figures"
        assert_png(p)


def test_read_series_columns(run_dir):
    out, _, _ = run_dir
    s = read_series(out / "series.csv")
    assert set(s) >= {"t", "t_travel", "slip", "net_traction", "gross_traction", "torque", "sinkage", "drawbar"}
    assert len(s["t"]) == 440
    assert np.isnan(s["slip"][0]) and np.isfinite(s["slip"][-1])


def test_layer_index_hand_computed():
    # surface 0.05 m, 5 layers of 10 mm, counted from the floor
    y0 = np.array([0.0, 0.009, 0.015, 0.035, 0.0499, 0.07, -0.001])
    assert layer_index(y0, 0.05, 5).tolist() == [0, 0, 1, 3, 4, 4, 0]
    assert layer_index(np.array([0.25, 0.75]), 1.0, 2, bottom=0.5).tolist() == [0, 1]
    with pytest.raises(ValueError):
        layer_index(y0, 0.05, 0)


def test_displacements_matched_by_id():
    iid = np.array([10, 3, 7])
    ix = np.array([1.0, 2.0, 3.0])
    iy = np.array([0.0, 1.0, 2.0])
    # final arrays permuted, with one extra disc that was not in the initial bed
    fid = np.array([7, 99, 10, 3])
    fx = np.array([3.5, 9.0, 0.5, 2.25])
    fy = np.array([2.0, 9.0, -1.0, 1.5])
    dx, dy = displacements(iid, ix, iy, fid, fx, fy)
    np.testing.assert_array_equal(dx, [-0.5, 0.25, 0.5])
    np.testing.assert_array_equal(dy, [-1.0, 0.5, 0.0])
    # a disc missing from the final state gets NaN
    dx, dy = displacements(iid, ix, iy, fid[[0, 2]], fx[[0, 2]], fy[[0, 2]])
    assert dx[0] == -0.5 and math.isnan(dx[1]) and dx[2] == 0.5
    with pytest.raises(ValueError):
        displacements(iid, ix, iy, np.array([7, 7]), fx[:2], fy[:2])


def test_displacements_of_permuted_synthetic_bed(run_dir):
    _, final, (iid, ix, iy, fx, fy) = run_dir
    fid, fxp, fyp = final[0], final[1], final[2]
    dx, dy = displacements(iid, ix, iy, fid, fxp, fyp)
    np.testing.assert_array_equal(dx, fx - ix)
    np.testing.assert_array_equal(dy, fy - iy)


def test_gridded_displacement_hand_computed():
    x0 = np.array([0.1, 0.4, 1.5, 0.5, 0.2])
    y0 = np.array([0.1, 0.2, 0.5, 1.5, 0.3])
    dx = np.array([1.0, 3.0, 0.0, 4.0, np.nan])  # the NaN disc is skipped
    dy = np.array([0.0, 2.0, -1.0, 4.0, 7.0])
    g = gridded_displacement(x0, y0, dx, dy, cell=1.0)
    assert g.u.shape == (2, 2)
    np.testing.assert_allclose(g.x, [[0.5, 1.5], [0.5, 1.5]])
    np.testing.assert_allclose(g.y, [[0.5, 0.5], [1.5, 1.5]])
    assert g.count.tolist() == [[2, 1], [1, 0]]
    np.testing.assert_allclose(g.u[0], [2.0, 0.0])
    np.testing.assert_allclose(g.v[0], [1.0, -1.0])
    assert g.u[1, 0] == 4.0 and g.v[1, 0] == 4.0
    assert math.isnan(g.u[1, 1]) and math.isnan(g.v[1, 1])
    # explicit extent and a minimum count
    g = gridded_displacement(x0, y0, dx, dy, cell=1.0, extent=(0.0, 2.0, 0.0, 1.0), min_count=2)
    assert g.u.shape == (1, 2)
    assert g.u[0, 0] == 2.0 and math.isnan(g.u[0, 1])


def test_print_table():
    text = print_table(_summary())
    assert "whole travel 0–2 s" in text and "steady 0.43–2 s" in text
    lines = {ln.split("  ")[0].strip(): ln for ln in text.splitlines()}
    assert "0.730" in lines["wheel slip (-)"] and "0.742" in lines["wheel slip (-)"]
    assert "9.952" in lines["net traction (N)"] and "10.011" in lines["net traction (N)"]
    assert "12.721" in lines["gross traction (N)"]
    assert "2.769" in lines["motion resistance (N)"]
    assert "8.1" in lines["static sinkage (mm)"]
    assert "21.5" in lines["travelling sinkage (mm)"] and "23.2" in lines["travelling sinkage (mm)"]
    assert "12.3" in lines["wall time (s)"]
    assert "paper" not in text
    paper = print_table(_summary("paper2008"))
    assert "paper 2008" in paper and "0.736" in paper and "6844" in paper


def test_print_table_missing_values():
    s = _summary()
    s["slip"]["steady"]["value"] = None
    s.pop("wall_time_s")
    text = print_table(s)
    assert "—" in text and "wall time" not in text


def test_sweep_plot(tmp_path):
    csv = tmp_path / "sweep.csv"
    rows = ["slip,drawbar_pull,gross_traction,sinkage"]
    for s in (0.1, 0.3, 0.2, 0.5, 0.7, 0.9):
        rows.append(
            f"{s},{12 * (1 - math.exp(-5 * s)) - 2:.4f},{13 * (1 - math.exp(-5 * s)):.4f},{0.01 + 0.02 * s:.4f}"
        )
    csv.write_text("\n".join(rows) + "\n")
    png = sweep_plot(csv, tmp_path / "figs" / "sweep.png")
    assert_png(png, min_bytes=10_000)


def test_report_also_writes_pdf_and_svg_on_request(run_dir):
    """`report --formats pdf,svg`: each figure also as a PDF and an SVG beside its PNG (the
    files are what a PDF reader and an XML parser take); an unknown format is one line."""
    import xml.etree.ElementTree as ET

    from support.cli import cli_in_process, one_line_error

    from ooc_dem.app.drawing import also_saved_as

    out, final, _ = run_dir
    with also_saved_as(("pdf", "svg")):  # what `report --formats pdf,svg` wraps its figures in
        make_figures(out, final=final)
    for name in ("series", "deformation", "displacement"):
        png = out / "figures" / f"{name}.png"
        assert_png(png)
        assert (out / "figures" / f"{name}.pdf").read_bytes().startswith(b"%PDF")
        assert ET.parse(out / "figures" / f"{name}.svg").getroot().tag.endswith("svg")
    one_line_error(cli_in_process("report", out, "--formats", "eps"), "--formats")
