"""Trajectories: frames of a run (``output.snapshot_interval``) in an append-only HDF5 file.

``RUN/trajectory.h5`` (separate from the checkpoint store's epochs) holds one frame every
``frame_every`` steps (``round(output.snapshot_interval / physics.dt)``, frame 0 is the
initial state), written by every mode:

* row datasets, one row a disc, the frames' rows one after another (chunked by frame,
  resizable): ``id`` (int64), ``pos`` (N x D), ``vel`` (N x D), ``spin`` (N x R), ``r``,
  ``mat`` (int32). A frame's rows are in the order they were written (out-of-core
  writes each slab's part as the slab passes, so never the whole bed at once); the
  reader sorts them by id.
* the frame index, one entry a frame: ``frame_step``, ``frame_time``, ``frame_start``
  (first row), ``frame_rows`` and ``wheel_state`` (F x 6, ``layout.WHEEL_STATE``).
* attribute ``frames``: the number of committed frames. A frame's rows and index entry
  are written and flushed first, and ``frames`` is bumped (and flushed) last, so after a
  kill a reader that trusts only ``frames`` sees complete frames only. Rows or index
  entries beyond it are leftovers of an unfinished frame.

A resumed run reopens the file, drops the frames after the step it resumes from (and any
leftovers) and appends from there: the frames of a killed-and-resumed run are those of an
uninterrupted one, bit for bit. HDF5 is not journaled: a kill in the middle of a flush can
(rarely) leave the file unreadable; the resume then keeps it as
``trajectory.h5.damaged-STEP`` and starts a new trajectory at the step it resumes from
(with a warning), the run itself is not affected.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from .physics.layout import WS_SIZE, axes, spin_width
from .plots import RunFileError, _one_line, run_file

TRAJECTORY_FILE = "trajectory.h5"
FORMAT_NAME = "ooc-dem trajectory"
FORMAT_VERSION = 1
ROW_FIELDS = ("id", "pos", "vel", "spin", "r", "mat")
INDEX_FIELDS = ("frame_step", "frame_time", "frame_start", "frame_rows", "wheel_state")
_DTYPES = {"id": np.dtype("<i8"), "pos": np.dtype("<f8"), "vel": np.dtype("<f8"),
           "spin": np.dtype("<f8"), "r": np.dtype("<f8"), "mat": np.dtype("<i4"),
           "frame_step": np.dtype("<i8"), "frame_time": np.dtype("<f8"),
           "frame_start": np.dtype("<i8"), "frame_rows": np.dtype("<i8"),
           "wheel_state": np.dtype("<f8")}
MAX_CHUNK_ROWS = 1 << 16
MAX_ROWS = 1 << 40            # a hostile file's counts are refused beyond this


class TrajectoryError(RunFileError):
    """A trajectory file is missing, unreadable or not what ooc-dem writes (one line)."""


def frame_every(sc) -> int:
    """Steps between frames (0: no trajectory): output.snapshot_interval in whole steps."""
    iv = sc.output.snapshot_interval
    if not iv:
        return 0
    return max(1, int(round(iv / sc.physics.dt)))


def _tails(dim: int) -> dict[str, tuple[int, ...]]:
    D, R = len(axes(dim)), spin_width(dim)
    return {"id": (), "pos": (D,), "vel": (D,), "spin": (R,), "r": (), "mat": (),
            "frame_step": (), "frame_time": (), "frame_start": (), "frame_rows": (),
            "wheel_state": (WS_SIZE,)}


def _h5py():
    import h5py
    return h5py


# ------------------------------------------------------------------ writer

class TrajectoryWriter:
    """Append frames to ``RUN/trajectory.h5`` (see the module docstring).

    ``due(step)`` tells whether a frame is written at ``step``; ``write_part(step, p)``
    appends discs of that frame (any order, any number of parts); ``end(step, time, ws)``
    commits it.
    """

    def __init__(self, f, path: Path, every: int):
        self.f = f
        self.path = path
        self.every = every
        self.committed = int(f.attrs["frames"])
        self._pending_step = None
        self._pending_rows = 0

    # ---- opening
    @classmethod
    def create(cls, out, sc, dim: int, n: int) -> "TrajectoryWriter | None":
        """A new trajectory for a run starting at step 0 (None if the scenario has none)."""
        every = frame_every(sc)
        if not every:
            return None
        path = Path(out) / TRAJECTORY_FILE
        if os.path.lexists(path) and not os.path.isfile(path) or os.path.islink(path):
            raise TrajectoryError(f"{path}: exists and is not a regular file (refused)")
        h5py = _h5py()
        f = h5py.File(path, "w")   # a fresh run's directory is new (or a stopped run's own)
        try:
            f.attrs["format"] = FORMAT_NAME
            f.attrs["format_version"] = FORMAT_VERSION
            f.attrs["dim"] = dim
            f.attrs["frame_every_steps"] = every
            f.attrs["dt"] = sc.physics.dt
            f.attrs["scenario_hash"] = sc.hash()
            f.attrs["n_discs"] = n
            chunk = max(1, min(n, MAX_CHUNK_ROWS))
            for k, tail in _tails(dim).items():
                rows = chunk if k in ROW_FIELDS else 64
                f.create_dataset(k, shape=(0, *tail), maxshape=(None, *tail), dtype=_DTYPES[k],
                                 chunks=(rows, *tail))
            f.attrs["frames"] = 0
            f.flush()
        except BaseException:
            f.close()
            raise
        return cls(f, path, every)

    @classmethod
    def reopen(cls, out, sc, dim: int, n: int, step: int) -> "TrajectoryWriter | None":
        """The trajectory of a run resumed at ``step``: frames after it are dropped. A missing
        or unusable file is set aside and a new one started (a warning names it)."""
        every = frame_every(sc)
        if not every:
            return None
        path = Path(out) / TRAJECTORY_FILE
        if not os.path.lexists(path):
            if step > 0:
                print(f"ooc-dem: warning: {path}: missing; the trajectory restarts at step {step}",
                      file=sys.stderr)
            return cls.create(out, sc, dim, n)
        if os.path.islink(path) or not os.path.isfile(path):
            raise TrajectoryError(f"{path}: not a regular file (refused: the run writes its trajectory "
                                  f"only into its own directory)")
        try:
            f = cls._open_checked(path, sc, dim, every)
        except TrajectoryError as e:
            aside = path.with_name(f"{path.name}.damaged-{step}")
            os.replace(path, aside)
            print(f"ooc-dem: warning: {_one_line(e)}; kept as {aside.name}, the trajectory "
                  f"restarts at step {step}", file=sys.stderr)
            return cls.create(out, sc, dim, n)
        w = cls(f, path, every)
        try:
            w.truncate_after(step)
        except BaseException:
            f.close()
            raise
        return w

    @staticmethod
    def _open_checked(path: Path, sc, dim: int, every: int):
        h5py = _h5py()
        try:
            f = h5py.File(path, "r+")
        except (OSError, ValueError) as e:
            raise TrajectoryError(f"{path}: not a readable HDF5 file ({_one_line(e)})") from None
        try:
            _check_layout(f, path)
            if int(f.attrs["dim"]) != dim:
                raise TrajectoryError(f"{path}: holds {f.attrs['dim']}-dimensional frames, the run is {dim}D")
            if int(f.attrs["frame_every_steps"]) != every:
                raise TrajectoryError(f"{path}: frame interval {f.attrs['frame_every_steps']} steps, the "
                                      f"scenario's is {every}")
            if str(f.attrs.get("scenario_hash", "")) != sc.hash():
                raise TrajectoryError(f"{path}: written by a different scenario")
            _check_index(f, path, int(f.attrs["frames"]))
        except BaseException:
            f.close()
            raise
        return f

    # ---- the committed extent
    def _end_row(self) -> int:
        F = self.committed
        if F == 0:
            return 0
        return int(self.f["frame_start"][F - 1] + self.f["frame_rows"][F - 1])

    def truncate_after(self, step: int) -> None:
        """Keep the committed frames at steps <= step; cut every dataset to that extent."""
        steps = self.f["frame_step"][:self.committed]
        keep = int(np.searchsorted(steps, step, side="right"))
        if keep != self.committed:
            self.f.attrs["frames"] = keep    # first: a kill from here on leaves `keep` frames
            self.f.flush()
            self.committed = keep
        end = self._end_row()
        for k in ROW_FIELDS:
            if self.f[k].shape[0] != end:
                self.f[k].resize(end, axis=0)
        for k in INDEX_FIELDS:
            if self.f[k].shape[0] != keep:
                self.f[k].resize(keep, axis=0)
        self.f.flush()
        self._pending_step = None

    def last_step(self) -> int | None:
        return int(self.f["frame_step"][self.committed - 1]) if self.committed else None

    def due(self, step: int) -> bool:
        """Whether a frame belongs at ``step`` and is not committed yet."""
        last = self.last_step()
        return step % self.every == 0 and (last is None or step > last)

    # ---- appending
    def write_part(self, step: int, arrays) -> None:
        """Append discs of the frame at ``step``: ``arrays`` has id, pos, vel, spin, r, mat
        (a ``Particles`` or a store record)."""
        get = (lambda k: getattr(arrays, k)) if not isinstance(arrays, dict) else arrays.__getitem__
        if self._pending_step != step:   # a new frame: drop any unfinished one
            self._pending_step = step
            self._pending_rows = 0
        start = self._end_row() + self._pending_rows
        ids = np.asarray(get("id"))
        m = len(ids)
        if m == 0:
            return
        for k in ROW_FIELDS:
            a = np.asarray(get(k), _DTYPES[k])
            ds = self.f[k]
            if ds.shape[0] < start + m:
                ds.resize(start + m, axis=0)
            ds[start:start + m] = a
        self._pending_rows += m

    def end(self, step: int, time: float, wheel_state) -> None:
        """Commit the frame at ``step`` (its rows written by write_part): index entry, flush,
        then the frame count, flush."""
        rows = self._pending_rows if self._pending_step == step else 0
        F = self.committed
        start = self._end_row()
        for k in INDEX_FIELDS:
            if self.f[k].shape[0] < F + 1:
                self.f[k].resize(F + 1, axis=0)
        self.f["frame_step"][F] = step
        self.f["frame_time"][F] = time
        self.f["frame_start"][F] = start
        self.f["frame_rows"][F] = rows
        self.f["wheel_state"][F] = np.asarray(wheel_state, np.float64)
        self.f.flush()
        self.f.attrs["frames"] = F + 1
        self.f.flush()
        self.committed = F + 1
        self._pending_step = None
        self._pending_rows = 0

    def write_frame(self, step: int, time: float, wheel_state, parts) -> None:
        """A whole frame from an iterable of parts."""
        self._pending_step = None
        for p in parts:
            self.write_part(step, p)
        self.end(step, time, wheel_state)

    def close(self) -> None:
        if self.f is not None:
            self.f.close()
            self.f = None


# ------------------------------------------------------------------ reader

def _check_layout(f, path) -> None:
    """The attributes and datasets of a trajectory, as ooc-dem writes them (untrusted input)."""
    h5py = _h5py()
    attrs = f.attrs
    if attrs.get("format") != FORMAT_NAME:
        raise TrajectoryError(f"{path}: not an ooc-dem trajectory")
    v = attrs.get("format_version")
    if not isinstance(v, (int, np.integer)) or int(v) != FORMAT_VERSION:
        raise TrajectoryError(f"{path}: trajectory format version {v!r} is not supported (this engine "
                              f"reads version {FORMAT_VERSION})")
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
    for k, tail in _tails(dim).items():
        link = f.get(k, getlink=True)
        if not isinstance(link, h5py.HardLink):
            raise TrajectoryError(f"{path}: no dataset {k!r}" if link is None else
                                  f"{path}: {k!r} is a link (refused)")
        ds = f[k]
        if not isinstance(ds, h5py.Dataset):
            raise TrajectoryError(f"{path}: {k!r} is not a dataset")
        if ds.is_virtual or ds.external:
            raise TrajectoryError(f"{path}: dataset {k!r} refers to other files (refused)")
        if ds.dtype != _DTYPES[k] or ds.shape[1:] != tail:
            raise TrajectoryError(f"{path}: dataset {k!r} has dtype {ds.dtype.str} shape {ds.shape}, "
                                  f"expected {_DTYPES[k].str} (rows, {', '.join(map(str, tail))})")


def _check_index(f, path, F: int) -> dict[str, np.ndarray]:
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
                raise TrajectoryError(f"{path}: dataset {k!r} has {f[k].shape[0]} rows, the committed "
                                      f"frames need {end}")
        s = idx["frame_step"]
        if (s < 0).any() or (np.diff(s) <= 0).any():
            raise TrajectoryError(f"{path}: frame steps are not rising")
        if not (np.isfinite(idx["frame_time"]).all() and np.isfinite(idx["wheel_state"]).all()):
            raise TrajectoryError(f"{path}: non-finite frame time or wheel state")
    return idx


class Trajectory:
    """A run's trajectory, read-only: ``len(t)`` frames, ``t[i]`` a dict of arrays sorted by
    id (``id``, ``pos``, ``vel``, ``spin``, ``r``, ``mat``) with ``step``, ``time`` and
    ``wheel_state``; iterating reads one frame at a time. Only committed frames are seen."""

    def __init__(self, path):
        path = Path(path)
        self.path = path
        h5py = _h5py()
        try:
            self.f = h5py.File(path, "r")
        except (OSError, ValueError) as e:
            raise TrajectoryError(f"{path}: not a readable HDF5 file ({_one_line(e)})") from None
        try:
            _check_layout(self.f, path)
            self.n_frames = int(self.f.attrs["frames"])
            self.index = _check_index(self.f, path, self.n_frames)
        except BaseException:
            self.f.close()
            raise
        self.dim = int(self.f.attrs["dim"])
        self.frame_every = int(self.f.attrs["frame_every_steps"])
        self.dt = float(self.f.attrs["dt"])

    @classmethod
    def of_run(cls, run_dir) -> "Trajectory":
        """The trajectory of a run directory (TrajectoryError if it has none)."""
        run_dir = Path(run_dir)
        if not run_dir.is_dir():
            raise TrajectoryError(f"{run_dir}: not a run directory")
        f = run_file(run_dir, TRAJECTORY_FILE)
        if f is None:
            raise TrajectoryError(f"{run_dir}: no {TRAJECTORY_FILE} (the run wrote no frames: set "
                                  f"output.snapshot_interval > 0)")
        return cls(f)

    @property
    def steps(self) -> np.ndarray:
        return self.index["frame_step"]

    @property
    def times(self) -> np.ndarray:
        return self.index["frame_time"]

    @property
    def wheel_states(self) -> np.ndarray:
        return self.index["wheel_state"]

    def __len__(self) -> int:
        return self.n_frames

    def rows(self, i: int) -> tuple[int, int]:
        """(first row, number of rows) of frame i in the row datasets."""
        return int(self.index["frame_start"][i]), int(self.index["frame_rows"][i])

    def __getitem__(self, i: int) -> dict:
        if not -self.n_frames <= i < self.n_frames:
            raise IndexError(f"frame {i}: the trajectory has {self.n_frames}")
        i %= self.n_frames
        a, m = self.rows(i)
        out = {k: self.f[k][a:a + m] for k in ROW_FIELDS}
        order = np.argsort(out["id"], kind="stable")
        out = {k: np.ascontiguousarray(v[order]) for k, v in out.items()}
        ids = out["id"]
        if len(ids) > 1 and (np.diff(ids) <= 0).any():
            raise TrajectoryError(f"{self.path}: frame {i} (step {self.steps[i]}) holds a disc id twice")
        for k in ("pos", "vel", "spin", "r"):
            if not np.isfinite(out[k]).all():
                raise TrajectoryError(f"{self.path}: frame {i} (step {self.steps[i]}): non-finite {k!r}")
        out["step"] = int(self.steps[i])
        out["time"] = float(self.times[i])
        out["wheel_state"] = self.wheel_states[i].copy()
        return out

    def __iter__(self):
        for i in range(self.n_frames):
            yield self[i]

    def close(self) -> None:
        self.f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ------------------------------------------------------------------ wheel outline

def wheel_outline(x: float, y: float, theta: float, radius: float, n_lugs: int, lug_tip_radius: float,
                  lug_thickness: float, arc_points: int = 6) -> np.ndarray:
    """The 2D wheel as one closed polygon (P x 2, counter-clockwise): the rim, and each of the
    ``n_lugs`` lugs (at angles theta + 2 pi k / n, ``lug_thickness`` wide, from the rim out to
    ``lug_tip_radius``) as an outward notch; a plain circle of 72 points without lugs."""
    n = int(n_lugs)
    if n <= 0 or lug_tip_radius <= radius:
        phi = theta + np.linspace(0.0, 2.0 * np.pi, 72, endpoint=False)
        return np.column_stack([x + radius * np.cos(phi), y + radius * np.sin(phi)])
    half = 0.5 * lug_thickness
    a = float(np.arcsin(min(1.0, half / radius)))
    b = float(np.arcsin(min(1.0, half / lug_tip_radius)))
    step = 2.0 * np.pi / n
    rr, aa = [], []
    for k in range(n):
        phi = theta + k * step
        rr += [radius, lug_tip_radius, lug_tip_radius, radius]
        aa += [phi - a, phi - b, phi + b, phi + a]
        gap = np.linspace(phi + a, phi + step - a, arc_points + 2)[1:-1]
        rr += [radius] * len(gap)
        aa += list(gap)
    rr, aa = np.asarray(rr), np.asarray(aa)
    return np.column_stack([x + rr * np.cos(aa), y + rr * np.sin(aa)])


# ------------------------------------------------------------------ XDMF

def _xml_numbers(a) -> str:
    return " ".join(repr(float(v)) for v in np.asarray(a, np.float64).ravel())


def write_xdmf(traj: Trajectory, out, sc=None) -> Path:
    """An XDMF 2 temporal collection over ``traj`` (ParaView, VTK's vtkXdmfReader): one
    spatial collection a frame, at the frame's time, holding the discs (Polyvertex points;
    velocity, spin, radius, id, material) as HyperSlab references into the trajectory file
    (no copy of the data: the XDMF file refers to it by a path relative to itself), and in
    2D, when the run's scenario has a wheel, the wheel's outline as a polygon (``wheel_outline``
    at the frame's wheel state; inline, a few hundred numbers). Written under a temporary name."""
    from xml.sax.saxutils import quoteattr
    from .export import ExportError, _Atomic, check_targets
    out = Path(out)
    if out.suffix.lower() not in (".xdmf", ".xmf"):
        raise ExportError(f"--out {out}: give a .xdmf (or .xmf) file name")
    check_targets([out], out)
    rel = os.path.relpath(traj.path.resolve(), out.parent.resolve())
    if ":" in rel or any(c in rel for c in "\n\r"):
        raise ExportError(f"--out {out}: the path to {traj.path} from there contains ':' (XDMF cannot "
                          f"refer to it)")
    dim = traj.dim
    D, R = len(axes(dim)), spin_width(dim)
    geo = "XY" if D == 2 else "XYZ"
    total = {k: traj.f[k].shape[0] for k in ROW_FIELDS}
    num = {"id": ('Int', 8), "pos": ('Float', 8), "vel": ('Float', 8), "spin": ('Float', 8),
           "r": ('Float', 8), "mat": ('Int', 4)}
    wheel = sc is not None and sc.wheel.enabled and dim == 2

    def slab(name: str, start: int, m: int, width: int | None, ind: str) -> str:
        nt, prec = num[name]
        src = quoteattr(f"{rel}:/{name}")[1:-1]
        if width is None:
            sel, dims, full = f"{start} 1 {m}", f"{m}", f"{total[name]}"
            sdims = "3 1"
        else:
            sel, dims, full = f"{start} 0 1 1 {m} {width}", f"{m} {width}", f"{total[name]} {width}"
            sdims = "3 2"
        return (f'{ind}<DataItem ItemType="HyperSlab" Dimensions="{dims}" Type="HyperSlab">\n'
                f'{ind}  <DataItem Dimensions="{sdims}" Format="XML">{sel}</DataItem>\n'
                f'{ind}  <DataItem Dimensions="{full}" NumberType="{nt}" Precision="{prec}" '
                f'Format="HDF">{src}</DataItem>\n'
                f'{ind}</DataItem>\n')

    attrs = [("velocity", "vel", D, "Vector"), ("spin", "spin", R, "Scalar" if R == 1 else "Vector"),
             ("radius", "r", None, "Scalar"), ("id", "id", None, "Scalar"),
             ("material", "mat", None, "Scalar")]
    with _Atomic(out) as f:
        f.write('<?xml version="1.0" ?>\n<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>\n<Xdmf Version="2.0">\n'
                ' <Domain>\n  <Grid Name="trajectory" GridType="Collection" CollectionType="Temporal">\n')
        for i in range(len(traj)):
            start, m = traj.rows(i)
            t = float(traj.times[i])
            ind = "     "
            f.write(f'   <Grid Name="step {int(traj.steps[i])}" GridType="Collection" '
                    f'CollectionType="Spatial">\n    <Time Value="{t!r}"/>\n'
                    f'    <Grid Name="discs" GridType="Uniform">\n'
                    f'{ind}<Topology TopologyType="Polyvertex" NumberOfElements="{m}" NodesPerElement="1"/>\n'
                    f'{ind}<Geometry GeometryType="{geo}">\n')
            f.write(slab("pos", start, m, D, ind + " "))
            f.write(f'{ind}</Geometry>\n')
            for label, name, width, kind in attrs:
                f.write(f'{ind}<Attribute Name="{label}" AttributeType="{kind}" Center="Node">\n')
                f.write(slab(name, start, m, width, ind + " "))
                f.write(f'{ind}</Attribute>\n')
            f.write('    </Grid>\n')
            if wheel:
                w = sc.wheel
                ws = traj.wheel_states[i]
                poly = wheel_outline(ws[0], ws[1], ws[4], w.radius, w.n_lugs, w.lug_tip_radius,
                                     w.lug_thickness)
                P = len(poly)
                f.write(f'    <Grid Name="wheel" GridType="Uniform">\n'
                        f'{ind}<Topology TopologyType="Polygon" NumberOfElements="1" NodesPerElement="{P}">\n'
                        f'{ind}  <DataItem Dimensions="1 {P}" NumberType="Int" Format="XML">'
                        f'{" ".join(map(str, range(P)))}</DataItem>\n{ind}</Topology>\n'
                        f'{ind}<Geometry GeometryType="XY">\n'
                        f'{ind}  <DataItem Dimensions="{P} 2" NumberType="Float" Precision="8" '
                        f'Format="XML">{_xml_numbers(poly)}</DataItem>\n{ind}</Geometry>\n'
                        f'    </Grid>\n')
            f.write('   </Grid>\n')
        f.write('  </Grid>\n </Domain>\n</Xdmf>\n')
    return out
