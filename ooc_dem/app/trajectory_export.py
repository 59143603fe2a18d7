"""``ooc-dem export-trajectory``: a run's trajectory as XDMF 3 time series (+ HDF5), through
meshio's XDMF time-series writer, read by ParaView (its XDMF readers) and by meshio.

* ``NAME.xdmf`` + ``NAME.h5``: the discs or spheres, a temporal collection of one uniform grid
  a frame (at the frame's time), each with its own geometry (the particles move, so unlike
  meshio's own ``write_points_cells`` the mesh is not shared): points (x, y in 2D; x, y, z in
  3D) as vertex cells, sorted by id, with point data ``radius``, ``velocity`` (3 components),
  ``spin`` (a scalar in 2D, 3 components in 3D), ``id`` and ``material``;
* ``NAME-wheel.xdmf`` + ``NAME-wheel.h5`` (a run with a wheel): the wheel's surface a frame,
  triangles at the frame's pose: in 3D ``wheel_surface.wheel_surface`` (rim cylinder and lug
  boxes), in 2D the outline polygon of ``trajectory.wheel_outline`` fanned into triangles.

The data is copied into the HDF5 files (each frame read and written in turn: memory, one
frame). Every file is written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ooc_dem.storage.writeguard import H5_OVERHEAD, check_room

from .outfile import AtomicFile, ExportError, check_targets, remove_file, write_failure, write_h5_replacing
from .trajectory import wheel_outline
from .trajectory_format import row_bytes
from .trajectory_read import Trajectory
from .wheel_surface import RIM_SEGMENTS, WheelGeometry, wheel_outline_triangles, wheel_surface

if TYPE_CHECKING:
    from ..model.scenario import Scenario

XDMF_SUFFIXES = (".xdmf", ".xmf")


def output_files(out: Path, wheel: bool) -> list[Path]:
    """The files an export to ``out`` writes: NAME.xdmf, NAME.h5 and, with a wheel,
    NAME-wheel.xdmf, NAME-wheel.h5."""
    files = [out, out.with_suffix(".h5")]
    if wheel:
        w = out.with_name(f"{out.stem}-wheel{out.suffix}")
        files += [w, w.with_suffix(".h5")]
    return files


def _series_writer() -> Any:
    """meshio's XDMF 3 time-series writer, each step a uniform grid with its own geometry
    and topology, its HDF5 data going to a file opened by the caller (through the write
    guard) under the name the XDMF file refers to."""
    from meshio.xdmf import TimeSeriesWriter

    class MovingSeriesWriter(TimeSeriesWriter):  # type: ignore[misc]
        def __init__(self, xdmf: Path, h5_name: str, h5_file: Any) -> None:
            super().__init__(xdmf, data_format="HDF")
            self.h5_filename = h5_name  # the XDMF refers to it by this (relative) name
            self.h5_file = h5_file

        def write_step(
            self,
            name: str,
            t: float,
            points: NDArray[np.float64],
            cells: list[tuple[str, NDArray[np.int64]]],
            point_data: dict[str, NDArray[Any]] | None = None,
        ) -> None:
            grid = ET.SubElement(self.collection, "Grid", Name=name, GridType="Uniform")
            ET.SubElement(grid, "Time", Value=repr(float(t)))
            self.points(grid, np.ascontiguousarray(points))
            self.cells(cells, grid)
            if point_data:
                self.point_data(point_data, grid)

        def xml(self) -> str:
            return '<?xml version="1.0" ?>\n' + ET.tostring(self.xdmf_file, encoding="unicode") + "\n"

    return MovingSeriesWriter


def _particle_step(
    fr: dict[str, Any],
) -> tuple[NDArray[np.float64], list[tuple[str, NDArray[np.int64]]], dict[str, NDArray[Any]]]:
    pos = fr["pos"]
    n, D = pos.shape
    vel = np.zeros((n, 3))
    vel[:, :D] = fr["vel"]
    spin = fr["spin"][:, 0] if fr["spin"].shape[1] == 1 else fr["spin"]
    data = {
        "radius": fr["r"],
        "velocity": vel,
        "spin": np.ascontiguousarray(spin),
        "id": fr["id"],
        "material": fr["mat"],
    }
    return pos, [("vertex", np.arange(n, dtype=np.int64).reshape(-1, 1))], data


def write_xdmf(traj: Trajectory, out: str | os.PathLike[str], sc: Scenario | None = None) -> list[Path]:
    """Export ``traj`` (see the module docstring) to ``out`` (.xdmf); returns the files written."""
    out = Path(out)
    if out.suffix.lower() not in XDMF_SUFFIXES:
        raise ExportError(f"--out {out}: give a .xdmf (or .xmf) file name")
    if ":" in out.name:
        raise ExportError(f"--out {out}: the file name must not contain ':' (XDMF HDF references)")
    dim = traj.dim
    wheel = sc is not None and sc.wheel.enabled
    files = output_files(out, wheel)
    check_targets(files, out)
    if not len(traj) or dim is None:
        raise ExportError(f"{traj.path}: no published frame yet")
    rows = int(np.sum(traj.index["frame_rows"]))
    try:
        check_room(files[1], rows * (row_bytes(dim) + 8 + 24) + len(traj) * 4096 + H5_OVERHEAD)
    except OSError as e:
        raise ExportError(write_failure(e.filename or files[1], e)) from None
    geometry = WheelGeometry.of_scenario(sc) if wheel and sc is not None else None

    def wheel_step(
        fr: dict[str, Any],
    ) -> tuple[NDArray[np.float64], list[tuple[str, NDArray[np.int64]]], dict[str, NDArray[Any]]]:
        ws = fr["wheel_state"]
        assert geometry is not None
        if dim == 3:
            v, tri = wheel_surface(geometry, ws[0], ws[1], ws[4], RIM_SEGMENTS)
        else:
            g = geometry
            outline = wheel_outline(ws[0], ws[1], ws[4], g.radius, g.n_lugs, g.lug_tip_radius, g.lug_thickness)
            v, tri = wheel_outline_triangles(outline, ws[0], ws[1])
        return v, [("triangle", tri)], {}

    series = [(files[0], files[1], _particle_step)]
    if geometry is not None:
        series.append((files[2], files[3], wheel_step))
    written: list[Path] = []
    try:
        for xdmf, h5, step_of in series:
            _write_series(traj, xdmf, h5, step_of)
            written += [xdmf, h5]
    except BaseException:
        for p in written:
            remove_file(p)
        raise
    return written


def _write_series(traj: Trajectory, xdmf: Path, h5: Path, step_of: Any) -> None:
    """One time series: every frame's (points, cells, point data) from ``step_of(frame)``
    into ``h5`` (a temporary renamed when complete), then ``xdmf`` referring to it."""
    writer: Any = None

    def fill(f: Any, guard: Any) -> None:
        nonlocal writer
        writer = _series_writer()(xdmf, h5.name, f)
        for fr in traj:  # one frame at a time
            points, cells, data = step_of(fr)
            writer.write_step(f"step {fr['step']}", fr["time"], points, cells, data)
            guard.check()

    write_h5_replacing(h5, fill)
    try:
        with AtomicFile(xdmf) as x:
            x.write(writer.xml())
    except BaseException:
        remove_file(h5)
        raise
