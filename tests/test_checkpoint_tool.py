"""`ooc-dem checkpoint`: export (XDMF + HDF5, VTK, CSV), list, prune and verify; corrupt stores and
a full disk handled through the CLI: fall back to the previous epoch and finish with the same bits,
or stop with one line (exit 2) - never resume from wrong data."""

import os
import resource
import shutil
import signal
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest

from ooc_dem.physics.layout import AX_X, AX_Y, HM_R, HS_T, SP_Z  # noqa: F401

from support.cli import cli_in_process, one_line_error, run_cli
from support.stores import zip_without

STEPS = 120
CKPT = 30
# ooc runs: 3 slabs, an epoch per 10-step sweep (current 120, previous 110 when finished)
OOC = ["--mode", "ooc", "--domains", "3", "--block", "10"]


def _run(out, *extra, scenario="bed-1200", steps=STEPS, ckpt=CKPT, **kw):
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "ooc_dem.cli",
            "run",
            scenario,
            "--out",
            str(out),
            "--steps",
            str(steps),
            "--checkpoint-every",
            str(ckpt),
            "--no-progress",
            "--no-figures",
            *map(str, extra),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        **kw,
    )


def _hash(store):
    return cli_in_process("checkpoint", "hash", store, check=True).stdout.strip()


def _column(p, k):
    """The exported column k of p: the vectors' columns by axis (x, y, vx, vy, w), else the field."""
    cols = {"x": p.pos[:, AX_X], "y": p.pos[:, AX_Y], "vx": p.vel[:, AX_X], "vy": p.vel[:, AX_Y], "w": p.spin[:, SP_Z]}
    return cols[k] if k in cols else getattr(p, k)


def _epoch_data(store, step=None):
    """(Particles sorted by id, wheel_state, step) straight from the store."""
    from ooc_dem.model.checkpoint import read_all_particles
    from ooc_dem.storage import open_store

    with open_store(store, repair=False) as st:
        r = st.read_epoch(step)
        assert not st.warnings, st.warnings
        arrays, attrs = r.read_globals()
        p = read_all_particles(r)
        r.close()
    return p, arrays["wheel_state"], int(attrs["step"])


def _current_path(store):
    import json

    m = json.loads((Path(store) / "MANIFEST.json").read_text())
    return Path(store) / m["current"]["path"], m


def _tree(root):
    return sorted(str(p.relative_to(root)) for p in Path(root).rglob("*"))


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted monolithic run and its `checkpoint hash` (the modes are bit-identical)."""
    out = tmp_path_factory.mktemp("ref") / "run"
    cp = _run(out)
    assert cp.returncode == 0, cp.stderr
    return out, _hash(out)


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    """Finished out-of-core stores (3 domain groups per epoch), built once per backend."""
    made = {}

    def get(backend):
        if backend not in made:
            out = tmp_path_factory.mktemp(f"ooc-{backend}") / "run"
            cp = _run(out, *OOC, "--backend", backend)
            assert cp.returncode == 0, cp.stderr
            made[backend] = out
        return made[backend]

    return get


@pytest.fixture(scope="module")
def wheel_store(tmp_path_factory):
    """A short run of the quick rig (wheel state not zero)."""
    out = tmp_path_factory.mktemp("wheel") / "run"
    cp = _run(out, scenario="quick", steps=60)
    assert cp.returncode == 0, cp.stderr
    return out


# ------------------------------------------------------------------ export


def test_export_xdmf(pristine, tmp_path):
    store = pristine("hdf5")
    p, ws, step = _epoch_data(store)
    out = tmp_path / "snap.xdmf"
    cp = cli_in_process("checkpoint", "export", store, "--format", "xdmf", "--out", out, check=True)
    assert "snap.h5" in cp.stdout
    n = len(p)
    with h5py.File(tmp_path / "snap.h5", "r") as f:
        pos, vel = f["positions"][()], f["velocity"][()]
        assert pos.shape == (n, 3) and vel.shape == (n, 3)
        assert np.array_equal(pos[:, 0], p.pos[:, AX_X]) and np.array_equal(pos[:, 1], p.pos[:, AX_Y])
        assert not pos[:, 2].any() and not vel[:, 2].any()
        assert np.array_equal(vel[:, 0], p.vel[:, AX_X]) and np.array_equal(vel[:, 1], p.vel[:, AX_Y])
        assert np.array_equal(f["radius"][()], p.r)
        assert np.array_equal(f["spin"][()], p.spin[:, SP_Z])
        assert np.array_equal(f["id"][()], p.id)
        assert np.array_equal(f["mass"][()], p.mass)
        assert np.array_equal(f["wheel_state"][()], ws)
        assert int(f.attrs["step"]) == step
    root = ET.parse(out).getroot()
    assert root.tag == "Xdmf" and root.get("Version") == "3.0"
    grid = root.find("Domain/Grid")
    topo = grid.find("Topology")
    assert topo.get("TopologyType") == "Polyvertex" and int(topo.get("NumberOfElements")) == n
    geo = grid.find("Geometry")
    assert geo.get("GeometryType") == "XYZ"
    item = geo.find("DataItem")
    assert item.get("Format") == "HDF" and item.text.strip() == "snap.h5:/positions"
    assert item.get("Dimensions") == f"{n} 3"
    attrs = {a.get("Name"): a for a in grid.findall("Attribute")}
    for name in ("radius", "velocity", "spin", "id"):
        a = attrs[name]
        assert a.get("Center") == "Node"
        assert a.find("DataItem").text.strip() == f"snap.h5:/{name}"
    # the wheel state, step and time are in the HDF5 file (above), not Grid-centred
    # attributes (meshio refuses those)
    assert all(a.get("Center") == "Node" for a in attrs.values())


def test_export_xdmf_read_by_meshio(pristine, tmp_path):
    meshio = pytest.importorskip(
        "meshio", reason="meshio is not installed (pip install meshio): third-party XDMF read-back skipped"
    )
    store = pristine("zarr")
    p, _, _ = _epoch_data(store)
    out = tmp_path / "snap.xdmf"
    cli_in_process("checkpoint", "export", store, "--out", out, check=True)  # format from the suffix
    m = meshio.read(out)  # the file as written
    assert np.array_equal(m.points[:, 0], p.pos[:, AX_X]) and np.array_equal(m.points[:, 1], p.pos[:, AX_Y])
    assert np.array_equal(m.point_data["radius"], p.r)
    assert np.array_equal(m.point_data["id"], p.id)
    assert m.cells[0].type == "vertex" and len(m.cells[0].data) == len(p)


def test_export_csv_round_trip(wheel_store, tmp_path):
    store = wheel_store
    p, ws, step = _epoch_data(store)
    assert ws[0] != 0 and ws[1] != 0
    out = tmp_path / "snap.csv"
    cli_in_process("checkpoint", "export", store, "--format", "csv", "--out", out, check=True)
    lines = out.read_text().splitlines()
    comments = [ln for ln in lines if ln.startswith("#")]
    rows = [ln for ln in lines if not ln.startswith("#")]
    wheel = next(ln for ln in comments if ln.startswith("# wheel_state "))
    vals = dict(kv.split("=") for kv in wheel[len("# wheel_state ") :].split(","))
    assert [float(vals[k]) for k in ("x", "y", "vx", "vy", "theta", "wz")] == list(ws)
    assert any(f"step={step}" in ln for ln in comments)
    header = rows[0].split(",")
    assert header == ["id", "x", "y", "vx", "vy", "w", "r", "mass", "mat"]
    table = [r.split(",") for r in rows[1:]]
    assert len(table) == len(p)
    cols = dict(zip(header, zip(*table)))
    for k in header:
        want = _column(p, k)
        conv = int if want.dtype.kind == "i" else float
        got = np.array([conv(v) for v in cols[k]], dtype=want.dtype)
        assert np.array_equal(got, want), k


def _vtk_legacy_points(path):
    lines = path.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("POINTS "))
    n = int(lines[i].split()[1])
    return np.array([[float(v) for v in ln.split()] for ln in lines[i + 1 : i + 1 + n]]), lines


def test_export_vtk_legacy_and_xml(wheel_store, tmp_path):
    store = wheel_store
    p, ws, step = _epoch_data(store)
    vtk, vtp, vtu = tmp_path / "snap.vtk", tmp_path / "snap.vtp", tmp_path / "snap.vtu"
    cli_in_process("checkpoint", "export", store, "--format", "vtk", "--out", vtk, check=True)
    cli_in_process("checkpoint", "export", store, "--format", "vtk", "--out", vtp, "--epoch", step, check=True)
    cli_in_process("checkpoint", "export", store, "--out", vtu, check=True)  # format from the suffix
    pts, lines = _vtk_legacy_points(vtk)
    assert lines[0] == "# vtk DataFile Version 5.1" and "DATASET UNSTRUCTURED_GRID" in lines
    assert (
        np.array_equal(pts[:, 0], p.pos[:, AX_X]) and np.array_equal(pts[:, 1], p.pos[:, AX_Y]) and not pts[:, 2].any()
    )
    assert f"CELLS {len(p) + 1} {len(p)}" in lines and f"CELL_TYPES {len(p)}" in lines
    assert lines[lines.index("wheel_x 1 1 double") + 1] == repr(float(ws[0]))
    for path, kind in ((vtp, "PolyData"), (vtu, "UnstructuredGrid")):
        root = ET.parse(path).getroot()
        piece = root.find(f"{kind}/Piece")
        xyz = np.array(piece.find("Points/DataArray").text.split(), float).reshape(-1, 3)
        assert np.array_equal(xyz[:, 0], p.pos[:, AX_X]) and np.array_equal(xyz[:, 1], p.pos[:, AX_Y])
        radius = next(a for a in piece.find("PointData") if a.get("Name") == "radius")
        assert np.array_equal(np.array(radius.text.split(), float), p.r)
        field = {a.get("Name"): a.text for a in root.find(f"{kind}/FieldData")}
        assert int(field["step"]) == step and float(field["wheel_theta"]) == ws[4]
    meshio = pytest.importorskip("meshio")
    for path in (vtk, vtu):  # meshio has no VTK XML PolyData (.vtp) reader
        m = meshio.read(path)
        assert np.array_equal(m.points[:, :2], np.c_[p.pos[:, AX_X], p.pos[:, AX_Y]]), path
        assert np.array_equal(m.point_data["radius"].ravel(), p.r) and np.array_equal(m.point_data["id"].ravel(), p.id)
        assert m.cells[0].type == "vertex" and len(m.cells[0].data) == len(p)
    assert float(m.field_data["wheel_theta"][0]) == ws[4]
    try:  # VTK itself, when installed (ParaView's readers)
        from vtkmodules.util.numpy_support import vtk_to_numpy
        from vtkmodules.vtkIOLegacy import vtkUnstructuredGridReader
        from vtkmodules.vtkIOXML import vtkXMLPolyDataReader, vtkXMLUnstructuredGridReader
    except ImportError:
        return
    for reader, path in (
        (vtkUnstructuredGridReader(), vtk),
        (vtkXMLPolyDataReader(), vtp),
        (vtkXMLUnstructuredGridReader(), vtu),
    ):
        reader.SetFileName(str(path))
        reader.Update()
        got = vtk_to_numpy(reader.GetOutput().GetPoints().GetData())
        assert np.array_equal(got[:, :2], np.c_[p.pos[:, AX_X], p.pos[:, AX_Y]]), path
        assert reader.GetOutput().GetNumberOfCells() == len(p), path


def test_export_bad_arguments(reference, tmp_path):
    store, _ = reference
    one_line_error(cli_in_process("checkpoint", "export", store, "--out", tmp_path / "snap.dat"), "--format")
    one_line_error(
        cli_in_process("checkpoint", "export", store, "--format", "xdmf", "--out", tmp_path / "s.h5"), "s.h5"
    )
    one_line_error(
        cli_in_process("checkpoint", "export", store, "--out", tmp_path / "s.csv", "--epoch", "7"), "epoch 7"
    )
    one_line_error(
        cli_in_process("checkpoint", "export", store, "--out", tmp_path / "nodir" / "s.csv"), "does not exist"
    )
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------ list, prune


def test_list_and_prune(pristine, tmp_path):
    store = tmp_path / "run"
    shutil.copytree(pristine("hdf5"), store)
    h = _hash(store)
    cp = cli_in_process("checkpoint", "list", store, check=True)
    lines = cp.stdout.splitlines()
    assert len(lines) == 2 and "(previous)" in lines[0] and "(current)" in lines[1]
    assert "epoch        110" in lines[0] and "discs 1200" in lines[1]
    cp = cli_in_process("checkpoint", "prune", store, "--keep", "2", check=True)
    assert "nothing to remove" in cp.stdout
    cp = cli_in_process("checkpoint", "prune", store, "--keep", "1", check=True)
    assert "removed epoch 110" in cp.stdout and "kept epochs [120]" in cp.stdout
    assert sorted(os.listdir(store / "epochs")) == ["e000000000120.h5"]
    cp = cli_in_process("checkpoint", "verify", store)
    assert cp.returncode == 0 and "OK" in cp.stdout, cp.stdout + cp.stderr
    assert _hash(store) == h
    assert len(cli_in_process("checkpoint", "list", store, check=True).stdout.splitlines()) == 1
    one_line_error(cli_in_process("checkpoint", "prune", store, "--keep", "0"), "--keep")


def test_prune_refuses_to_drop_the_fallback_of_a_damaged_epoch(pristine, tmp_path):
    store = tmp_path / "run"
    shutil.copytree(pristine("hdf5"), store)
    cur, _ = _current_path(store)
    _flip_byte(cur)
    before = _tree(store)
    one_line_error(cli_in_process("checkpoint", "prune", store, "--keep", "1"), "refusing to prune", "120")
    assert _tree(store) == before
    cp = cli_in_process("checkpoint", "list", store, check=True)  # list still works on a damaged store
    assert "(previous)" in cp.stdout and "(current)" in cp.stdout


# ------------------------------------------------------------------ corruption


def _flip_byte(path, where=0.5):
    size = os.path.getsize(path)
    with open(path, "r+b") as f:
        f.seek(int(size * where))
        b = f.read(1)
        f.seek(int(size * where))
        f.write(bytes([b[0] ^ 0xFF]))


def _chunk_file(epoch_dir):
    """The file holding the positions of domain 0: a zarr epoch's archive (one file), or in
    the directory layout the chunk (zarr v3 key c/0/0: one chunk of a 2-D array)."""
    if Path(epoch_dir).is_file():
        return Path(epoch_dir)
    p = Path(epoch_dir) / "domains" / "d0000" / "pos" / "c" / "0" / "0"
    assert p.is_file(), sorted(map(str, Path(epoch_dir).rglob("*")))[:20]
    return p


def _running(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _dead_pid():
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def corrupt(store, backend, kind):
    cur, m = _current_path(store)
    prev = Path(store) / m["previous"]["path"]
    if kind == "truncate":
        target = cur if backend == "hdf5" else _chunk_file(cur)
        with open(target, "r+b") as f:
            f.truncate(os.path.getsize(target) // 2)
    elif kind == "flip":
        _flip_byte(cur if backend == "hdf5" else _chunk_file(cur))
    elif kind == "delete_group":
        if backend == "hdf5":
            with h5py.File(cur, "r+", locking=False) as f:
                del f["domains/d0001"]
        elif cur.is_file():
            zip_without(cur, "domains/d0001/")
        else:
            shutil.rmtree(cur / "domains" / "d0001")
    elif kind == "delete_manifest":
        os.unlink(Path(store) / "MANIFEST.json")
    elif kind == "stray_tmp":  # left by a killed writer (pid 123, or another pid that is not running)
        pid = 123 if not _running(123) else _dead_pid()
        e = Path(store) / "epochs"
        (e / f"e000000000130.{'h5' if backend == 'hdf5' else 'zarr'}.tmp-{pid}").write_bytes(b"\0" * 999)
        (e / f"e000000000120.r1.zarr.tmp-{pid}").mkdir()
        (e / f"e000000000120.r1.zarr.tmp-{pid}" / "zarr.json").write_text("{")
        (Path(store) / "MANIFEST.json.tmp").write_text('{"half": ')
    elif kind == "both_epochs":
        _flip_byte(cur if backend == "hdf5" else _chunk_file(cur))
        _flip_byte(prev if backend == "hdf5" else _chunk_file(prev), where=0.3)
    else:
        raise ValueError(kind)
    return cur, prev


KINDS = ["truncate", "flip", "delete_group", "delete_manifest", "stray_tmp", "both_epochs"]
PROBLEM = {
    "truncate": "truncated",
    "flip": "xxh3_128 mismatch",
    "delete_group": None,
    "both_epochs": "xxh3_128 mismatch",
}


@pytest.mark.parametrize("backend", ["hdf5", "zarr"])
@pytest.mark.parametrize("kind", KINDS)
def test_corrupt_store_verify_and_resume(reference, pristine, tmp_path, backend, kind):
    _, ref_hash = reference
    store = tmp_path / "run"
    shutil.copytree(pristine(backend), store)
    cur, prev = corrupt(store, backend, kind)

    cp = cli_in_process("checkpoint", "verify", store)
    if kind == "delete_manifest":
        one_line_error(cp, "MANIFEST.json missing")
    elif kind == "stray_tmp":
        assert cp.returncode == 0, cp.stdout + cp.stderr
        warned = [ln for ln in cp.stdout.splitlines() if ln.startswith("warning:")]
        assert len(warned) == 3 and all("leftover" in ln for ln in warned), cp.stdout
    else:
        assert cp.returncode == 2 and "Traceback" not in cp.stderr, cp.stdout + cp.stderr
        fails = [ln for ln in cp.stdout.splitlines() if ln.startswith("FAIL ")]
        assert fails and all(str(cur) in ln for ln in fails if "epoch 120:" in ln), cp.stdout
        assert any("epoch 120:" in ln for ln in fails), cp.stdout
        if kind == "both_epochs":
            assert any("epoch 110:" in ln and str(prev) in ln for ln in fails), cp.stdout
        if PROBLEM.get(kind):
            assert any(PROBLEM[kind] in ln for ln in fails), cp.stdout
        if kind == "delete_group":
            assert any("d0001" in ln for ln in fails), cp.stdout
        one_line_error(
            cp, "problem(s) found", "no intact epoch" if kind == "both_epochs" else "falls back to epoch 110"
        )

    before = _tree(store)
    cp = run_cli("resume", store, "--no-progress", "--no-figures")
    if kind == "delete_manifest":  # nothing names an intact epoch: stop, touch nothing
        one_line_error(cp, "MANIFEST.json")
        assert _tree(store) == before
        return
    if kind == "both_epochs":
        one_line_error(cp, "epoch 120 is corrupt", "previous epoch 110 too")
        assert _tree(store) == before
        return
    assert cp.returncode == 0, cp.stderr
    assert "Traceback" not in cp.stderr
    if kind == "stray_tmp":
        assert "already finished" in cp.stdout
        assert not [n for n in os.listdir(store / "epochs") if ".tmp-" in n]
        assert not (store / "MANIFEST.json.tmp").exists()
    else:  # fell back to the previous epoch, said so, and recomputed the last sweep
        assert "using previous epoch 110" in cp.stderr, cp.stderr
    assert _hash(store) == ref_hash
    cp = cli_in_process("checkpoint", "verify", store)
    assert cp.returncode == 0 and "warning" not in cp.stdout, cp.stdout + cp.stderr


# ------------------------------------------------------------------ full disk

# the quick rig with one series row per step: the wheel's series is part of every epoch, so an
# epoch grows by one row (104 bytes) per step and a file-size limit can fall between two epochs
FULL = ["--set", "output.series_interval=1e-5"]
FULL_STEPS, FULL_CKPT = 600, 150  # epochs grow by ~15.6 kB from one to the next


def _limit_file_size(nbytes):
    def set_limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, nbytes))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG, not death by signal

    return set_limit


def test_full_disk_stops_cleanly_and_resumes(tmp_path):
    ref = tmp_path / "ref"
    cp = _run(ref, *FULL, scenario="quick", steps=FULL_STEPS, ckpt=FULL_CKPT)
    assert cp.returncode == 0, cp.stderr
    ref_hash = _hash(ref)
    _, m = _current_path(ref)
    size_prev, size_cur = m["previous"]["files"][0]["size"], m["current"]["files"][0]["size"]
    assert (m["previous"]["step"], m["current"]["step"]) == (450, 600)
    assert size_cur - size_prev > 10_000, (size_prev, size_cur)
    # epochs 450 and 600 cannot fit; 300 and before fit with > 15 kB to spare
    limit = size_prev - 1024

    out = tmp_path / "run"
    cp = _run(out, *FULL, scenario="quick", steps=FULL_STEPS, ckpt=FULL_CKPT, preexec_fn=_limit_file_size(limit))
    one_line_error(cp, "disk full or file too large")
    _, m = _current_path(out)
    assert 0 < m["current"]["step"] < FULL_STEPS, m["current"]["step"]
    assert not [n for n in os.listdir(out / "epochs") if ".tmp-" in n]
    cp = cli_in_process("checkpoint", "verify", out)
    assert cp.returncode == 0 and "OK" in cp.stdout, cp.stdout + cp.stderr

    cp = run_cli("resume", out, "--no-progress", "--no-figures")
    assert cp.returncode == 0, cp.stderr
    assert _hash(out) == ref_hash
