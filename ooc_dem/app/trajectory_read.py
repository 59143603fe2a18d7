"""Reading a run's trajectory: ``Trajectory`` (the ``trajectory/`` folder of frame files, or a
version-1 ``trajectory.h5``), every file checked as it is opened (trajectory_format.py)."""

from __future__ import annotations

import os
from pathlib import Path
from collections.abc import Iterator
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

from ..physics.layout import WS_SIZE
from .runfiles import one_line, run_file
from .trajectory_format import (
    FORMAT_NAME,
    H5Object,
    FORMAT_VERSION,
    FrameHeader,
    INDEX_FIELDS,
    LEGACY_VERSION,
    MAX_ROWS,
    ROW_FIELDS,
    TRAJECTORY_DIR,
    TRAJECTORY_FILE,
    TrajectoryError,
    check_row_bytes,
    checked_dataset,
    h5py_module,
    open_frame,
    row_tails,
    scan_frames,
    trajectory_folder,
)

# one frame as Trajectory gives it: its row arrays by name (id, pos, vel, spin, r, mat) sorted
# by id, and its step (int), time (float) and wheel_state
Frame: TypeAlias = dict[str, Any]


# format version 1: RUN/trajectory.h5, all frames in one file (read only)


def _check_legacy_layout(f: H5Object, path: Path) -> None:
    """The attributes and datasets of a trajectory, as ooc-dem writes them (untrusted input)."""
    attrs = f.attrs
    fmt = attrs.get("format")
    if not isinstance(fmt, str) or fmt != FORMAT_NAME:  # an array attribute compares element-wise
        raise TrajectoryError(f"{path}: not an ooc-dem trajectory")
    v = attrs.get("format_version")
    if not isinstance(v, (int, np.integer)) or int(v) != LEGACY_VERSION:
        raise TrajectoryError(
            f"{path}: trajectory format version {v!r} is not supported (this engine "
            f"reads versions {LEGACY_VERSION} and {FORMAT_VERSION})"
        )
    for key in ("dim", "frame_every_steps", "frames", "n_discs"):
        a = attrs.get(key)
        if not isinstance(a, (int, np.integer)) or not 0 <= int(a) <= MAX_ROWS:
            raise TrajectoryError(f"{path}: attribute {key!r} = {a!r} is not a count")
    dim = int(attrs["dim"])
    if dim not in (2, 3):
        raise TrajectoryError(f"{path}: dim = {dim}: must be 2 or 3")
    dt = attrs.get("dt")
    if not isinstance(dt, (float, np.floating)) or not (0.0 < float(dt) < 1.0):
        raise TrajectoryError(f"{path}: attribute 'dt' = {dt!r} is not a time step")
    for k, tail in row_tails(dim).items():
        checked_dataset(f, k, tail, path)


def _check_legacy_index(f: H5Object, path: Path, F: int) -> dict[str, NDArray[Any]]:
    """The committed frame index, checked: contiguous rows within the datasets, steps rising."""
    for k in INDEX_FIELDS:
        if f[k].shape[0] < F:
            raise TrajectoryError(f"{path}: {F} frames committed but {k!r} has {f[k].shape[0]} entries")
    idx = {k: f[k][:F] for k in INDEX_FIELDS}
    rows, start = idx["frame_rows"], idx["frame_start"]
    if F:
        if (rows < 0).any() or (rows > MAX_ROWS).any():
            raise TrajectoryError(f"{path}: frame row counts out of range")
        want = np.concatenate([[0], np.cumsum(rows)[:-1]])
        if not np.array_equal(start, want):
            raise TrajectoryError(f"{path}: frame rows are not contiguous (index damaged or edited)")
        end = int(start[-1] + rows[-1])
        for k in ROW_FIELDS:
            if f[k].shape[0] < end:
                raise TrajectoryError(
                    f"{path}: dataset {k!r} has {f[k].shape[0]} rows, the committed frames need {end}"
                )
        if int(rows.max()) > int(f.attrs["n_discs"]):
            raise TrajectoryError(f"{path}: a frame of {int(rows.max())} rows, more than n_discs")
        check_row_bytes(f, path, end, int(f.attrs["dim"]))
        s = idx["frame_step"]
        if (s < 0).any() or (np.diff(s) <= 0).any():
            raise TrajectoryError(f"{path}: frame steps are not rising")
        if not (np.isfinite(idx["frame_time"]).all() and np.isfinite(idx["wheel_state"]).all()):
            raise TrajectoryError(f"{path}: non-finite frame time or wheel state")
    return idx


class Trajectory:
    """A run's trajectory, read-only: ``len(t)`` frames, ``t[i]`` a dict of arrays sorted by
    id (``id``, ``pos``, ``vel``, ``spin``, ``r``, ``mat``) with ``step``, ``time`` and
    ``wheel_state``; iterating reads one frame at a time. Only published frames are seen
    (``path``: the ``trajectory/`` folder, or a version-1 ``trajectory.h5``)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        path = Path(path)
        self.path = path
        self.f: H5Object = None  # the open version-1 file (None: a folder of frames, or closed)
        self.files: list[Path] | None = None
        self.n_frames: int
        self.index: dict[str, NDArray[Any]]
        self.dim: int | None  # None: no frame to say
        self.frame_every: int | None
        self.dt: float | None
        self.scenario_hash: str | None
        if os.path.isdir(path):
            self._open_folder(path)
        else:
            self._open_legacy(path)

    def _open_folder(self, folder: Path) -> None:
        frames, _ = scan_frames(folder)
        self.files = list(frames.values())
        heads: list[FrameHeader] = []
        for s, p in frames.items():
            f, head = open_frame(p, s)
            f.close()
            if heads:
                for key in ("dim", "frame_every_steps", "dt", "scenario_hash", "n_discs"):
                    if head[key] != heads[0][key]:
                        raise TrajectoryError(
                            f"{p}: {key} {head[key]!r}, the first frame's is "
                            f"{heads[0][key]!r} (frames of different runs)"
                        )
            heads.append(head)
        F = len(heads)
        self.n_frames = F
        self.index = {
            "frame_step": np.array([h["step"] for h in heads], np.int64),
            "frame_time": np.array([h["time"] for h in heads], np.float64),
            "frame_start": np.zeros(F, np.int64),
            "frame_rows": np.array([h["rows"] for h in heads], np.int64),
            "wheel_state": (np.array([h["wheel_state"] for h in heads], np.float64) if F else np.zeros((0, WS_SIZE))),
        }
        h0: FrameHeader = heads[0] if heads else {}
        self.dim = h0.get("dim")
        self.frame_every = h0.get("frame_every_steps")
        self.dt = h0.get("dt")
        self.scenario_hash = h0.get("scenario_hash")

    def _open_legacy(self, path: Path) -> None:
        h5py = h5py_module()
        try:
            self.f = h5py.File(path, "r")
        except (OSError, ValueError) as e:
            raise TrajectoryError(f"{path}: not a readable HDF5 file ({one_line(e)})") from None
        try:
            _check_legacy_layout(self.f, path)
            self.n_frames = int(self.f.attrs["frames"])
            self.index = _check_legacy_index(self.f, path, self.n_frames)
        except BaseException:
            self.f.close()
            raise
        self.dim = int(self.f.attrs["dim"])
        self.frame_every = int(self.f.attrs["frame_every_steps"])
        self.dt = float(self.f.attrs["dt"])
        self.scenario_hash = str(self.f.attrs.get("scenario_hash", ""))

    @classmethod
    def of_run(cls, run_dir: str | os.PathLike[str]) -> Trajectory:
        """The trajectory of a run directory: ``trajectory/``, else a version-1
        ``trajectory.h5`` (TrajectoryError if it has none)."""
        run_dir = Path(run_dir)
        if not run_dir.is_dir():
            raise TrajectoryError(f"{run_dir}: not a run directory")
        folder = trajectory_folder(run_dir, create=False)
        if folder is not None:
            return cls(folder)
        f = run_file(run_dir, TRAJECTORY_FILE)
        if f is None:
            raise TrajectoryError(
                f"{run_dir}: no {TRAJECTORY_DIR}/ (the run wrote no frames: set output.snapshot_interval > 0)"
            )
        return cls(f)

    @property
    def steps(self) -> NDArray[np.int64]:
        return self.index["frame_step"]

    @property
    def times(self) -> NDArray[np.float64]:
        return self.index["frame_time"]

    @property
    def wheel_states(self) -> NDArray[np.float64]:
        return self.index["wheel_state"]

    def __len__(self) -> int:
        return self.n_frames

    def rows(self, i: int) -> tuple[int, int]:
        """(first row, number of rows) of frame i in the row datasets of ``file(i)``."""
        return int(self.index["frame_start"][i]), int(self.index["frame_rows"][i])

    def file(self, i: int) -> Path:
        """The HDF5 file holding frame i."""
        return self.path if self.files is None else self.files[i]

    def file_rows(self, i: int) -> int:
        """The number of rows of the row datasets in ``file(i)``."""
        return self._legacy_file()["id"].shape[0] if self.files is None else self.rows(i)[1]

    def __getitem__(self, i: int) -> Frame:
        if not -self.n_frames <= i < self.n_frames:
            raise IndexError(f"frame {i}: the trajectory has {self.n_frames}")
        i %= self.n_frames
        a, m = self.rows(i)
        if self.files is None:
            legacy = self._legacy_file()
            out = {k: legacy[k][a : a + m] for k in ROW_FIELDS}
        else:
            f, head = open_frame(self.files[i], int(self.steps[i]))
            try:
                if head["rows"] != m or head["dim"] != self.dim:
                    raise TrajectoryError(f"{self.files[i]}: changed while open")
                out = {k: f[k][:] for k in ROW_FIELDS}
            finally:
                f.close()
        where = self.file(i)
        order = np.argsort(out["id"], kind="stable")
        out = {k: np.ascontiguousarray(v[order]) for k, v in out.items()}
        ids = out["id"]
        if len(ids) > 1 and (np.diff(ids) <= 0).any():
            raise TrajectoryError(f"{where}: frame {i} (step {self.steps[i]}) holds a disc id twice")
        for k in ("pos", "vel", "spin", "r"):
            if not np.isfinite(out[k]).all():
                raise TrajectoryError(f"{where}: frame {i} (step {self.steps[i]}): non-finite {k!r}")
        out["step"] = int(self.steps[i])
        out["time"] = float(self.times[i])
        out["wheel_state"] = self.wheel_states[i].copy()
        return out

    def __iter__(self) -> Iterator[Frame]:
        for i in range(self.n_frames):
            yield self[i]

    def _legacy_file(self) -> Any:
        """The open version-1 file (a trajectory without ``files``)."""
        if self.f is None:
            raise TrajectoryError(f"{self.path}: the trajectory is closed")
        return self.f

    def close(self) -> None:
        if self.f is not None:
            self.f.close()
            self.f = None

    def __enter__(self) -> Trajectory:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
