"""The checkpoint tools (list / verify / inspect / hash / prune / export) on a 3D
store, and the exports' 3D points, radius, 3-component velocity and spin read back by
meshio and VTK (ParaView's readers)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import ooc_dem
from ooc_dem import cli
from ooc_dem.model.checkpoint import hash_particles
from ooc_dem.model.state import Particles


@pytest.fixture(scope="module")
def store3d(tmp_path_factory):
    out = tmp_path_factory.mktemp("d3tools") / "run"
    res = ooc_dem.run("bed3d", out, mode="ooc", backend="zarr", domains=3, block=5, steps=30, checkpoint_every=10)
    return out, res


def _cli(capsys, *args):
    rc = cli.main([str(a) for a in args])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_list_verify_inspect_hash(store3d, capsys):
    out, res = store3d
    rc, text, _ = _cli(capsys, "checkpoint", "list", out)
    assert rc == 0 and "discs 2000" in text and "(current)" in text
    rc, text, _ = _cli(capsys, "checkpoint", "verify", out)
    assert rc == 0 and text.startswith("OK")
    rc, text, _ = _cli(capsys, "checkpoint", "inspect", out)
    info = json.loads(text)
    assert rc == 0 and info["step"] == 30 and info["discs"] == 2000
    rc, text, _ = _cli(capsys, "checkpoint", "hash", out)
    s = res.state()
    p = Particles(**s)
    assert p.dim == 3
    assert rc == 0 and text.strip() == res.summary["state_hash"] == hash_particles(p, np.zeros(6), 30)


def test_prune(store3d, tmp_path, capsys):
    src, res = store3d
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    rc, text, _ = _cli(capsys, "checkpoint", "prune", out, "--keep", "1")
    assert rc == 0 and "kept epochs [30]" in text
    rc, text, _ = _cli(capsys, "checkpoint", "hash", out)
    assert text.strip() == res.summary["state_hash"]


def test_export_csv_has_the_3d_columns(store3d, tmp_path, capsys):
    out, res = store3d
    s = res.state()
    f = tmp_path / "s.csv"
    rc, _, err = _cli(capsys, "checkpoint", "export", out, "--out", f)
    assert rc == 0, err
    rows = [ln for ln in f.read_text().splitlines() if not ln.startswith("#")]
    header = rows[0].split(",")
    assert header == ["id", "x", "y", "z", "vx", "vy", "vz", "wx", "wy", "wz", "r", "mass", "mat"]
    table = np.array([[float(v) for v in r.split(",")] for r in rows[1:]])
    assert np.array_equal(table[:, 1:4], s["pos"]) and np.array_equal(table[:, 4:7], s["vel"])
    assert np.array_equal(table[:, 7:10], s["spin"]) and np.array_equal(table[:, 10], s["r"])


def test_export_xdmf_read_by_meshio(store3d, tmp_path, capsys):
    meshio = pytest.importorskip("meshio")
    out, res = store3d
    s = res.state()
    f = tmp_path / "s.xdmf"
    assert _cli(capsys, "checkpoint", "export", out, "--out", f)[0] == 0
    m = meshio.read(f)  # the file as written
    assert np.array_equal(m.points, s["pos"]) and s["pos"][:, 2].std() > 0.01
    assert np.array_equal(m.point_data["radius"], s["r"])
    assert np.array_equal(m.point_data["velocity"], s["vel"])
    assert np.array_equal(m.point_data["spin"], s["spin"])


def test_export_vtk_read_by_meshio(store3d, tmp_path, capsys):
    meshio = pytest.importorskip("meshio")
    out, res = store3d
    s = res.state()
    for name in ("s.vtk", "s.vtu"):  # meshio has no VTK XML PolyData (.vtp) reader
        f = tmp_path / name
        assert _cli(capsys, "checkpoint", "export", out, "--out", f)[0] == 0
        m = meshio.read(f)
        assert np.array_equal(m.points, s["pos"]), name
        assert np.array_equal(m.point_data["radius"].ravel(), s["r"]), name
        assert np.array_equal(m.point_data["velocity"], s["vel"]), name
        assert np.array_equal(m.point_data["spin"], s["spin"]), name
        assert m.cells[0].type == "vertex" and len(m.cells[0].data) == len(s["r"]), name


def test_export_vtk_read_by_vtk(store3d, tmp_path, capsys):
    pytest.importorskip("vtkmodules")
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOLegacy import vtkUnstructuredGridReader
    from vtkmodules.vtkIOXML import vtkXMLPolyDataReader, vtkXMLUnstructuredGridReader

    out, res = store3d
    s = res.state()
    for name, reader in (
        ("s.vtk", vtkUnstructuredGridReader()),
        ("s.vtp", vtkXMLPolyDataReader()),
        ("s.vtu", vtkXMLUnstructuredGridReader()),
    ):
        f = tmp_path / name
        assert _cli(capsys, "checkpoint", "export", out, "--out", f)[0] == 0
        reader.SetFileName(str(f))
        if hasattr(reader, "ReadAllFieldsOn"):
            reader.ReadAllFieldsOn()
        reader.Update()
        poly = reader.GetOutput()
        assert np.array_equal(vtk_to_numpy(poly.GetPoints().GetData()), s["pos"]), name
        pd = poly.GetPointData()
        assert np.array_equal(vtk_to_numpy(pd.GetArray("radius")), s["r"]), name
        assert np.array_equal(vtk_to_numpy(pd.GetArray("velocity")), s["vel"]), name
        assert np.array_equal(vtk_to_numpy(pd.GetArray("spin")), s["spin"]), name


def test_domain_sensitivity_runs_share_the_tile_under_the_wheel(capsys):
    """tools/domain_sensitivity.py: every configuration of a seed is made of the base's
    settled tile (the same bed hash), the other seeds of another; tile counts across that
    would put the wheel on another kind of seam are refused with exit code 2."""
    import importlib.util
    from pathlib import Path

    from ooc_dem.model.scenario_check import tile_grid, tile_scenario
    from ooc_dem.model.scenario import load_scenario

    path = Path(__file__).resolve().parents[1] / "tools" / "domain_sensitivity.py"
    spec = importlib.util.spec_from_file_location("domain_sensitivity", path)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    assert [n for n in range(1, 15) if tool.seam_matches_base(n)] == [2, 6, 10, 14]
    base = load_scenario("paper2008-3d")
    configs = tool.configurations([2, 6, 10], [2, 3])
    assert [c[0] for c in configs] == ["base", "across6", "across10", "along3"]
    tiles = {}
    for seed in (2008, 2009):
        for name, across, along in configs:
            sc = load_scenario("paper2008-3d", tool.run_settings(base, [], seed, across, along))
            assert tile_grid(sc) == (along, across)
            assert sc.wheel.z0 == 0.0  # mid-width: on the seam between tiles across/2 - 1 and across/2
            tiles.setdefault(seed, set()).add(tile_scenario(sc).bed_hash())
    assert len(tiles[2008]) == 1 and len(tiles[2009]) == 1 and tiles[2008] != tiles[2009]
    assert tool.main(["--across", "2,4"]) == 2
    assert "2 m with m odd" in capsys.readouterr().err
    assert tool.main(["--scenario", "quick-3d"]) == 2
    assert "tiled bed" in capsys.readouterr().err
