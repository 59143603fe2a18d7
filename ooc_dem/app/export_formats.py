"""The export formats (export.py's module docstring describes them): a ``Snapshot`` (the
exported content of one epoch, in id order) written as XDMF (+ HDF5), VTK (legacy .vtk, XML
.vtu or .vtp) or CSV, each under a temporary name (``outfile.AtomicFile``)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import IO, Any, Literal, TypeAlias
from xml.sax.saxutils import escape, quoteattr

import numpy as np
from numpy.typing import NDArray


from ..physics.layout import AXIS_NAMES, WS_NAMES, axes, spin_width
from ..model.state import FIELD_DTYPES
from .outfile import AtomicFile, ExportError, write_h5_replacing

# a slice of a snapshot: its columns by name (snapshot_columns)
Chunk: TypeAlias = dict[str, NDArray[Any]]
# the arrays a text writer puts on each line, from a slice (its first row, its columns)
ColumnsOf: TypeAlias = Callable[[int, Chunk], Sequence[NDArray[Any]]]


def vector_columns(dim: int) -> dict[str, list[str]]:
    """Output column names of the state's vectors, from the axes (layout.AXIS_NAMES): 2D
    pos -> x, y; vel -> vx, vy; spin -> w (about z); 3D adds z, vz and spin wx, wy, wz."""
    names = [AXIS_NAMES[a] for a in axes(dim)]
    spin = ["w"] if spin_width(dim) == 1 else ["w" + a for a in AXIS_NAMES]
    return {"pos": names, "vel": ["v" + a for a in names], "spin": spin}


def snapshot_columns(dim: int) -> tuple[str, ...]:
    v = vector_columns(dim)
    return ("id", *v["pos"], *v["vel"], *v["spin"], "r", "mass", "mat")


WHEEL_NAMES = WS_NAMES  # layout.WHEEL_STATE: x, y, vx, vy, theta, wz
_ROWS_PER_WRITE = 65536


class Snapshot:
    """The exported content of one epoch, sorted by id, held in a temporary file.

    Built by ``export.read_snapshot``; the writers read it back in slices (``chunks``), so an
    export holds a few slices in RAM whatever the number of discs. Close it (or use it as
    a context manager) to free the temporary file; it is unnamed, so even a killed export
    leaves nothing behind.
    """

    def __init__(
        self,
        step: int,
        time: float,
        wheel_state: NDArray[np.float64],
        info: dict[str, str],
        dim: int,
        records: IO[bytes],
        n: int,
        int_ranges: dict[str, tuple[int, int]],
    ) -> None:
        self.step = step
        self.time = time
        self.wheel_state = wheel_state
        self.info = info
        self.dim = dim
        self.columns = snapshot_columns(dim)
        self.dtype = record_dtype(dim)
        self._records = records  # an unnamed temporary file of n records, id order
        self._n = n
        self.int_ranges = int_ranges  # integer column -> (min, max) over every disc

    def __len__(self) -> int:
        return self._n

    def chunks(self, rows: int | None = None) -> Iterator[tuple[int, Chunk]]:
        """(first row, {column: array}) of consecutive slices of at most `rows` discs."""
        rows = rows or _ROWS_PER_WRITE
        for start in range(0, self._n, rows):
            rec = read_records(self._records, self.dtype, start, min(rows, self._n - start))
            yield start, {k: rec[k] for k in self.columns}

    def close(self) -> None:
        self._records.close()

    def __enter__(self) -> Snapshot:
        return self

    def __exit__(self, *exc: object) -> Literal[False]:
        self.close()
        return False


def record_dtype(dim: int) -> np.dtype[np.void]:
    """One exported disc: the snapshot's columns with the state's dtypes."""
    vec = vector_columns(dim)
    of = {name: FIELD_DTYPES[k] for k, names in vec.items() for name in names}
    return np.dtype([(c, of.get(c, FIELD_DTYPES.get(c))) for c in snapshot_columns(dim)])


def read_records(f: IO[bytes], dtype: np.dtype[np.void], start: int, count: int) -> NDArray[np.void]:
    size = dtype.itemsize
    buf = bytearray(count * size)
    view, done = memoryview(buf), 0
    while done < len(buf):
        got = os.preadv(f.fileno(), [view[done:]], (start * size) + done)
        if got == 0:
            raise ExportError(f"{f.name}: temporary export file ended early")
        done += got
    return np.frombuffer(buf, dtype)


def output_files(fmt: str, out: Path) -> list[Path]:
    """Every file an export of `fmt` to `out` writes (XDMF writes its HDF5 data beside it)."""
    out = Path(out)
    if fmt == "xdmf":
        h5 = out.with_suffix(".h5")
        if h5 == out:
            raise ExportError(f"--out {out}: give the .xdmf name; the HDF5 data is written beside it as {out.stem}.h5")
        return [out, h5]
    return [out]


def write_snapshot(snap: Snapshot, fmt: str, out: Path) -> list[Path]:
    """Write `snap` as `fmt` ("xdmf", "vtk", "csv") to `out`; returns the files written."""
    if fmt == "xdmf":
        return _write_xdmf(snap, out)
    if fmt == "vtk":
        xml = out.suffix.lower() in (".vtp", ".vtu")
        return [_write_vtk_xml(snap, out) if xml else _write_vtk_legacy(snap, out)]
    return [_write_csv(snap, out)]


def _fmt(a: np.ndarray) -> list[str]:
    """Text of each value that reads back to the same bits (repr of Python floats/ints)."""
    return [repr(v) for v in a.tolist()] if a.dtype.kind == "f" else [str(v) for v in a.tolist()]


def _write_columns(f: IO[str], snap: Snapshot, columns_of: ColumnsOf, sep: str) -> None:
    """One line per disc (id order): the arrays ``columns_of(first_row, chunk)`` gives for
    each slice of the snapshot, their values joined by sep."""
    for start, chunk in snap.chunks():
        texts = [_fmt(c) for c in columns_of(start, chunk)]
        f.write("".join(sep.join(row) + "\n" for row in zip(*texts)))


def _columns(names: Sequence[str]) -> ColumnsOf:
    """The columns ``names`` of each slice, in that order."""
    return lambda s, c: [c[k] for k in names]


def _index(start: int, chunk: Chunk) -> NDArray[np.int64]:
    """The rows' positions in the export (0-based), for connectivity."""
    return np.arange(start, start + len(chunk["id"]), dtype=np.int64)


def _field_items(snap: Snapshot) -> list[tuple[str, str, str]]:
    """(name, kind "f"|"i", text) of the per-epoch values (field data)."""
    items = [("step", "i", str(snap.step)), ("time", "f", repr(float(snap.time)))]
    items += [(f"wheel_{n}", "f", repr(float(v))) for n, v in zip(WHEEL_NAMES, snap.wheel_state)]
    return items


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _description(snap: Snapshot) -> str:
    return _one_line(
        f"ooc-dem epoch {snap.step} t = {snap.time!r} s, {len(snap)} discs"
        + (f", from {snap.info['source']}" if snap.info.get("source") else "")
    )


def _xml_comment(text: str) -> str:
    return escape(text).replace("--", "- -")


def _xyz(c: Chunk, prefix: str = "") -> list[NDArray[Any]]:
    """The x, y, z columns of a vector (zeros for an axis the run does not have)."""
    n = len(c["id"])
    return [c.get(prefix + a, np.zeros(n)) for a in AXIS_NAMES]


def _xyz_array(c: Chunk, prefix: str = "") -> NDArray[np.float64]:
    return np.stack(_xyz(c, prefix), axis=1).astype(np.float64)


def _spin(c: Chunk) -> list[NDArray[Any]]:
    """The spin's columns: [w] (2D, about z) or [wx, wy, wz] (3D)."""
    return [c["w"]] if "w" in c else [c["w" + a] for a in AXIS_NAMES]


def _spin_array(c: Chunk) -> NDArray[Any]:
    """The spin as written: (N,) in 2D, (N, 3) in 3D."""
    cols = _spin(c)
    return cols[0] if len(cols) == 1 else np.stack(cols, axis=1).astype(np.float64)


# ------------------------------------------------------------------ XDMF + HDF5


def _write_xdmf(snap: Snapshot, out: Path) -> list[Path]:
    _, h5 = output_files("xdmf", out)
    if ":" in h5.name:
        raise ExportError(f"--out {out}: the file name must not contain ':' (XDMF HDF references)")
    n = len(snap)
    # each dataset from a slice of the snapshot (rows first..): written slice by slice
    data: dict[str, Callable[[int, Chunk], NDArray[Any]]] = {
        "positions": lambda s, c: _xyz_array(c),
        "velocity": lambda s, c: _xyz_array(c, "v"),
        "radius": lambda s, c: c["r"],
        "spin": lambda s, c: _spin_array(c),
        "id": lambda s, c: c["id"],
        "mass": lambda s, c: c["mass"],
        "material": lambda s, c: c["mat"],
        "connectivity": lambda s, c: _index(s, c).reshape(-1, 1),
    }
    spin_shape = (n,) if spin_width(snap.dim) == 1 else (n, 3)
    shapes = {"positions": (n, 3), "velocity": (n, 3), "spin": spin_shape, "connectivity": (n, 1)}
    dtypes = {"id": snap.dtype["id"], "material": snap.dtype["mat"], "connectivity": np.dtype(np.int64)}

    def fill(f: Any, guard: Any) -> None:
        sets = {
            k: f.create_dataset(k, shape=shapes.get(k, (n,)), dtype=dtypes.get(k, np.dtype(np.float64))) for k in data
        }
        for start, chunk in snap.chunks():
            for k, of in data.items():
                v = of(start, chunk)
                sets[k][start : start + len(v)] = v
            guard.check()  # stop at the first failed write
        ws = f.create_dataset("wheel_state", data=np.asarray(snap.wheel_state, np.float64))
        ws.attrs["components"] = ",".join(WHEEL_NAMES)
        f.attrs["step"] = np.int64(snap.step)
        f.attrs["time"] = np.float64(snap.time)
        f.attrs["description"] = _description(snap)

    write_h5_replacing(h5, fill)

    def item(name: str, dims: str, kind: str, size: int) -> str:
        typ = "Int" if kind in "iu" else "Float"
        return (
            f'<DataItem Dimensions="{dims}" DataType="{typ}" Precision="{size}" '
            f'Format="HDF">{escape(h5.name)}:/{name}</DataItem>'
        )

    lines = [
        '<?xml version="1.0" ?>',
        f"<!-- {_xml_comment(_description(snap))} -->",
        '<Xdmf Version="3.0">',
        "  <Domain>",
        '    <Grid Name="discs" GridType="Uniform">',
        f'      <Topology TopologyType="Polyvertex" NumberOfElements="{n}" NodesPerElement="1">',
        f"        {item('connectivity', f'{n} 1', 'i', 8)}",
        "      </Topology>",
        '      <Geometry GeometryType="XYZ">',
        f"        {item('positions', f'{n} 3', 'f', 8)}",
        "      </Geometry>",
    ]
    for name in ("radius", "velocity", "spin", "id", "mass", "material"):
        shape, dt = shapes.get(name, (n,)), dtypes.get(name, np.dtype(np.float64))
        atype = "Vector" if len(shape) == 2 else "Scalar"
        dims = " ".join(map(str, shape))
        lines += [
            f'      <Attribute Name="{name}" AttributeType="{atype}" Center="Node">',
            f"        {item(name, dims, dt.kind, dt.itemsize)}",
            "      </Attribute>",
        ]
    # the per-epoch values (step, time, wheel state) stay in the HDF5 file (/wheel_state and
    # its attributes) and the comment above: as Grid-centred attributes (field data to
    # ParaView) they would make the file unreadable to meshio, which refuses that centre
    lines += ["    </Grid>", "  </Domain>", "</Xdmf>", ""]
    with AtomicFile(out) as f:
        f.write("\n".join(lines))
    return [out, h5]


# ------------------------------------------------------------------ VTK


def _vtk_legacy_type(snap: Snapshot, column: str) -> str:
    if snap.dtype[column].kind == "f":
        return "double"
    lo, hi = snap.int_ranges.get(column, (0, 0))
    if hi > np.iinfo(np.int32).max or lo < np.iinfo(np.int32).min:
        return "vtktypeint64"
    return "int"


def _spin_columns(dim: int) -> list[str]:
    return vector_columns(dim)["spin"]


def _write_vtk_legacy(snap: Snapshot, out: Path) -> Path:
    # version 5.1 (VTK >= 9, ParaView >= 5.9): its cells are offsets + connectivity, and
    # meshio reads it with its 64-bit integer arrays (its 4.2 reader knows no vtktypeint64)
    n = len(snap)
    with AtomicFile(out) as f:
        f.write("# vtk DataFile Version 5.1\n")
        f.write(_description(snap)[:255] + "\n")
        f.write("ASCII\nDATASET UNSTRUCTURED_GRID\n")
        items = _field_items(snap)
        f.write(f"FIELD FieldData {len(items)}\n")
        for name, kind, text in items:
            f.write(f"{name} 1 1 {'vtktypeint64' if kind == 'i' else 'double'}\n{text}\n")
        f.write(f"POINTS {n} double\n")
        _write_columns(f, snap, lambda s, c: _xyz(c), " ")
        # one vertex cell a point
        f.write(f"CELLS {n + 1} {n}\nOFFSETS vtktypeint64\n")
        _write_columns(f, snap, lambda s, c: [_index(s, c)], " ")
        f.write(f"{n}\nCONNECTIVITY vtktypeint64\n")
        _write_columns(f, snap, lambda s, c: [_index(s, c)], " ")
        f.write(f"CELL_TYPES {n}\n")
        _write_columns(f, snap, lambda s, c: [np.ones(len(c["id"]), np.int64)], " ")
        f.write(f"POINT_DATA {n}\n")
        f.write("SCALARS radius double 1\nLOOKUP_TABLE default\n")
        _write_columns(f, snap, lambda s, c: [c["r"]], " ")
        f.write("VECTORS velocity double\n")
        _write_columns(f, snap, lambda s, c: _xyz(c, "v"), " ")
        # further point arrays as a FIELD block: a legacy reader keeps only the first SCALARS
        # unless told to read them all, but always reads every FIELD array
        more = (("spin", _spin_columns(snap.dim)), ("id", ["id"]), ("mass", ["mass"]), ("material", ["mat"]))
        f.write(f"FIELD point_arrays {len(more)}\n")
        for name, cols in more:
            f.write(f"{name} {len(cols)} {n} {_vtk_legacy_type(snap, cols[0])}\n")
            _write_columns(f, snap, _columns(cols), " ")
    return out


_VTP_TYPE = {"f8": "Float64", "i8": "Int64", "i4": "Int32", "u1": "UInt8"}


def _vtp_array(
    f: IO[str],
    snap: Snapshot,
    name: str,
    columns_of: ColumnsOf,
    dtype: np.dtype[Any],
    ncomp: int = 1,
    indent: str = "        ",
) -> None:
    t = _VTP_TYPE[f"{dtype.kind}{dtype.itemsize}"]
    nm = f' Name="{name}"' if name else ""
    f.write(f'{indent}<DataArray type="{t}"{nm} NumberOfComponents="{ncomp}" format="ascii">\n')
    _write_columns(f, snap, columns_of, " ")
    f.write(f"{indent}</DataArray>\n")


def _write_vtk_xml(snap: Snapshot, out: Path) -> Path:
    """VTK XML: PolyData (.vtp, the points as Verts) or UnstructuredGrid (.vtu, one vertex
    cell a point; meshio reads this one, it has no PolyData reader)."""
    n = len(snap)
    f8, i8 = np.dtype(np.float64), np.dtype(np.int64)
    kind = "UnstructuredGrid" if out.suffix.lower() == ".vtu" else "PolyData"
    with AtomicFile(out) as f:
        f.write('<?xml version="1.0"?>\n')
        f.write(f"<!-- {_xml_comment(_description(snap))} -->\n")
        f.write(
            f'<VTKFile type="{kind}" version="1.0" byte_order="LittleEndian" '
            f'header_type="UInt64">\n  <{kind}>\n    <FieldData>\n'
        )
        for name, kind_of, text in _field_items(snap):
            t = "Int64" if kind_of == "i" else "Float64"
            f.write(
                f'      <DataArray type="{t}" Name={quoteattr(name)} NumberOfTuples="1" '
                f'format="ascii">{text}</DataArray>\n'
            )
        f.write("    </FieldData>\n")
        if kind == "PolyData":
            f.write(
                f'    <Piece NumberOfPoints="{n}" NumberOfVerts="{n}" NumberOfLines="0" '
                f'NumberOfStrips="0" NumberOfPolys="0">\n'
            )
        else:
            f.write(f'    <Piece NumberOfPoints="{n}" NumberOfCells="{n}">\n')
        f.write('      <PointData Scalars="radius" Vectors="velocity">\n')
        for name, col in (("radius", "r"), ("id", "id"), ("mass", "mass"), ("material", "mat")):
            _vtp_array(f, snap, name, _columns([col]), snap.dtype[col])
        spin = _spin_columns(snap.dim)
        _vtp_array(f, snap, "spin", _columns(spin), f8, len(spin))
        _vtp_array(f, snap, "velocity", lambda s, c: _xyz(c, "v"), f8, 3)
        f.write("      </PointData>\n      <Points>\n")
        _vtp_array(f, snap, "positions", lambda s, c: _xyz(c), f8, 3)
        cells = "Verts" if kind == "PolyData" else "Cells"
        f.write(f"      </Points>\n      <{cells}>\n")
        _vtp_array(f, snap, "connectivity", lambda s, c: [_index(s, c)], i8)
        _vtp_array(f, snap, "offsets", lambda s, c: [_index(s, c) + 1], i8)
        if kind == "UnstructuredGrid":
            _vtp_array(f, snap, "types", lambda s, c: [np.ones(len(c["id"]), np.uint8)], np.dtype(np.uint8))
        f.write(f"      </{cells}>\n    </Piece>\n  </{kind}>\n</VTKFile>\n")
    return out


# ------------------------------------------------------------------ CSV


def _write_csv(snap: Snapshot, out: Path) -> Path:
    with AtomicFile(out) as f:
        f.write(f"# {_description(snap)}\n")
        f.write(f"# step={snap.step} time={float(snap.time)!r}\n")
        f.write("# wheel_state " + ",".join(f"{k}={float(v)!r}" for k, v in zip(WHEEL_NAMES, snap.wheel_state)) + "\n")
        f.write(",".join(snap.columns) + "\n")
        _write_columns(f, snap, _columns(snap.columns), ",")
    return out
