"""Trajectories: frames of a run (``output.snapshot_interval``), one HDF5 file a frame.

``RUN/trajectory/`` (separate from the checkpoint store's epochs) holds one frame every
``frame_every`` steps (``round(output.snapshot_interval / physics.dt)``, frame 0 is the
initial state), written by every mode, each frame its own file ``frame-SSSSSSSSSSSS.h5``
(the step, 12 digits: the names sort by step):

* attributes ``format``, ``format_version`` (2), ``dim``, ``frame_every_steps``, ``dt``,
  ``scenario_hash``, ``n_discs``, and the frame's ``step``, ``time`` and ``wheel_state``
  (6 numbers, ``layout.WHEEL_STATE``);
* row datasets, one row a disc: ``id`` (int64), ``pos`` (N x D), ``vel`` (N x D), ``spin``
  (N x R), ``r``, ``mat`` (int32). The rows are in the order they were written
  (out-of-core writes each slab's part as the slab passes, so never the whole bed at
  once); the reader sorts them by id.

A frame is written under a temporary name (``frame-...h5.tmp-XXXXXXXX``, beside its target)
and published by an atomic rename (``os.replace``) once complete and closed (``--durable``:
the file is fsynced before, the folder after). A kill at any moment can therefore only
lose the frame being written: every published file is whole, and readers list published
files only. A resumed run deletes the published frames after the step it resumes from and
the leftover temporaries (only names of these two patterns: a run directory is untrusted
input, nothing else in it is ever deleted), then writes on: the frames of a
killed-and-resumed run are those of an uninterrupted one, bit for bit.

Version 1 (``RUN/trajectory.h5``, one append-only file for all frames, as earlier
engines wrote it) is still read; a run resumed over one continues in ``trajectory/``
(its frames up to the resumed step copied there first; the old file is left as it is).
"""
from __future__ import annotations

import contextlib
import os
import re
import stat
import sys
from pathlib import Path

import numpy as np

from ooc_dem.storage.writeguard import H5_OVERHEAD, check_room, close_h5, create_h5

from ..storage.atomic import new_temp
from ..physics.layout import WS_SIZE, axes, spin_width
from .runfiles import RunFileError, one_line, run_file

TRAJECTORY_DIR = "trajectory"
TRAJECTORY_FILE = "trajectory.h5"        # format version 1 (read, and migrated on resume)
FORMAT_NAME = "ooc-dem trajectory"
FORMAT_VERSION = 2
LEGACY_VERSION = 1
FRAME_RE = re.compile(r"frame-([0-9]{12})\.h5")
TEMP_RE = re.compile(r"frame-[0-9]{12}\.h5\.tmp-[A-Za-z0-9_]{1,64}")
MAX_STEP = 10 ** 12 - 1
ROW_FIELDS = ("id", "pos", "vel", "spin", "r", "mat")
INDEX_FIELDS = ("frame_step", "frame_time", "frame_start", "frame_rows", "wheel_state")
_DTYPES = {"id": np.dtype("<i8"), "pos": np.dtype("<f8"), "vel": np.dtype("<f8"),
           "spin": np.dtype("<f8"), "r": np.dtype("<f8"), "mat": np.dtype("<i4"),
           "frame_step": np.dtype("<i8"), "frame_time": np.dtype("<f8"),
           "frame_start": np.dtype("<i8"), "frame_rows": np.dtype("<i8"),
           "wheel_state": np.dtype("<f8")}
MAX_CHUNK_ROWS = 1 << 16
MAX_ROWS = 1 << 40            # a hostile file's counts are refused beyond this
MAX_FRAMES = 1 << 24          # a hostile folder's file count is refused beyond this


class TrajectoryError(RunFileError):
    """A trajectory file is missing, unreadable or not what ooc-dem writes (one line)."""


def frame_every(sc) -> int:
    """Steps between frames (0: no trajectory): output.snapshot_interval in whole steps."""
    iv = sc.output.snapshot_interval
    if not iv:
        return 0
    return max(1, int(round(iv / sc.physics.dt)))


def frame_name(step: int) -> str:
    return f"frame-{int(step):012d}.h5"


def _tails(dim: int) -> dict[str, tuple[int, ...]]:
    D, R = len(axes(dim)), spin_width(dim)
    return {"id": (), "pos": (D,), "vel": (D,), "spin": (R,), "r": (), "mat": (),
            "frame_step": (), "frame_time": (), "frame_start": (), "frame_rows": (),
            "wheel_state": (WS_SIZE,)}


def _h5py():
    import h5py
    return h5py


def _fsync(path) -> None:
    fd = os.open(os.fspath(path), os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _folder(out, create: bool) -> Path | None:
    """``out/trajectory`` as a real directory of the run (a symlink or other file there is
    refused); None if absent and not ``create``."""
    d = Path(out) / TRAJECTORY_DIR
    if os.path.lexists(d):
        st = os.lstat(d)
        if not stat.S_ISDIR(st.st_mode):
            raise TrajectoryError(f"{d}: exists and is not a directory (a symlink or file: refused)")
        return d
    if not create:
        return None
    os.mkdir(d)
    return d


def _scan(folder: Path) -> tuple[dict[int, Path], list[Path]]:
    """The published frame files of ``folder`` by step, and the leftover temporaries of our
    own name pattern (regular files only); other names are ignored. A frame name that is
    not a regular file (a symlink, a directory, a FIFO) is refused."""
    frames, temps = {}, []
    try:
        entries = list(os.scandir(folder))
    except OSError as e:
        raise TrajectoryError(f"{folder}: unreadable ({one_line(e)})") from None
    if len(entries) > MAX_FRAMES:
        raise TrajectoryError(f"{folder}: {len(entries)} entries (refused)")
    for e in entries:
        m = FRAME_RE.fullmatch(e.name)
        if m:
            if not e.is_file(follow_symlinks=False):
                raise TrajectoryError(f"{folder / e.name}: not a regular file (refused)")
            frames[int(m.group(1))] = folder / e.name
        elif TEMP_RE.fullmatch(e.name) and e.is_file(follow_symlinks=False):
            temps.append(folder / e.name)
    return dict(sorted(frames.items())), temps


def _row_bytes(dim: int) -> int:
    return sum(_DTYPES[k].itemsize * int(np.prod(_tails(dim)[k], dtype=np.int64)) for k in ROW_FIELDS)


def _check_row_bytes(f, path, rows: int, dim: int) -> None:
    """Refuse a file whose datasets declare more rows than it holds: the writer's datasets are
    unfiltered, so every row's bytes are in the file, and a read allocates no more than the
    file's own size (nor more than this machine's memory)."""
    import psutil
    for k in ROW_FIELDS:
        if f[k].id.get_create_plist().get_nfilters():
            raise TrajectoryError(f"{path}: dataset {k!r} is filtered or compressed (not what "
                                  f"ooc-dem writes; refused)")
    need, size = rows * _row_bytes(dim), os.stat(path).st_size
    if need > size or need > psutil.virtual_memory().total // 4:
        raise TrajectoryError(f"{path}: {rows} rows declared ({need} bytes), the file holds "
                              f"{size} bytes (refused)")


def _is_count(a) -> bool:
    return isinstance(a, (int, np.integer)) and not isinstance(a, bool) and 0 <= int(a) <= MAX_ROWS


def _check_frame_file(f, path, step: int | None = None) -> dict:
    """The header and datasets of one frame file, as ooc-dem writes them (untrusted input);
    returns its header (dim, frame_every_steps, dt, scenario_hash, step, time, wheel_state, rows)."""
    attrs = f.attrs
    fmt = attrs.get("format")
    if not isinstance(fmt, str) or fmt != FORMAT_NAME:   # an array attribute compares element-wise
        raise TrajectoryError(f"{path}: not an ooc-dem trajectory frame")
    v = attrs.get("format_version")
    if not isinstance(v, (int, np.integer)) or int(v) != FORMAT_VERSION:
        raise TrajectoryError(f"{path}: trajectory format version {v!r} is not supported (this engine "
                              f"reads version {FORMAT_VERSION} frames)")
    for key in ("dim", "frame_every_steps", "n_discs", "step"):
        if not _is_count(attrs.get(key)):
            raise TrajectoryError(f"{path}: attribute {key!r} = {attrs.get(key)!r} is not a count")
    dim = int(attrs["dim"])
    if dim not in (2, 3):
        raise TrajectoryError(f"{path}: dim = {dim}: must be 2 or 3")
    if int(attrs["frame_every_steps"]) < 1:
        raise TrajectoryError(f"{path}: frame_every_steps must be >= 1")
    dt = attrs.get("dt")
    if not isinstance(dt, (float, np.floating)) or not (0.0 < float(dt) < 1.0):
        raise TrajectoryError(f"{path}: attribute 'dt' = {dt!r} is not a time step")
    s = int(attrs["step"])
    if step is not None and s != step:
        raise TrajectoryError(f"{path}: holds step {s}, its name says {step} (renamed or edited)")
    t = attrs.get("time")
    if not isinstance(t, (float, np.floating)) or not np.isfinite(t):
        raise TrajectoryError(f"{path}: attribute 'time' = {t!r} is not a time")
    ws = attrs.get("wheel_state")
    if (not isinstance(ws, np.ndarray) or ws.dtype != _DTYPES["wheel_state"] or ws.shape != (WS_SIZE,)
            or not np.isfinite(ws).all()):
        raise TrajectoryError(f"{path}: attribute 'wheel_state' is not {WS_SIZE} finite float64 numbers")
    h = str(attrs.get("scenario_hash", ""))
    rows = None
    for k in ROW_FIELDS:
        tail = _tails(dim)[k]
        ds = _checked_dataset(f, k, tail, path)
        if rows is None:
            rows = ds.shape[0]
        elif ds.shape[0] != rows:
            raise TrajectoryError(f"{path}: dataset {k!r} has {ds.shape[0]} rows, 'id' has {rows}")
    if rows > MAX_ROWS:
        raise TrajectoryError(f"{path}: {rows} rows (refused)")
    if rows > int(attrs["n_discs"]):
        raise TrajectoryError(f"{path}: {rows} rows, more than its n_discs = {int(attrs['n_discs'])}")
    _check_row_bytes(f, path, rows, dim)
    return {"dim": dim, "frame_every_steps": int(attrs["frame_every_steps"]), "dt": float(dt),
            "scenario_hash": h, "step": s, "time": float(t), "wheel_state": np.array(ws), "rows": rows,
            "n_discs": int(attrs["n_discs"])}


def _open_frame(path, step: int | None = None):
    h5py = _h5py()
    try:
        f = h5py.File(path, "r")
    except (OSError, ValueError) as e:
        raise TrajectoryError(f"{path}: not a readable HDF5 file ({one_line(e)})") from None
    try:
        head = _check_frame_file(f, path, step)
    except BaseException:
        f.close()
        raise
    return f, head


# ------------------------------------------------------------------ writer

def _checked_dataset(f, k: str, tail: tuple, path):
    """Dataset k of an open trajectory file, refused unless it is a hard-linked, local
    dataset of our dtype with row shape ``tail`` (one-line TrajectoryError)."""
    h5py = _h5py()
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
    return ds


class TrajectoryWriter:
    """Write frames to ``RUN/trajectory/``, one file a frame (see the module docstring).

    ``due(step)`` tells whether a frame is written at ``step``; ``write_part(step, p)``
    appends discs of that frame to its temporary file (any order, any number of parts);
    ``end(step, time, ws)`` publishes it.
    """

    def __init__(self, folder: Path, sc, dim: int, n: int, every: int, durable: bool = False):
        self.folder = folder
        self.path = folder
        self.every = every
        self.dim = dim
        self.n = n
        self.durable = durable
        self.header = {"format": FORMAT_NAME, "format_version": FORMAT_VERSION, "dim": dim,
                       "frame_every_steps": every, "dt": float(sc.physics.dt),
                       "scenario_hash": sc.hash(), "n_discs": n}
        self.steps: list[int] = []        # the published frames' steps, rising
        self._pending_step = None
        self._tmp = None                  # the pending frame's temporary (path, h5py file)

    @property
    def committed(self) -> int:
        return len(self.steps)

    # ---- opening
    @classmethod
    def create(cls, out, sc, dim: int, n: int, durable: bool = False) -> "TrajectoryWriter | None":
        """A new trajectory for a run starting at step 0 (None if the scenario has none);
        frames a stopped run left in its own folder are deleted (our names only)."""
        every = frame_every(sc)
        if not every:
            return None
        w = cls(_folder(out, create=True), sc, dim, n, every, durable)
        w._drop_after(-1)
        return w

    @classmethod
    def reopen(cls, out, sc, dim: int, n: int, step: int, durable: bool = False) -> "TrajectoryWriter | None":
        """The trajectory of a run resumed at ``step``: frames after it and leftover temporaries
        are deleted; a published frame that does not belong to this run (unreadable, another
        scenario or interval) is set aside as ``*.damaged`` with a warning."""
        every = frame_every(sc)
        if not every:
            return None
        w = cls(_folder(out, create=True), sc, dim, n, every, durable)
        w._drop_after(step)
        w._migrate_legacy(Path(out), step)
        w.steps = []
        for s, p in _scan(w.folder)[0].items():
            try:
                f, head = _open_frame(p, s)
                f.close()
                for key in ("dim", "frame_every_steps", "scenario_hash"):
                    if head[key] != w.header[key]:
                        raise TrajectoryError(f"{p}: {key} {head[key]!r}, the run's is {w.header[key]!r}")
            except TrajectoryError as e:
                aside = p.with_name(p.name + ".damaged")
                os.replace(p, aside)
                print(f"ooc-dem: warning: {one_line(e)}; kept as {aside.name}", file=sys.stderr)
                continue
            w.steps.append(s)
        if not w.steps and step > 0:
            print(f"ooc-dem: warning: {w.folder}: no frame up to step {step}; the trajectory "
                  f"restarts there", file=sys.stderr)
        return w

    def _drop_after(self, step: int) -> None:
        """Delete the published frames after ``step`` (last first: a kill meanwhile leaves a
        prefix) and every leftover temporary of our name pattern."""
        frames, temps = _scan(self.folder)
        for s in sorted((s for s in frames if s > step), reverse=True):
            os.unlink(frames[s])
        for t in temps:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(t)
        if self.durable:
            _fsync(self.folder)
        self.steps = [s for s in frames if s <= step]

    def _migrate_legacy(self, out: Path, step: int) -> None:
        """A run started with a version-1 ``trajectory.h5``: its frames up to ``step`` that the
        folder lacks are copied into it (so a kill during the copy is completed by the next
        resume; the old file stays, unused); an unusable one is skipped with a warning."""
        if not os.path.lexists(out / TRAJECTORY_FILE):
            return
        have = set(self.steps)
        try:
            with Trajectory(run_file(out, TRAJECTORY_FILE)) as old:
                if old.dim != self.dim or old.frame_every != self.every or old.scenario_hash != self.header["scenario_hash"]:
                    raise TrajectoryError(f"{old.path}: written by another scenario or interval")
                for i in range(len(old)):
                    if old.steps[i] <= step and int(old.steps[i]) not in have:
                        fr = old[i]
                        self.write_frame(fr["step"], fr["time"], fr["wheel_state"], [fr])
        except RunFileError as e:
            print(f"ooc-dem: warning: {one_line(e)}; the trajectory continues in {self.folder} "
                  f"without its frames", file=sys.stderr)

    def last_step(self) -> int | None:
        return self.steps[-1] if self.steps else None

    def due(self, step: int) -> bool:
        """Whether a frame belongs at ``step`` and is not published yet."""
        last = self.last_step()
        return step % self.every == 0 and (last is None or step > last)

    # ---- writing
    def _discard(self) -> None:
        if self._tmp is not None:
            tmp, f, guard = self._tmp
            self._tmp = None
            self._pending_step = None
            with contextlib.suppress(Exception):
                close_h5(f, guard)
            with contextlib.suppress(OSError):
                os.unlink(tmp)

    def _begin(self, step: int) -> None:
        self._discard()
        if not 0 <= step <= MAX_STEP:
            raise TrajectoryError(f"step {step}: out of the frame names' range")
        target = self.folder / frame_name(step)
        # the whole frame is refused up front when it cannot fit (one line, nothing written);
        # a failure while writing is the guard's (writeguard), raised as an OSError
        check_room(target, self.n * _row_bytes(self.dim) + H5_OVERHEAD)
        tmp = new_temp(target)
        try:
            f, guard = create_h5(tmp, exclusive=False)
        except BaseException:
            os.unlink(tmp)
            raise
        self._tmp = (tmp, f, guard)
        self._pending_step = step
        for k, v in self.header.items():
            f.attrs[k] = v
        chunk = max(1, min(self.n, MAX_CHUNK_ROWS))
        for k in ROW_FIELDS:
            tail = _tails(self.dim)[k]
            f.create_dataset(k, shape=(0, *tail), maxshape=(None, *tail), dtype=_DTYPES[k],
                             chunks=(chunk, *tail))

    def write_part(self, step: int, arrays) -> None:
        """Append discs of the frame at ``step`` to its temporary file: ``arrays`` has id, pos,
        vel, spin, r, mat (a ``Particles`` or a store record)."""
        get = (lambda k: getattr(arrays, k)) if not isinstance(arrays, dict) else arrays.__getitem__
        if self._pending_step != step:   # a new frame: drop any unfinished one
            self._begin(step)
        _, f, guard = self._tmp
        ids = np.asarray(get("id"))
        m = len(ids)
        if m == 0:
            return
        try:
            start = f["id"].shape[0]
            for k in ROW_FIELDS:
                ds = f[k]
                ds.resize(start + m, axis=0)
                ds[start:start + m] = np.asarray(get(k), _DTYPES[k])
            guard.check()
        except BaseException:
            self._discard()
            raise

    def end(self, step: int, time: float, wheel_state) -> None:
        """Publish the frame at ``step`` (its rows written by write_part): its step, time and
        wheel state, close, (fsync,) rename into place (, fsync the folder)."""
        if self._pending_step != step:
            self._begin(step)
        tmp, f, guard = self._tmp
        try:
            f.attrs["step"] = int(step)
            f.attrs["time"] = float(time)
            f.attrs["wheel_state"] = np.asarray(wheel_state, _DTYPES["wheel_state"])
            self._tmp = (tmp, None, guard)
            close_h5(f, guard)
            if self.durable:
                _fsync(tmp)
            os.replace(tmp, self.folder / frame_name(step))
        except BaseException:
            self._discard()
            raise
        self._tmp = None
        self._pending_step = None
        if self.durable:
            _fsync(self.folder)
        self.steps = [s for s in self.steps if s < step] + [int(step)]

    def write_frame(self, step: int, time: float, wheel_state, parts) -> None:
        """A whole frame from an iterable of parts."""
        self._discard()
        for p in parts:
            self.write_part(step, p)
        self.end(step, time, wheel_state)

    def close(self) -> None:
        self._discard()


# ------------------------------------------------------------------ reader

# format version 1: RUN/trajectory.h5, all frames in one file (read only)

def _check_legacy_layout(f, path) -> None:
    """The attributes and datasets of a trajectory, as ooc-dem writes them (untrusted input)."""
    attrs = f.attrs
    fmt = attrs.get("format")
    if not isinstance(fmt, str) or fmt != FORMAT_NAME:   # an array attribute compares element-wise
        raise TrajectoryError(f"{path}: not an ooc-dem trajectory")
    v = attrs.get("format_version")
    if not isinstance(v, (int, np.integer)) or int(v) != LEGACY_VERSION:
        raise TrajectoryError(f"{path}: trajectory format version {v!r} is not supported (this engine "
                              f"reads versions {LEGACY_VERSION} and {FORMAT_VERSION})")
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
        _checked_dataset(f, k, tail, path)


def _check_legacy_index(f, path, F: int) -> dict[str, np.ndarray]:
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
        if int(rows.max()) > int(f.attrs["n_discs"]):
            raise TrajectoryError(f"{path}: a frame of {int(rows.max())} rows, more than n_discs")
        _check_row_bytes(f, path, end, int(f.attrs["dim"]))
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

    def __init__(self, path):
        path = Path(path)
        self.path = path
        self.f = None
        self.files = None
        if os.path.isdir(path):
            self._open_folder(path)
        else:
            self._open_legacy(path)

    def _open_folder(self, folder: Path) -> None:
        frames, _ = _scan(folder)
        self.files = list(frames.values())
        heads = []
        for s, p in frames.items():
            f, head = _open_frame(p, s)
            f.close()
            if heads:
                for key in ("dim", "frame_every_steps", "dt", "scenario_hash", "n_discs"):
                    if head[key] != heads[0][key]:
                        raise TrajectoryError(f"{p}: {key} {head[key]!r}, the first frame's is "
                                              f"{heads[0][key]!r} (frames of different runs)")
            heads.append(head)
        F = len(heads)
        self.n_frames = F
        self.index = {
            "frame_step": np.array([h["step"] for h in heads], np.int64),
            "frame_time": np.array([h["time"] for h in heads], np.float64),
            "frame_start": np.zeros(F, np.int64),
            "frame_rows": np.array([h["rows"] for h in heads], np.int64),
            "wheel_state": (np.array([h["wheel_state"] for h in heads], np.float64) if F
                            else np.zeros((0, WS_SIZE))),
        }
        h0 = heads[0] if heads else {}
        self.dim = h0.get("dim")
        self.frame_every = h0.get("frame_every_steps")
        self.dt = h0.get("dt")
        self.scenario_hash = h0.get("scenario_hash")

    def _open_legacy(self, path: Path) -> None:
        h5py = _h5py()
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
    def of_run(cls, run_dir) -> "Trajectory":
        """The trajectory of a run directory: ``trajectory/``, else a version-1
        ``trajectory.h5`` (TrajectoryError if it has none)."""
        run_dir = Path(run_dir)
        if not run_dir.is_dir():
            raise TrajectoryError(f"{run_dir}: not a run directory")
        folder = _folder(run_dir, create=False)
        if folder is not None:
            return cls(folder)
        f = run_file(run_dir, TRAJECTORY_FILE)
        if f is None:
            raise TrajectoryError(f"{run_dir}: no {TRAJECTORY_DIR}/ (the run wrote no frames: set "
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
        """(first row, number of rows) of frame i in the row datasets of ``file(i)``."""
        return int(self.index["frame_start"][i]), int(self.index["frame_rows"][i])

    def file(self, i: int) -> Path:
        """The HDF5 file holding frame i."""
        return self.path if self.files is None else self.files[i]

    def file_rows(self, i: int) -> int:
        """The number of rows of the row datasets in ``file(i)``."""
        return self.f["id"].shape[0] if self.files is None else self.rows(i)[1]

    def __getitem__(self, i: int) -> dict:
        if not -self.n_frames <= i < self.n_frames:
            raise IndexError(f"frame {i}: the trajectory has {self.n_frames}")
        i %= self.n_frames
        a, m = self.rows(i)
        if self.files is None:
            out = {k: self.f[k][a:a + m] for k in ROW_FIELDS}
        else:
            f, head = _open_frame(self.files[i], int(self.steps[i]))
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

    def __iter__(self):
        for i in range(self.n_frames):
            yield self[i]

    def close(self) -> None:
        if self.f is not None:
            self.f.close()
            self.f = None

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
    velocity, spin, radius, id, material) as HyperSlab references into the frame's HDF5 file
    (no copy of the data: the XDMF file refers to each by a path relative to itself), and in
    2D, when the run's scenario has a wheel, the wheel's outline as a polygon (``wheel_outline``
    at the frame's wheel state; inline, a few hundred numbers). Written under a temporary name."""
    from xml.sax.saxutils import quoteattr
    from .export import ExportError, _Atomic, check_targets
    out = Path(out)
    if out.suffix.lower() not in (".xdmf", ".xmf"):
        raise ExportError(f"--out {out}: give a .xdmf (or .xmf) file name")
    check_targets([out], out)
    base = out.parent.resolve()

    def rel_of(i: int) -> str:
        rel = os.path.relpath(traj.file(i).resolve(), base)
        if ":" in rel or any(c in rel for c in "\n\r"):
            raise ExportError(f"--out {out}: the path to {traj.file(i)} from there contains ':' (XDMF "
                              f"cannot refer to it)")
        return rel

    if not len(traj):
        raise ExportError(f"{traj.path}: no published frame yet")
    rels = [rel_of(i) for i in range(len(traj))]
    dim = traj.dim
    D, R = len(axes(dim)), spin_width(dim)
    geo = "XY" if D == 2 else "XYZ"
    num = {"id": ('Int', 8), "pos": ('Float', 8), "vel": ('Float', 8), "spin": ('Float', 8),
           "r": ('Float', 8), "mat": ('Int', 4)}
    wheel = sc is not None and sc.wheel.enabled and dim == 2

    def slab(i: int, name: str, start: int, m: int, width: int | None, ind: str) -> str:
        nt, prec = num[name]
        src = quoteattr(f"{rels[i]}:/{name}")[1:-1]
        total = traj.file_rows(i)
        if width is None:
            sel, dims, full = f"{start} 1 {m}", f"{m}", f"{total}"
            sdims = "3 1"
        else:
            sel, dims, full = f"{start} 0 1 1 {m} {width}", f"{m} {width}", f"{total} {width}"
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
            f.write(slab(i, "pos", start, m, D, ind + " "))
            f.write(f'{ind}</Geometry>\n')
            for label, name, width, kind in attrs:
                f.write(f'{ind}<Attribute Name="{label}" AttributeType="{kind}" Center="Node">\n')
                f.write(slab(i, name, start, m, width, ind + " "))
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
