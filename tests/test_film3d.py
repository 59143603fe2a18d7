"""3D runs you can watch: the wheel's surface mesh, the sphere splatter of ``ooc-dem animate``
(exact hidden-surface removal), quick-3d's trajectory frames, and on a tiny 3D run the film
(both panels drawn) and the XDMF 3 time series read back by meshio (spheres and wheel)."""

from collections import Counter

import numpy as np
import pytest

import ooc_dem
from ooc_dem.app import film3d
from ooc_dem.app.film3d import SphereSplatter, colour_map
from ooc_dem.app.trajectory_format import frame_every
from ooc_dem.app.wheel_surface import WheelGeometry, wheel_surface
from ooc_dem.model.scenario import load_scenario
from support.cli import cli_in_process, run_cli


def test_wheel_surface_is_closed_and_turns_with_the_wheel():
    """Rim cylinder (72 facets, capped) and 18 lug boxes: every edge shared by exactly two
    triangles in opposite directions (closed, consistently oriented), outward (positive
    volume close to the cylinder's plus the lugs'), and placed at the pose."""
    g = WheelGeometry.of_scenario(load_scenario("quick-3d"))
    v, tri = wheel_surface(g, 0.12, 0.2, 0.3)
    assert tri.shape == (4 * 72 + 12 * 18, 3) and v.shape == (2 * 72 + 2 + 8 * 18, 3)
    edges = Counter(map(tuple, np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])))
    assert max(edges.values()) == 1 and all(edges[(b, a)] == 1 for a, b in edges)
    a, b, c = v[tri[:, 0]], v[tri[:, 1]], v[tri[:, 2]]
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    lugs = g.n_lugs * (g.lug_tip_radius - g.radius) * g.lug_thickness * g.width
    assert volume == pytest.approx(np.pi * g.radius**2 * g.width + lugs, rel=2e-3)
    assert np.isclose(v[:, 2].min(), g.z_centre - g.width / 2) and np.isclose(v[:, 2].max(), g.z_centre + g.width / 2)
    tips = np.hypot(v[:, 0] - 0.12, v[:, 1] - 0.2)
    assert np.isclose(tips.max(), np.hypot(g.lug_tip_radius, g.lug_thickness / 2))
    v2, tri2 = wheel_surface(g, 0.12, 0.2, 0.3 + 2 * np.pi / g.n_lugs)
    assert np.array_equal(tri2, tri) and not np.allclose(v2, v)  # turned by one lug pitch


def test_the_nearest_sphere_shows():
    sp = SphereSplatter(100, 50, 0.0, 1.0, 0.0, 0.5)
    pos = np.array([[0.5, 0.25, 0.0], [0.52, 0.25, 0.1]])  # the second is nearer (+z side)
    rgb = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], np.float32)
    img = sp.render(pos, np.array([0.1, 0.1]), rgb)
    assert img[25, 52, 2] > 100 and img[25, 52, 0] == 0  # blue in front
    assert img[25, 41, 0] > 50 and img[25, 41, 2] == 0  # red's uncovered edge
    assert (img[0, 0] == 255).all()  # background
    img = sp.render(pos[::-1], np.array([0.1, 0.1]), rgb[::-1])  # the order does not matter
    assert img[25, 52, 2] > 100 and img[25, 52, 0] == 0


def test_skipping_hidden_spheres_changes_no_pixel(monkeypatch):
    """The depth slabs' culling skips only spheres that cannot show: the picture is the
    one drawn without it, pixel for pixel (a bed of spheres with a rut and a hole)."""
    rng = np.random.default_rng(5)
    n = 60000
    pos = rng.random((n, 3)) * [1.0, 0.3, 0.4]
    keep = ~((np.abs(pos[:, 0] - 0.5) < 0.1) & (pos[:, 1] > 0.2) & (np.abs(pos[:, 2] - 0.2) < 0.1))
    pos = pos[keep]
    r = rng.uniform(0.004, 0.006, len(pos))
    rgb = colour_map(pos[:, 1], 0.0, 0.3)
    sp = SphereSplatter(400, 160, 0.0, 1.0, 0.0, 0.4)
    culled = sp.render(pos, r, rgb)
    monkeypatch.setattr(film3d, "SLAB_MIN_SPHERES", 10**9)
    assert np.array_equal(sp.render(pos, r, rgb), culled)


def test_quick3d_writes_50_to_100_frames():
    sc = load_scenario("quick-3d")
    steps = round((sc.wheel.settle_time + sc.wheel.travel_time) / sc.physics.dt)
    frames = steps // frame_every(sc) + 1
    assert 50 <= frames <= 100, frames


# a tiny 3D run: the small bin of tests/test_wheel3d.py (two 750-sphere tiles), the wheel
# placed on the bed and rolling at a prescribed slip, a frame every 20 steps
TINY3D = [
    "soil.n=1500",
    "bed.tile=750",
    "bin.length=0.4",
    "bin.width=0.07",
    "wheel.width=0.035",
    "wheel.x0=0.2",
    "wheel.drop_gap=0",
    "wheel.settle_time=0.0004",
    "wheel.travel_time=0.002",
    "wheel.control=slip",
    "wheel.slip=0.2",
    "wheel.omega=10.0",
    "output.steady_start=0.0004",
    "output.steady_end=0.002",
    "output.series_interval=0.0002",
    "output.snapshot_interval=0.0004",
]
TINY3D_STEPS = 100


@pytest.fixture(scope="module")
def tiny3d(tmp_path_factory):
    out = tmp_path_factory.mktemp("film3d") / "run"
    ooc_dem.run("quick-3d", out, overrides=TINY3D, steps=TINY3D_STEPS)
    return out


@pytest.mark.slow
def test_animate_3d_draws_both_panels(tmp_path, tiny3d):
    imageio = pytest.importorskip("imageio.v2")
    out = tmp_path / "film.gif"
    cp = run_cli("animate", tiny3d, "--out", out, "--fps", "10", "--no-progress", check=True)
    assert "6 frames" in cp.stdout, cp.stdout
    rd = imageio.get_reader(out)
    try:
        pictures = [np.asarray(p)[:, :, :3] for p in rd]
    finally:
        rd.close()
    assert len(pictures) == 6
    pic = pictures[-1]
    H = pic.shape[0]
    assert pic.shape[1] == 1280 and H % 16 == 0
    for panel in (pic[: H // 2], pic[H // 2 :]):
        coloured = (np.ptp(panel.astype(int), axis=2) > 40).sum()  # the spheres' colours, not grey
        assert coloured > 0.05 * panel.shape[0] * panel.shape[1], coloured
    top, cut = pic[: H // 2], pic[H // 2 :]
    assert (np.ptp(top.astype(int), axis=2) > 40).sum() > (np.ptp(cut.astype(int), axis=2) > 40).sum()
    cp = run_cli("animate", tiny3d, "--out", tmp_path / "h.mp4", "--colour", "height", "--no-progress", check=True)
    assert "6 frames" in cp.stdout


@pytest.mark.slow
def test_export_trajectory_3d_reads_in_meshio(tmp_path, tiny3d):
    meshio = pytest.importorskip("meshio")
    from ooc_dem.app.trajectory_read import Trajectory

    out = tmp_path / "traj.xdmf"
    cp = cli_in_process("export-trajectory", tiny3d, "--out", out, check=True)
    assert "6 frames" in cp.stdout and "traj-wheel.xdmf" in cp.stdout
    sc = load_scenario("quick-3d", TINY3D)
    g = WheelGeometry.of_scenario(sc)
    with Trajectory.of_run(tiny3d) as t, meshio.xdmf.TimeSeriesReader(out) as r:
        points, cells = r.read_points_cells()
        assert r.num_steps == len(t) == 6
        first = t[0]
        assert np.array_equal(points, first["pos"]) and cells[0].type == "vertex" and len(cells[0].data) == 1500
        for k in range(r.num_steps):
            time, data, _ = r.read_data(k)
            fr = t[k]
            assert time == fr["time"]
            assert np.array_equal(data["radius"], fr["r"]) and np.array_equal(data["id"], fr["id"])
            assert np.array_equal(data["velocity"], fr["vel"]) and np.array_equal(data["spin"], fr["spin"])
        last_ws = t.wheel_states[-1]
    with meshio.xdmf.TimeSeriesReader(tmp_path / "traj-wheel.xdmf") as r:
        points, cells = r.read_points_cells()
        v, tri = wheel_surface(g, *t.wheel_states[0][[0, 1, 4]])
        assert r.num_steps == 6 and cells[0].type == "triangle" and np.array_equal(cells[0].data, tri)
        assert np.array_equal(points, v)
    vtk = pytest.importorskip("vtk")  # ParaView's XDMF reader: every frame's own geometry
    rd = vtk.vtkXdmfReader()
    rd.SetFileName(str(tmp_path / "traj-wheel.xdmf"))
    rd.UpdateInformation()
    times = rd.GetOutputInformation(0).Get(vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS())
    rd.UpdateTimeStep(times[-1])
    mesh = rd.GetOutputDataObject(0)
    v, tri = wheel_surface(g, *last_ws[[0, 1, 4]])
    assert mesh.GetNumberOfCells() == len(tri) and np.allclose(mesh.GetPoint(0), v[0], rtol=0, atol=1e-15)


def test_film_speed_tool_prints_its_times():
    """tools/film_speed.py (the renderer's timing, not asserted: printed as JSON)."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cp = subprocess.run(
        [sys.executable, str(root / "tools" / "film_speed.py"), "--n", "30000", "--repeat", "1"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        check=True,
    )
    got = json.loads(cp.stdout)
    print(cp.stdout)
    assert got["spheres"] == 30000 and got["covered_px_side"] > 0
    assert set(got["seconds"]) == {"colour", "side", "cut", "compose", "frame"}
