"""Export one committed epoch: XDMF 3 (+ HDF5), VTK PolyData (legacy ASCII or XML .vtp), CSV.

Every format holds one point per disc, sorted by id, with the disc's radius,
velocity, spin, id, mass and material, plus the wheel state, the step and the
simulated time:

* ``xdmf``: ``NAME.h5`` beside ``NAME.xdmf``. The HDF5 file holds ``/positions``
  (N x 3, z = 0), ``/velocity`` (N x 3, vz = 0), ``/radius``, ``/spin``, ``/id``,
  ``/mass``, ``/material``, ``/connectivity`` (N x 1, the Polyvertex cells) and
  ``/wheel_state`` (x, y, vx, vy, theta, wz: ``layout.WHEEL_STATE``) with ``step``/``time``
  attributes.
  The XDMF file is one Uniform grid with a Polyvertex topology and node-centred
  attributes; the wheel state, step and time are Grid-centred attributes (field
  data in ParaView's XDMF 3 reader).
* ``vtk``: legacy ASCII ``.vtk`` PolyData (points + VERTICES, POINT_DATA, dataset
  FIELD data for the wheel), or VTK XML PolyData if the file name ends in ``.vtp``.
* ``csv``: ``#`` comment lines (epoch, time, wheel state), a header row
  ``id,x,y,vx,vy,w,r,mass,mat`` (2D; the vector columns named from the axes,
  ``vector_columns(dim)``) and one row per disc; 3D:
  ``id,x,y,z,vx,vy,vz,wx,wy,wz,r,mass,mat``.

3D runs write the same files with real z positions and velocities and the spin as a
3-vector (``spin`` N x 3: an XDMF Vector attribute, a 3-component VTK array): one
point per sphere with its radius (ParaView: Glyph filter, sphere, scale by radius).

Floats are written so that they read back to the same bits (``repr``; HDF5 as
float64). Only the per-disc scalars are read from the store (never the contact
history), domain group by domain group. Files are written under a temporary name
and renamed when complete.
"""
from __future__ import annotations

import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from .atomic import new_temp
from .checkpoint import StateError, check_unique_sorted, validate_globals
from .physics.layout import AXIS_NAMES, WS_NAMES, axes, spin_width
from .state import FIELD_DTYPES

STORE_MANIFEST = "MANIFEST.json"   # its presence marks a directory as an ooc-dem store

FORMATS = ("xdmf", "vtk", "csv")


def vector_columns(dim: int) -> dict[str, list[str]]:
    """Output column names of the state's vectors, from the axes (layout.AXIS_NAMES): 2D
    pos -> x, y; vel -> vx, vy; spin -> w (about z); 3D adds z, vz and spin wx, wy, wz."""
    names = [AXIS_NAMES[a] for a in axes(dim)]
    spin = ["w"] if spin_width(dim) == 1 else ["w" + a for a in AXIS_NAMES]
    return {"pos": names, "vel": ["v" + a for a in names], "spin": spin}


def snapshot_columns(dim: int) -> tuple[str, ...]:
    v = vector_columns(dim)
    return ("id", *v["pos"], *v["vel"], *v["spin"], "r", "mass", "mat")


CSV_COLUMNS = snapshot_columns(2)   # id, x, y, vx, vy, w, r, mass, mat
WHEEL_NAMES = WS_NAMES               # layout.WHEEL_STATE: x, y, vx, vy, theta, wz
_SUFFIX_FORMAT = {".xdmf": "xdmf", ".xmf": "xdmf", ".vtk": "vtk", ".vtp": "vtk", ".csv": "csv"}
_ROWS_PER_WRITE = 65536


class ExportError(Exception):
    """An export cannot be written (one-line message)."""


@dataclass
class Snapshot:
    """The exported content of one epoch: per-disc columns sorted by id, wheel, step, time."""
    step: int
    time: float
    cols: dict[str, np.ndarray]
    wheel_state: np.ndarray
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.cols["id"])


def infer_format(out) -> str | None:
    return _SUFFIX_FORMAT.get(Path(out).suffix.lower())


def read_snapshot(reader, source: str = "") -> Snapshot:
    """The columns (``snapshot_columns(dim)``) of every domain group of an epoch reader
    (format 2: see checkpoint.open_epoch), sorted by id."""
    names = ["id", "pos", "vel", "spin", "r", "mass", "mat"]
    parts = [reader.read_domain(d, names) for d in reader.domains()]
    dim = 2
    for p in parts:
        if p["pos"].ndim == 2 and p["pos"].shape[1] in (2, 3):
            dim = p["pos"].shape[1]
            break
    vec = vector_columns(dim)
    cols = {}
    for k in names:
        dt = FIELD_DTYPES[k]
        if k in vec:
            width = len(vec[k])
            for d, p in zip(reader.domains(), parts):
                if p[k].shape != (len(p["id"]), width):
                    raise StateError(f"{source}: epoch {reader.step} domain {d}: array {k!r} has "
                                     f"shape {p[k].shape}, expected ({len(p['id'])}, {width}) "
                                     f"({dim}D)")
            a = (np.concatenate([np.asarray(p[k], dt) for p in parts]) if parts
                 else np.zeros((0, width), dt))
            for c, name in enumerate(vec[k]):
                cols[name] = a[:, c]
        else:
            for d, p in zip(reader.domains(), parts):
                if p[k].shape != (len(p["id"]),):
                    raise StateError(f"{source}: epoch {reader.step} domain {d}: array {k!r} has "
                                     f"shape {p[k].shape}, expected ({len(p['id'])},)")
            cols[k] = (np.concatenate([np.asarray(p[k], dt) for p in parts]) if parts
                       else np.zeros(0, dt))
    cols = {k: cols[k] for k in snapshot_columns(dim)}
    order = np.argsort(cols["id"], kind="stable")
    cols = {k: np.ascontiguousarray(v[order]) for k, v in cols.items()}
    check_unique_sorted(cols["id"], f"{source}: epoch {reader.step}")
    arrays, attrs = reader.read_globals()
    validate_globals(arrays, attrs, f"{source}: epoch {reader.step}")
    info = {"source": str(source), "mode": str(attrs.get("mode", ""))}
    return Snapshot(attrs["step"], float(attrs.get("time", 0.0)), cols,
                    np.asarray(arrays["wheel_state"], np.float64), info)


def export_snapshot(snap: Snapshot, fmt: str, out) -> list[Path]:
    """Write `snap` as `fmt` to `out`; returns the files written."""
    out = Path(out)
    if fmt not in FORMATS:
        raise ExportError(f"--format {fmt!r}: must be one of {', '.join(FORMATS)}")
    check_targets(output_files(fmt, out), out)
    if fmt == "xdmf":
        return _write_xdmf(snap, out)
    if fmt == "vtk":
        return [_write_vtp(snap, out) if out.suffix.lower() == ".vtp" else _write_vtk_legacy(snap, out)]
    return [_write_csv(snap, out)]


def output_files(fmt: str, out: Path) -> list[Path]:
    """Every file an export of `fmt` to `out` writes (XDMF writes its HDF5 data beside it)."""
    out = Path(out)
    if fmt == "xdmf":
        h5 = out.with_suffix(".h5")
        if h5 == out:
            raise ExportError(f"--out {out}: give the .xdmf name; the HDF5 data is written beside it "
                              f"as {out.stem}.h5")
        return [out, h5]
    return [out]


def check_targets(files: list[Path], out: Path) -> None:
    """Refuse to write anywhere but a new path or an existing regular file outside every store.

    An export replaces its targets, so a target that is a directory, a device, a FIFO or a
    symlink, or that lies inside an ooc-dem store (a directory holding MANIFEST.json, at any
    depth above the target), is refused: an export must never replace a store's manifest or
    epochs, nor a system file such as /dev/null.
    """
    for f in files:
        try:
            st = os.lstat(f)
        except FileNotFoundError:
            st = None
        except OSError as e:
            raise ExportError(f"--out {out}: cannot inspect {f} ({e.strerror})") from None
        if st is not None and not stat.S_ISREG(st.st_mode):
            kind = "a directory" if stat.S_ISDIR(st.st_mode) else (
                "a symlink" if stat.S_ISLNK(st.st_mode) else "not a regular file")
            raise ExportError(f"--out {out}: {f} is {kind} (give a new file name or a regular file)")
        parent = f.parent.resolve()
        if not parent.is_dir():
            raise ExportError(f"--out {out}: directory {f.parent} does not exist")
        for d in (parent, *parent.parents):
            if (d / STORE_MANIFEST).exists():
                raise ExportError(f"--out {out}: {f} would be inside the ooc-dem store {d} "
                                  f"(write exports outside any store)")


# ------------------------------------------------------------------ helpers

class _Atomic:
    """Open `path` for writing under a temporary name; renamed into place on success.

    The temporary comes from ``atomic.new_temp`` (exclusive, unpredictable name).
    """

    def __init__(self, path: Path, mode: str = "w"):
        self.path = Path(path)
        self.mode = mode
        self.tmp = None
        self.f = None

    def __enter__(self):
        try:
            self.tmp = new_temp(self.path)
            self.f = open(self.tmp, self.mode, encoding=None if "b" in self.mode else "ascii",
                          newline=None if "b" in self.mode else "\n")
        except OSError as e:
            if self.tmp is not None:
                _unlink(self.tmp)
            raise ExportError(_oserror(self.path, e)) from None
        return self.f

    def __exit__(self, exc_type, exc, tb):
        try:
            self.f.close()
            if exc_type is None:
                os.replace(self.tmp, self.path)
        except OSError as e:
            _unlink(self.tmp)
            raise ExportError(_oserror(self.path, e)) from None
        if exc_type is not None:
            _unlink(self.tmp)
            if issubclass(exc_type, OSError):
                raise ExportError(_oserror(self.path, exc)) from None
        return False


def _unlink(p) -> None:
    try:
        os.unlink(p)
    except FileNotFoundError:
        pass


def _oserror(path, e: BaseException) -> str:
    detail = getattr(e, "strerror", None) or " ".join(str(e).split()) or type(e).__name__
    return f"{path}: cannot write ({detail})"


def _fmt(a: np.ndarray) -> list[str]:
    """Text of each value that reads back to the same bits (repr of Python floats/ints)."""
    return [repr(v) for v in a.tolist()] if a.dtype.kind == "f" else [str(v) for v in a.tolist()]


def _write_columns(f, columns: list[np.ndarray], sep: str) -> None:
    """One line per row, the columns' values joined by sep (in slices, to bound memory)."""
    n = len(columns[0]) if columns else 0
    for s in range(0, n, _ROWS_PER_WRITE):
        texts = [_fmt(c[s:s + _ROWS_PER_WRITE]) for c in columns]
        f.write("".join(sep.join(row) + "\n" for row in zip(*texts)))


def _field_items(snap: Snapshot) -> list[tuple[str, str, str]]:
    """(name, kind "f"|"i", text) of the per-epoch values (field data)."""
    items = [("step", "i", str(snap.step)), ("time", "f", repr(float(snap.time)))]
    items += [(f"wheel_{n}", "f", repr(float(v))) for n, v in zip(WHEEL_NAMES, snap.wheel_state)]
    return items


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _description(snap: Snapshot) -> str:
    return _one_line(f"ooc-dem epoch {snap.step} t = {snap.time!r} s, {len(snap)} discs"
                     + (f", from {snap.info['source']}" if snap.info.get("source") else ""))


def _xml_comment(text: str) -> str:
    return escape(text).replace("--", "- -")


def _xyz(c: dict, prefix: str = "") -> list[np.ndarray]:
    """The x, y, z columns of a vector (zeros for an axis the run does not have)."""
    n = len(c["id"])
    return [c.get(prefix + a, np.zeros(n)) for a in AXIS_NAMES]


def _xyz_array(c: dict, prefix: str = "") -> np.ndarray:
    return np.stack(_xyz(c, prefix), axis=1).astype(np.float64)


def _spin(c: dict) -> list[np.ndarray]:
    """The spin's columns: [w] (2D, about z) or [wx, wy, wz] (3D)."""
    return [c["w"]] if "w" in c else [c["w" + a] for a in AXIS_NAMES]


def _spin_array(c: dict) -> np.ndarray:
    """The spin as written: (N,) in 2D, (N, 3) in 3D."""
    cols = _spin(c)
    return cols[0] if len(cols) == 1 else np.stack(cols, axis=1).astype(np.float64)


# ------------------------------------------------------------------ XDMF + HDF5

def _write_xdmf(snap: Snapshot, out: Path) -> list[Path]:
    import h5py
    _, h5 = output_files("xdmf", out)
    if ":" in h5.name:
        raise ExportError(f"--out {out}: the file name must not contain ':' (XDMF HDF references)")
    c, n = snap.cols, len(snap)
    data = {
        "positions": _xyz_array(c),
        "velocity": _xyz_array(c, "v"),
        "radius": c["r"], "spin": _spin_array(c), "id": c["id"], "mass": c["mass"], "material": c["mat"],
        "connectivity": np.arange(n, dtype=np.int64).reshape(n, 1),
    }
    try:
        tmp = new_temp(h5)
    except OSError as e:
        raise ExportError(_oserror(h5, e)) from None
    try:
        with h5py.File(tmp, "w") as f:
            for k, v in data.items():
                f.create_dataset(k, data=v)
            ws = f.create_dataset("wheel_state", data=np.asarray(snap.wheel_state, np.float64))
            ws.attrs["components"] = ",".join(WHEEL_NAMES)
            f.attrs["step"] = np.int64(snap.step)
            f.attrs["time"] = np.float64(snap.time)
            f.attrs["description"] = _description(snap)
        os.replace(tmp, h5)
    except OSError as e:
        _unlink(tmp)
        raise ExportError(_oserror(h5, e)) from None

    def item(name, dims, kind, size):
        typ = "Int" if kind in "iu" else "Float"
        return (f'<DataItem Dimensions="{dims}" DataType="{typ}" Precision="{size}" '
                f'Format="HDF">{escape(h5.name)}:/{name}</DataItem>')

    lines = ['<?xml version="1.0" ?>',
             f"<!-- {_xml_comment(_description(snap))} -->",
             '<Xdmf Version="3.0">',
             "  <Domain>",
             '    <Grid Name="discs" GridType="Uniform">',
             f'      <Topology TopologyType="Polyvertex" NumberOfElements="{n}" NodesPerElement="1">',
             f"        {item('connectivity', f'{n} 1', 'i', 8)}",
             "      </Topology>",
             '      <Geometry GeometryType="XYZ">',
             f"        {item('positions', f'{n} 3', 'f', 8)}",
             "      </Geometry>"]
    for name, atype in (("radius", "Scalar"), ("velocity", "Vector"), ("spin", "Scalar"),
                        ("id", "Scalar"), ("mass", "Scalar"), ("material", "Scalar")):
        a = data[name]
        if a.ndim == 2:
            atype = "Vector"
        dims = f"{n} 3" if a.ndim == 2 else f"{n}"
        lines += [f'      <Attribute Name="{name}" AttributeType="{atype}" Center="Node">',
                  f"        {item(name, dims, a.dtype.kind, a.dtype.itemsize)}",
                  "      </Attribute>"]
    # per-epoch values: Grid-centred attributes = field data in ParaView's XDMF 3 reader
    for name, kind, text in _field_items(snap):
        typ = "Int" if kind == "i" else "Float"
        lines += [f'      <Attribute Name="{name}" AttributeType="Scalar" Center="Grid">',
                  f'        <DataItem Dimensions="1" DataType="{typ}" Precision="8" Format="XML">'
                  f"{text}</DataItem>",
                  "      </Attribute>"]
    lines += ["    </Grid>", "  </Domain>", "</Xdmf>", ""]
    with _Atomic(out) as f:
        f.write("\n".join(lines))
    return [out, h5]


# ------------------------------------------------------------------ VTK

def _vtk_legacy_type(a: np.ndarray) -> str:
    if a.dtype.kind == "f":
        return "double"
    if a.size and (int(a.max()) > np.iinfo(np.int32).max or int(a.min()) < np.iinfo(np.int32).min):
        return "vtktypeint64"
    return "int"


def _write_vtk_legacy(snap: Snapshot, out: Path) -> Path:
    c, n = snap.cols, len(snap)
    with _Atomic(out) as f:
        f.write("# vtk DataFile Version 4.2\n")
        f.write(_description(snap)[:255] + "\n")
        f.write("ASCII\nDATASET POLYDATA\n")
        items = _field_items(snap)
        f.write(f"FIELD FieldData {len(items)}\n")
        for name, kind, text in items:
            f.write(f"{name} 1 1 {'vtktypeint64' if kind == 'i' else 'double'}\n{text}\n")
        f.write(f"POINTS {n} double\n")
        _write_columns(f, _xyz(c), " ")
        f.write(f"VERTICES {n} {2 * n}\n")
        _write_columns(f, [np.ones(n, np.int64), np.arange(n, dtype=np.int64)], " ")
        f.write(f"POINT_DATA {n}\n")
        f.write("SCALARS radius double 1\nLOOKUP_TABLE default\n")
        _write_columns(f, [c["r"]], " ")
        f.write("VECTORS velocity double\n")
        _write_columns(f, _xyz(c, "v"), " ")
        # further point arrays as a FIELD block: a legacy reader keeps only the first SCALARS
        # unless told to read them all, but always reads every FIELD array
        more = (("spin", _spin(c)), ("id", [c["id"]]), ("mass", [c["mass"]]),
                ("material", [c["mat"]]))
        f.write(f"FIELD point_arrays {len(more)}\n")
        for name, cols in more:
            f.write(f"{name} {len(cols)} {n} {_vtk_legacy_type(cols[0])}\n")
            _write_columns(f, cols, " ")
    return out


_VTP_TYPE = {"f8": "Float64", "i8": "Int64", "i4": "Int32"}


def _vtp_array(f, name, a: np.ndarray, ncomp: int = 1, columns=None, indent="        ") -> None:
    t = _VTP_TYPE[f"{a.dtype.kind}{a.dtype.itemsize}"]
    nm = f' Name="{name}"' if name else ""
    f.write(f'{indent}<DataArray type="{t}"{nm} NumberOfComponents="{ncomp}" format="ascii">\n')
    _write_columns(f, columns if columns is not None else [a], " ")
    f.write(f"{indent}</DataArray>\n")


def _write_vtp(snap: Snapshot, out: Path) -> Path:
    c, n = snap.cols, len(snap)
    with _Atomic(out) as f:
        f.write('<?xml version="1.0"?>\n')
        f.write(f"<!-- {_xml_comment(_description(snap))} -->\n")
        f.write('<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" '
                'header_type="UInt64">\n  <PolyData>\n    <FieldData>\n')
        for name, kind, text in _field_items(snap):
            t = "Int64" if kind == "i" else "Float64"
            f.write(f'      <DataArray type="{t}" Name={quoteattr(name)} NumberOfTuples="1" '
                    f'format="ascii">{text}</DataArray>\n')
        f.write("    </FieldData>\n")
        f.write(f'    <Piece NumberOfPoints="{n}" NumberOfVerts="{n}" NumberOfLines="0" '
                f'NumberOfStrips="0" NumberOfPolys="0">\n')
        f.write('      <PointData Scalars="radius" Vectors="velocity">\n')
        for name, a in (("radius", c["r"]), ("id", c["id"]), ("mass", c["mass"]),
                        ("material", c["mat"])):
            _vtp_array(f, name, a)
        spin = _spin(c)
        _vtp_array(f, "spin", spin[0], len(spin), spin)
        _vtp_array(f, "velocity", c["vx"], 3, _xyz(c, "v"))
        f.write("      </PointData>\n      <Points>\n")
        _vtp_array(f, "positions", c["x"], 3, _xyz(c))
        f.write("      </Points>\n      <Verts>\n")
        _vtp_array(f, "connectivity", np.arange(n, dtype=np.int64))
        _vtp_array(f, "offsets", np.arange(1, n + 1, dtype=np.int64))
        f.write("      </Verts>\n    </Piece>\n  </PolyData>\n</VTKFile>\n")
    return out


# ------------------------------------------------------------------ CSV

def _write_csv(snap: Snapshot, out: Path) -> Path:
    with _Atomic(out) as f:
        f.write(f"# {_description(snap)}\n")
        f.write(f"# step={snap.step} time={float(snap.time)!r}\n")
        f.write("# wheel_state " + ",".join(f"{k}={float(v)!r}" for k, v in
                                            zip(WHEEL_NAMES, snap.wheel_state)) + "\n")
        f.write(",".join(snap.cols) + "\n")
        _write_columns(f, list(snap.cols.values()), ",")
    return out
