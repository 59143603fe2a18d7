"""Export one committed epoch: XDMF 3 (+ HDF5), VTK (legacy ASCII .vtk, XML .vtu or .vtp), CSV.

Every format holds one point per disc, sorted by id, with the disc's radius,
velocity, spin, id, mass and material, plus the wheel state, the step and the
simulated time:

* ``xdmf``: ``NAME.h5`` beside ``NAME.xdmf``. The HDF5 file holds ``/positions``
  (N x 3, z = 0), ``/velocity`` (N x 3, vz = 0), ``/radius``, ``/spin``, ``/id``,
  ``/mass``, ``/material``, ``/connectivity`` (N x 1, the Polyvertex cells) and
  ``/wheel_state`` (x, y, vx, vy, theta, wz: ``layout.WHEEL_STATE``) with ``step``/``time``
  attributes.
  The XDMF file is one Uniform grid with a Polyvertex topology and node-centred
  attributes (read by ParaView and meshio); the wheel state, step and time are in the
  HDF5 file only (Grid-centred attributes, ParaView's field data, are refused by meshio).
* ``vtk``: legacy ASCII ``.vtk`` (file version 5.1) UnstructuredGrid (points, one vertex
  cell each, POINT_DATA, dataset FIELD data for the wheel); VTK XML UnstructuredGrid if
  the file name ends in ``.vtu``, or PolyData (Verts) if in ``.vtp``. meshio reads the
  ``.vtk`` and ``.vtu`` files (it has no VTK XML PolyData reader); ParaView all three.
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

import os
import tempfile
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import NDArray

from ooc_dem.storage.writeguard import H5_OVERHEAD, check_room

from ..model.checkpoint import OpenEpoch
from ..model.state_check import StateError, check_unique_sorted, validate_globals
from ..physics.layout import spin_width
from .export_formats import Snapshot, output_files, read_records, record_dtype, vector_columns, write_snapshot
from .outfile import ExportError, check_targets, write_failure

FORMATS = ("xdmf", "vtk", "csv")
_SUFFIX_FORMAT = {".xdmf": "xdmf", ".xmf": "xdmf", ".vtk": "vtk", ".vtp": "vtk", ".vtu": "vtk", ".csv": "csv"}


def infer_format(out: str | os.PathLike[str]) -> str | None:
    return _SUFFIX_FORMAT.get(Path(out).suffix.lower())


def _group_records(reader: OpenEpoch, d: int, source: str, dim: int | None) -> tuple[NDArray[np.void], int]:
    """One domain group's discs as export records sorted by id (and the dimension)."""
    names = ["id", "pos", "vel", "spin", "r", "mass", "mat"]
    p = reader.read_domain(d, names)
    n = len(p["id"])
    if dim is None:
        pos = p["pos"]
        dim = pos.shape[1] if pos.ndim == 2 and pos.shape[1] in (2, 3) else 2
    vec = vector_columns(dim)
    rec = np.empty(n, record_dtype(dim))
    for k in names:
        width = len(vec[k]) if k in vec else None
        want = (n, width) if width else (n,)
        if p[k].shape != want:
            raise StateError(
                f"{source}: epoch {reader.step} domain {d}: array {k!r} has "
                f"shape {p[k].shape}, expected {want}" + (f" ({dim}D)" if width else "")
            )
        if width:
            for c, name in enumerate(vec[k]):
                rec[name] = p[k][:, c]
        else:
            rec[k] = p[k]
    del p
    rec = rec[np.argsort(rec["id"], kind="stable")]
    check_unique_sorted(rec["id"], f"{source}: epoch {reader.step}")
    return rec, dim


def _flush(records: IO[bytes], out: str | os.PathLike[str]) -> None:
    try:
        records.flush()
    except OSError as e:
        raise ExportError(write_failure(out, e)) from None


def _spill(records: IO[bytes], rec: NDArray[np.void], out: str | os.PathLike[str]) -> None:
    try:
        records.write(rec.tobytes())
    except OSError as e:
        raise ExportError(write_failure(out, e)) from None


def read_snapshot(
    reader: OpenEpoch, source: str = "", workdir: str | os.PathLike[str] = ".", buffer_bytes: int = 64 << 20
) -> Snapshot:
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

    def temp() -> IO[bytes]:
        try:
            return tempfile.TemporaryFile(dir=workdir)
        except OSError as e:
            raise ExportError(f"{workdir}: cannot create a temporary export file ({e.strerror})") from None

    runs_file, dim = temp(), None
    runs: list[tuple[int, int]] = []  # (first record, count)
    lo: dict[str, int | None] = {"id": None, "mat": None}
    hi = dict(lo)
    try:
        start = 0
        for d in reader.domains():
            rec, dim = _group_records(reader, d, source, dim)
            if len(rec):
                for k in lo:
                    a, b = rec[k].min(), rec[k].max()
                    low, high = lo[k], hi[k]
                    lo[k] = int(a) if low is None else min(low, int(a))
                    hi[k] = int(b) if high is None else max(high, int(b))
                _spill(runs_file, rec, workdir)
                runs.append((start, len(rec)))
                start += len(rec)
            del rec
        dim = dim or 2
        dtype = record_dtype(dim)
        _flush(runs_file, workdir)
        if len(runs) > 1:
            merged = temp()
            try:
                _merge_runs(
                    runs_file,
                    runs,
                    dtype,
                    merged,
                    where,
                    max(64, buffer_bytes // (2 * len(runs) * dtype.itemsize)),
                    workdir,
                )
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
    ranges = {k: (low, high) for k in lo if (low := lo[k]) is not None and (high := hi[k]) is not None}
    return Snapshot(
        attrs["step"],
        float(attrs.get("time", 0.0)),
        np.asarray(arrays["wheel_state"], np.float64),
        info,
        dim,
        runs_file,
        start,
        ranges,
    )


def _merge_runs(
    src: IO[bytes],
    runs: list[tuple[int, int]],
    dtype: np.dtype[np.void],
    dst: IO[bytes],
    where: str,
    rows: int,
    out: str | os.PathLike[str],
) -> None:
    """Merge sorted runs of `src` into `dst` in id order, `rows` to 2 x rows of each run in RAM.

    Each round takes, from every run's buffer, the records up to the smallest last id among
    the buffers of runs not yet fully read (nothing beyond it can come later from any run),
    sorts that batch and writes it; the run that set the bound is emptied, so every round
    writes at least one buffer's worth unless the runs are ending.
    """
    pos = [s for s, _ in runs]  # next record of each run still on disk
    end = [s + c for s, c in runs]
    bufs = [np.empty(0, dtype)] * len(runs)
    last = None
    while True:
        for i in range(len(runs)):
            if len(bufs[i]) < rows and pos[i] < end[i]:
                take = min(rows, end[i] - pos[i])
                bufs[i] = np.concatenate([bufs[i], read_records(src, dtype, pos[i], take)])
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


def export_snapshot(snap: Snapshot, fmt: str, out: str | os.PathLike[str]) -> list[Path]:
    """Write `snap` as `fmt` to `out`; returns the files written."""
    out = Path(out)
    if fmt not in FORMATS:
        raise ExportError(f"--format {fmt!r}: must be one of {', '.join(FORMATS)}")
    check_targets(output_files(fmt, out), out)
    _check_room(snap, fmt, out)
    return write_snapshot(snap, fmt, out)


# bytes of text a value takes in the text formats (a float's repr and separator, on the low
# side: the check before writing refuses only what surely cannot fit)
_TEXT_VALUE_BYTES = 10


def _check_room(snap: Snapshot, fmt: str, out: Path) -> None:
    """Refuse an export that cannot fit, before writing anything (one line)."""
    n = len(snap)
    try:
        if fmt == "xdmf":
            h5 = output_files(fmt, out)[1]
            row = 2 * 3 * 8 + 3 * 8 + 8 * spin_width(snap.dim) + snap.dtype["id"].itemsize + snap.dtype["mat"].itemsize
            check_room(h5, n * row + H5_OVERHEAD)
            check_room(out, 4096)
        else:
            values = 3 * 3 + spin_width(snap.dim) + 6  # xyz, velocity, offsets, spin, ...
            check_room(out, n * values * _TEXT_VALUE_BYTES + 4096)
    except OSError as e:
        raise ExportError(write_failure(e.filename or out, e)) from None
