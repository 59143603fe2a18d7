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
float64). Only the per-disc columns are read from the store (never the contact
history), domain group by domain group, and sorted by id in bounded memory
(``read_snapshot``: an external merge through unnamed temporary files beside the
output), so a store larger than RAM exports too. Files are written under a
temporary name and renamed when complete.
"""
from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from ooc_dem.storage.writeguard import H5_OVERHEAD, check_room, close_h5, create_h5

from ..storage.atomic import new_temp
from ..model.checkpoint import StateError, check_unique_sorted, validate_globals
from ..physics.layout import AXIS_NAMES, WS_NAMES, axes, spin_width
from ..model.state import FIELD_DTYPES

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


class Snapshot:
    """The exported content of one epoch, sorted by id, held in a temporary file.

    Built by ``read_snapshot``; the writers read it back in slices (``chunks``), so an
    export holds a few slices in RAM whatever the number of discs. Close it (or use it as
    a context manager) to free the temporary file; it is unnamed, so even a killed export
    leaves nothing behind.
    """

    def __init__(self, step, time, wheel_state, info, dim, records, n, int_ranges):
        self.step = step
        self.time = time
        self.wheel_state = wheel_state
        self.info = info
        self.dim = dim
        self.columns = snapshot_columns(dim)
        self.dtype = _record_dtype(dim)
        self._records = records     # an unnamed temporary file of n records, id order
        self._n = n
        self.int_ranges = int_ranges  # integer column -> (min, max) over every disc

    def __len__(self) -> int:
        return self._n

    def chunks(self, rows: int | None = None):
        """(first row, {column: array}) of consecutive slices of at most `rows` discs."""
        rows = rows or _ROWS_PER_WRITE
        for start in range(0, self._n, rows):
            rec = _read_records(self._records, self.dtype, start, min(rows, self._n - start))
            yield start, {k: rec[k] for k in self.columns}

    def close(self) -> None:
        self._records.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def _record_dtype(dim: int) -> np.dtype:
    """One exported disc: the snapshot's columns with the state's dtypes."""
    vec = vector_columns(dim)
    of = {name: FIELD_DTYPES[k] for k, names in vec.items() for name in names}
    return np.dtype([(c, of.get(c, FIELD_DTYPES.get(c))) for c in snapshot_columns(dim)])


def _read_records(f, dtype: np.dtype, start: int, count: int) -> np.ndarray:
    size = dtype.itemsize
    buf = bytearray(count * size)
    view, done = memoryview(buf), 0
    while done < len(buf):
        got = os.preadv(f.fileno(), [view[done:]], (start * size) + done)
        if got == 0:
            raise ExportError(f"{f.name}: temporary export file ended early")
        done += got
    return np.frombuffer(buf, dtype)


def infer_format(out) -> str | None:
    return _SUFFIX_FORMAT.get(Path(out).suffix.lower())


def _group_records(reader, d, source: str, dim: int | None) -> tuple[np.ndarray, int]:
    """One domain group's discs as export records sorted by id (and the dimension)."""
    names = ["id", "pos", "vel", "spin", "r", "mass", "mat"]
    p = reader.read_domain(d, names)
    n = len(p["id"])
    if dim is None:
        pos = p["pos"]
        dim = pos.shape[1] if pos.ndim == 2 and pos.shape[1] in (2, 3) else 2
    vec = vector_columns(dim)
    rec = np.empty(n, _record_dtype(dim))
    for k in names:
        width = len(vec[k]) if k in vec else None
        want = (n, width) if width else (n,)
        if p[k].shape != want:
            raise StateError(f"{source}: epoch {reader.step} domain {d}: array {k!r} has "
                             f"shape {p[k].shape}, expected {want}" + (f" ({dim}D)" if width else ""))
        if width:
            for c, name in enumerate(vec[k]):
                rec[name] = p[k][:, c]
        else:
            rec[k] = p[k]
    del p
    rec = rec[np.argsort(rec["id"], kind="stable")]
    check_unique_sorted(rec["id"], f"{source}: epoch {reader.step}")
    return rec, dim


def _flush(records, out) -> None:
    try:
        records.flush()
    except OSError as e:
        raise ExportError(_oserror(out, e)) from None


def _spill(records, rec: np.ndarray, out) -> None:
    try:
        records.write(rec.tobytes())
    except OSError as e:
        raise ExportError(_oserror(out, e)) from None


def read_snapshot(reader, source: str = "", workdir=".", buffer_bytes: int = 64 << 20) -> Snapshot:
    """The columns (``snapshot_columns(dim)``) of every domain group of an epoch reader
    (format 2: see checkpoint.open_epoch), sorted by id, in bounded memory.

    An external merge sort: each group (one slab) is read, sorted by id and appended to an
    unnamed temporary file in `workdir` as a sorted run; the runs are then merged into a
    second temporary file holding every disc in id order, a few slices of each run in RAM
    at a time (about `buffer_bytes` in all). Repeated ids, within a group or across groups,
    are refused. Disk: twice the records (one copy when the epoch has a single group).
    """
    arrays, attrs = reader.read_globals()
    validate_globals(arrays, attrs, f"{source}: epoch {reader.step}")
    where = f"{source}: epoch {reader.step}"

    def temp():
        try:
            return tempfile.TemporaryFile(dir=workdir)
        except OSError as e:
            raise ExportError(f"{workdir}: cannot create a temporary export file "
                              f"({e.strerror})") from None

    runs_file, runs, dim = temp(), [], None     # runs: (first record, count)
    lo = {"id": None, "mat": None}
    hi = dict(lo)
    try:
        start = 0
        for d in reader.domains():
            rec, dim = _group_records(reader, d, source, dim)
            if len(rec):
                for k in lo:
                    a, b = rec[k].min(), rec[k].max()
                    lo[k] = int(a) if lo[k] is None else min(lo[k], int(a))
                    hi[k] = int(b) if hi[k] is None else max(hi[k], int(b))
                _spill(runs_file, rec, workdir)
                runs.append((start, len(rec)))
                start += len(rec)
            del rec
        dim = dim or 2
        dtype = _record_dtype(dim)
        _flush(runs_file, workdir)
        if len(runs) > 1:
            merged = temp()
            try:
                _merge_runs(runs_file, runs, dtype, merged, where,
                            max(64, buffer_bytes // (2 * len(runs) * dtype.itemsize)), workdir)
            except BaseException:
                merged.close()
                raise
            _flush(merged, workdir)
            runs_file.close()
            runs_file = merged
    except BaseException:
        runs_file.close()
        raise
    info = {"source": str(source), "mode": str(attrs.get("mode", ""))}
    ranges = {k: (lo[k], hi[k]) for k in lo if lo[k] is not None}
    return Snapshot(attrs["step"], float(attrs.get("time", 0.0)),
                    np.asarray(arrays["wheel_state"], np.float64), info, dim, runs_file,
                    start, ranges)


def _merge_runs(src, runs, dtype, dst, where: str, rows: int, out) -> None:
    """Merge sorted runs of `src` into `dst` in id order, `rows` to 2 x rows of each run in RAM.

    Each round takes, from every run's buffer, the records up to the smallest last id among
    the buffers of runs not yet fully read (nothing beyond it can come later from any run),
    sorts that batch and writes it; the run that set the bound is emptied, so every round
    writes at least one buffer's worth unless the runs are ending.
    """
    pos = [s for s, _ in runs]          # next record of each run still on disk
    end = [s + c for s, c in runs]
    bufs = [np.empty(0, dtype)] * len(runs)
    last = None
    while True:
        for i in range(len(runs)):
            if len(bufs[i]) < rows and pos[i] < end[i]:
                take = min(rows, end[i] - pos[i])
                bufs[i] = np.concatenate([bufs[i], _read_records(src, dtype, pos[i], take)])
                pos[i] += take
        live = [i for i in range(len(runs)) if len(bufs[i])]
        if not live:
            return
        open_runs = [bufs[i]["id"][-1] for i in live if pos[i] < end[i]]
        bound = min(open_runs) if open_runs else None
        parts = []
        for i in live:
            k = len(bufs[i]) if bound is None else int(np.searchsorted(bufs[i]["id"], bound, "right"))
            parts.append(bufs[i][:k])
            bufs[i] = bufs[i][k:]
        batch = np.concatenate(parts)
        batch = batch[np.argsort(batch["id"], kind="stable")]
        if len(batch):
            if last is not None and batch["id"][0] <= last:
                raise StateError(f"{where}: disc id {int(last)} appears more than once")
            check_unique_sorted(batch["id"], where)
            last = batch["id"][-1]
            _spill(dst, batch, out)


def export_snapshot(snap: Snapshot, fmt: str, out) -> list[Path]:
    """Write `snap` as `fmt` to `out`; returns the files written."""
    out = Path(out)
    if fmt not in FORMATS:
        raise ExportError(f"--format {fmt!r}: must be one of {', '.join(FORMATS)}")
    check_targets(output_files(fmt, out), out)
    _check_room(snap, fmt, out)
    if fmt == "xdmf":
        return _write_xdmf(snap, out)
    if fmt == "vtk":
        return [_write_vtp(snap, out) if out.suffix.lower() == ".vtp" else _write_vtk_legacy(snap, out)]
    return [_write_csv(snap, out)]


# bytes of text a value takes in the text formats (a float's repr and separator, on the low
# side: the check before writing refuses only what surely cannot fit)
_TEXT_VALUE_BYTES = 10


def _check_room(snap: Snapshot, fmt: str, out: Path) -> None:
    """Refuse an export that cannot fit, before writing anything (one line)."""
    n = len(snap)
    try:
        if fmt == "xdmf":
            h5 = output_files(fmt, out)[1]
            row = 2 * 3 * 8 + 3 * 8 + 8 * spin_width(snap.dim) + snap.dtype["id"].itemsize \
                + snap.dtype["mat"].itemsize
            check_room(h5, n * row + H5_OVERHEAD)
            check_room(out, 4096)
        else:
            values = 3 * 3 + spin_width(snap.dim) + 6        # xyz, velocity, offsets, spin, ...
            check_room(out, n * values * _TEXT_VALUE_BYTES + 4096)
    except OSError as e:
        raise ExportError(_oserror(e.filename or out, e)) from None


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


def _write_columns(f, snap: Snapshot, columns_of, sep: str) -> None:
    """One line per disc (id order): the arrays ``columns_of(first_row, chunk)`` gives for
    each slice of the snapshot, their values joined by sep."""
    for start, chunk in snap.chunks():
        texts = [_fmt(c) for c in columns_of(start, chunk)]
        f.write("".join(sep.join(row) + "\n" for row in zip(*texts)))


def _index(start: int, chunk: dict) -> np.ndarray:
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
    _, h5 = output_files("xdmf", out)
    if ":" in h5.name:
        raise ExportError(f"--out {out}: the file name must not contain ':' (XDMF HDF references)")
    n = len(snap)
    # each dataset from a slice of the snapshot (rows first..): written slice by slice
    data = {
        "positions": lambda s, c: _xyz_array(c),
        "velocity": lambda s, c: _xyz_array(c, "v"),
        "radius": lambda s, c: c["r"], "spin": lambda s, c: _spin_array(c),
        "id": lambda s, c: c["id"], "mass": lambda s, c: c["mass"],
        "material": lambda s, c: c["mat"],
        "connectivity": lambda s, c: _index(s, c).reshape(-1, 1),
    }
    spin_shape = (n,) if spin_width(snap.dim) == 1 else (n, 3)
    shapes = {"positions": (n, 3), "velocity": (n, 3), "spin": spin_shape, "connectivity": (n, 1)}
    dtypes = {"id": snap.dtype["id"], "material": snap.dtype["mat"], "connectivity": np.dtype(np.int64)}
    try:
        tmp = new_temp(h5)
    except OSError as e:
        raise ExportError(_oserror(h5, e)) from None
    f = guard = None
    try:
        # through the write guard: a full disk or the file-size limit must reach us as an
        # OSError, never reach HDF5 (which crashes after a failed write)
        f, guard = create_h5(tmp, exclusive=False)
        sets = {k: f.create_dataset(k, shape=shapes.get(k, (n,)),
                                    dtype=dtypes.get(k, np.dtype(np.float64)))
                for k in data}
        for start, chunk in snap.chunks():
            for k, of in data.items():
                v = of(start, chunk)
                sets[k][start:start + len(v)] = v
            guard.check()    # stop at the first failed write
        ws = f.create_dataset("wheel_state", data=np.asarray(snap.wheel_state, np.float64))
        ws.attrs["components"] = ",".join(WHEEL_NAMES)
        f.attrs["step"] = np.int64(snap.step)
        f.attrs["time"] = np.float64(snap.time)
        f.attrs["description"] = _description(snap)
        f, g = None, f
        close_h5(g, guard)
        os.replace(tmp, h5)
    except BaseException as e:
        if guard is not None:
            with contextlib.suppress(Exception):
                close_h5(f, guard)
        _unlink(tmp)
        if isinstance(e, OSError):
            raise ExportError(_oserror(h5, e)) from None
        raise

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
    for name in ("radius", "velocity", "spin", "id", "mass", "material"):
        shape, dt = shapes.get(name, (n,)), dtypes.get(name, np.dtype(np.float64))
        atype = "Vector" if len(shape) == 2 else "Scalar"
        dims = " ".join(map(str, shape))
        lines += [f'      <Attribute Name="{name}" AttributeType="{atype}" Center="Node">',
                  f"        {item(name, dims, dt.kind, dt.itemsize)}",
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
    n = len(snap)
    with _Atomic(out) as f:
        f.write("# vtk DataFile Version 4.2\n")
        f.write(_description(snap)[:255] + "\n")
        f.write("ASCII\nDATASET POLYDATA\n")
        items = _field_items(snap)
        f.write(f"FIELD FieldData {len(items)}\n")
        for name, kind, text in items:
            f.write(f"{name} 1 1 {'vtktypeint64' if kind == 'i' else 'double'}\n{text}\n")
        f.write(f"POINTS {n} double\n")
        _write_columns(f, snap, lambda s, c: _xyz(c), " ")
        f.write(f"VERTICES {n} {2 * n}\n")
        _write_columns(f, snap, lambda s, c: [np.ones(len(c["id"]), np.int64), _index(s, c)], " ")
        f.write(f"POINT_DATA {n}\n")
        f.write("SCALARS radius double 1\nLOOKUP_TABLE default\n")
        _write_columns(f, snap, lambda s, c: [c["r"]], " ")
        f.write("VECTORS velocity double\n")
        _write_columns(f, snap, lambda s, c: _xyz(c, "v"), " ")
        # further point arrays as a FIELD block: a legacy reader keeps only the first SCALARS
        # unless told to read them all, but always reads every FIELD array
        more = (("spin", _spin_columns(snap.dim)), ("id", ["id"]), ("mass", ["mass"]),
                ("material", ["mat"]))
        f.write(f"FIELD point_arrays {len(more)}\n")
        for name, cols in more:
            f.write(f"{name} {len(cols)} {n} {_vtk_legacy_type(snap, cols[0])}\n")
            _write_columns(f, snap, lambda s, c, cols=cols: [c[k] for k in cols], " ")
    return out


_VTP_TYPE = {"f8": "Float64", "i8": "Int64", "i4": "Int32"}


def _vtp_array(f, snap: Snapshot, name, columns_of, dtype: np.dtype, ncomp: int = 1,
               indent="        ") -> None:
    t = _VTP_TYPE[f"{dtype.kind}{dtype.itemsize}"]
    nm = f' Name="{name}"' if name else ""
    f.write(f'{indent}<DataArray type="{t}"{nm} NumberOfComponents="{ncomp}" format="ascii">\n')
    _write_columns(f, snap, columns_of, " ")
    f.write(f"{indent}</DataArray>\n")


def _write_vtp(snap: Snapshot, out: Path) -> Path:
    n = len(snap)
    f8, i8 = np.dtype(np.float64), np.dtype(np.int64)
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
        for name, col in (("radius", "r"), ("id", "id"), ("mass", "mass"), ("material", "mat")):
            _vtp_array(f, snap, name, lambda s, c, col=col: [c[col]], snap.dtype[col])
        spin = _spin_columns(snap.dim)
        _vtp_array(f, snap, "spin", lambda s, c: [c[k] for k in spin], f8, len(spin))
        _vtp_array(f, snap, "velocity", lambda s, c: _xyz(c, "v"), f8, 3)
        f.write("      </PointData>\n      <Points>\n")
        _vtp_array(f, snap, "positions", lambda s, c: _xyz(c), f8, 3)
        f.write("      </Points>\n      <Verts>\n")
        _vtp_array(f, snap, "connectivity", lambda s, c: [_index(s, c)], i8)
        _vtp_array(f, snap, "offsets", lambda s, c: [_index(s, c) + 1], i8)
        f.write("      </Verts>\n    </Piece>\n  </PolyData>\n</VTKFile>\n")
    return out


# ------------------------------------------------------------------ CSV

def _write_csv(snap: Snapshot, out: Path) -> Path:
    with _Atomic(out) as f:
        f.write(f"# {_description(snap)}\n")
        f.write(f"# step={snap.step} time={float(snap.time)!r}\n")
        f.write("# wheel_state " + ",".join(f"{k}={float(v)!r}" for k, v in
                                            zip(WHEEL_NAMES, snap.wheel_state)) + "\n")
        f.write(",".join(snap.columns) + "\n")
        _write_columns(f, snap, lambda s, c: [c[k] for k in snap.columns], ",")
    return out
