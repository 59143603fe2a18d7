"""The trajectory's file format (trajectory.py's module docstring describes it): names,
dtypes and limits, and the checks of a frame file read back (untrusted input: a file that is
not what ooc-dem writes is refused in one line, ``TrajectoryError``)."""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TypeAlias, overload

import numpy as np

from ..physics.layout import WS_SIZE, axes, spin_width
from .runfiles import RunFileError, one_line

if TYPE_CHECKING:
    from ..model.scenario import Scenario

# an open HDF5 file, group or dataset of h5py (untyped in this environment: its names are Any)
H5Object: TypeAlias = Any
# a frame file's header as open_frame checks it (dim, frame_every_steps, dt, scenario_hash,
# step, time, wheel_state, rows, n_discs): values of several types, read from the file
FrameHeader: TypeAlias = dict[str, Any]

TRAJECTORY_DIR = "trajectory"
TRAJECTORY_FILE = "trajectory.h5"  # format version 1 (read, and migrated on resume)
FORMAT_NAME = "ooc-dem trajectory"
FORMAT_VERSION = 2
LEGACY_VERSION = 1
FRAME_RE = re.compile(r"frame-([0-9]{12})\.h5")
TEMP_RE = re.compile(r"frame-[0-9]{12}\.h5\.tmp-[A-Za-z0-9_]{1,64}")
MAX_STEP = 10**12 - 1
ROW_FIELDS = ("id", "pos", "vel", "spin", "r", "mat")
INDEX_FIELDS = ("frame_step", "frame_time", "frame_start", "frame_rows", "wheel_state")
DTYPES: dict[str, np.dtype[Any]] = {
    "id": np.dtype("<i8"),
    "pos": np.dtype("<f8"),
    "vel": np.dtype("<f8"),
    "spin": np.dtype("<f8"),
    "r": np.dtype("<f8"),
    "mat": np.dtype("<i4"),
    "frame_step": np.dtype("<i8"),
    "frame_time": np.dtype("<f8"),
    "frame_start": np.dtype("<i8"),
    "frame_rows": np.dtype("<i8"),
    "wheel_state": np.dtype("<f8"),
}
MAX_CHUNK_ROWS = 1 << 16
MAX_ROWS = 1 << 40  # a hostile file's counts are refused beyond this
MAX_FRAMES = 1 << 24  # a hostile folder's file count is refused beyond this


class TrajectoryError(RunFileError):
    """A trajectory file is missing, unreadable or not what ooc-dem writes (one line)."""


def frame_every(sc: Scenario) -> int:
    """Steps between frames (0: no trajectory): output.snapshot_interval in whole steps."""
    iv = sc.output.snapshot_interval
    if not iv:
        return 0
    return max(1, int(round(iv / sc.physics.dt)))


def frame_name(step: int) -> str:
    return f"frame-{int(step):012d}.h5"


def row_tails(dim: int) -> dict[str, tuple[int, ...]]:
    """Each dataset's shape beyond its first axis, in a run of dimension `dim`."""
    D, R = len(axes(dim)), spin_width(dim)
    return {
        "id": (),
        "pos": (D,),
        "vel": (D,),
        "spin": (R,),
        "r": (),
        "mat": (),
        "frame_step": (),
        "frame_time": (),
        "frame_start": (),
        "frame_rows": (),
        "wheel_state": (WS_SIZE,),
    }


def h5py_module() -> Any:
    """h5py, imported when first needed."""
    import h5py

    return h5py


@overload
def trajectory_folder(out: str | os.PathLike[str], create: Literal[True]) -> Path: ...


@overload
def trajectory_folder(out: str | os.PathLike[str], create: bool) -> Path | None: ...


def trajectory_folder(out: str | os.PathLike[str], create: bool) -> Path | None:
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


def scan_frames(folder: Path) -> tuple[dict[int, Path], list[Path]]:
    """The published frame files of ``folder`` by step, and the leftover temporaries of our
    own name pattern (regular files only); other names are ignored. A frame name that is
    not a regular file (a symlink, a directory, a FIFO) is refused."""
    frames: dict[int, Path] = {}
    temps: list[Path] = []
    try:
        entries = list(os.scandir(folder))
    except OSError as e:
        raise TrajectoryError(f"{folder}: unreadable ({one_line(e)})") from None
    if len(entries) > MAX_FRAMES:
        raise TrajectoryError(f"{folder}: {len(entries)} entries (refused)")
    for entry in entries:
        m = FRAME_RE.fullmatch(entry.name)
        if m:
            if not entry.is_file(follow_symlinks=False):
                raise TrajectoryError(f"{folder / entry.name}: not a regular file (refused)")
            frames[int(m.group(1))] = folder / entry.name
        elif TEMP_RE.fullmatch(entry.name) and entry.is_file(follow_symlinks=False):
            temps.append(folder / entry.name)
    return dict(sorted(frames.items())), temps


def row_bytes(dim: int) -> int:
    """The bytes of one disc's row over every row dataset."""
    return sum(DTYPES[k].itemsize * int(np.prod(row_tails(dim)[k], dtype=np.int64)) for k in ROW_FIELDS)


def check_row_bytes(f: H5Object, path: str | os.PathLike[str], rows: int, dim: int) -> None:
    """Refuse a file whose datasets declare more rows than it holds: the writer's datasets are
    unfiltered, so every row's bytes are in the file, and a read allocates no more than the
    file's own size (nor more than this machine's memory)."""
    import psutil

    for k in ROW_FIELDS:
        if f[k].id.get_create_plist().get_nfilters():
            raise TrajectoryError(f"{path}: dataset {k!r} is filtered or compressed (not what ooc-dem writes; refused)")
    need, size = rows * row_bytes(dim), os.stat(path).st_size
    if need > size or need > psutil.virtual_memory().total // 4:
        raise TrajectoryError(f"{path}: {rows} rows declared ({need} bytes), the file holds {size} bytes (refused)")


def _is_count(a: object) -> bool:
    return isinstance(a, (int, np.integer)) and not isinstance(a, bool) and 0 <= int(a) <= MAX_ROWS


def _check_frame_file(f: H5Object, path: str | os.PathLike[str], step: int | None = None) -> FrameHeader:
    """The header and datasets of one frame file, as ooc-dem writes them (untrusted input);
    returns its header (dim, frame_every_steps, dt, scenario_hash, step, time, wheel_state, rows)."""
    attrs = f.attrs
    fmt = attrs.get("format")
    if not isinstance(fmt, str) or fmt != FORMAT_NAME:  # an array attribute compares element-wise
        raise TrajectoryError(f"{path}: not an ooc-dem trajectory frame")
    v = attrs.get("format_version")
    if not isinstance(v, (int, np.integer)) or int(v) != FORMAT_VERSION:
        raise TrajectoryError(
            f"{path}: trajectory format version {v!r} is not supported (this engine "
            f"reads version {FORMAT_VERSION} frames)"
        )
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
    if (
        not isinstance(ws, np.ndarray)
        or ws.dtype != DTYPES["wheel_state"]
        or ws.shape != (WS_SIZE,)
        or not np.isfinite(ws).all()
    ):
        raise TrajectoryError(f"{path}: attribute 'wheel_state' is not {WS_SIZE} finite float64 numbers")
    h = str(attrs.get("scenario_hash", ""))
    tails = row_tails(dim)
    rows: int = checked_dataset(f, ROW_FIELDS[0], tails[ROW_FIELDS[0]], path).shape[0]  # 'id'
    for k in ROW_FIELDS[1:]:
        ds = checked_dataset(f, k, tails[k], path)
        if ds.shape[0] != rows:
            raise TrajectoryError(f"{path}: dataset {k!r} has {ds.shape[0]} rows, 'id' has {rows}")
    if rows > MAX_ROWS:
        raise TrajectoryError(f"{path}: {rows} rows (refused)")
    if rows > int(attrs["n_discs"]):
        raise TrajectoryError(f"{path}: {rows} rows, more than its n_discs = {int(attrs['n_discs'])}")
    check_row_bytes(f, path, rows, dim)
    return {
        "dim": dim,
        "frame_every_steps": int(attrs["frame_every_steps"]),
        "dt": float(dt),
        "scenario_hash": h,
        "step": s,
        "time": float(t),
        "wheel_state": np.array(ws),
        "rows": rows,
        "n_discs": int(attrs["n_discs"]),
    }


def open_frame(path: str | os.PathLike[str], step: int | None = None) -> tuple[H5Object, FrameHeader]:
    """(open h5py file, header) of a frame file, checked (``step``: the step its name says)."""
    h5py = h5py_module()
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


def checked_dataset(f: H5Object, k: str, tail: tuple[int, ...], path: str | os.PathLike[str]) -> H5Object:
    """Dataset k of an open trajectory file, refused unless it is a hard-linked, local
    dataset of our dtype with row shape ``tail`` (one-line TrajectoryError)."""
    h5py = h5py_module()
    link = f.get(k, getlink=True)
    if not isinstance(link, h5py.HardLink):
        raise TrajectoryError(f"{path}: no dataset {k!r}" if link is None else f"{path}: {k!r} is a link (refused)")
    ds = f[k]
    if not isinstance(ds, h5py.Dataset):
        raise TrajectoryError(f"{path}: {k!r} is not a dataset")
    if ds.is_virtual or ds.external:
        raise TrajectoryError(f"{path}: dataset {k!r} refers to other files (refused)")
    if ds.dtype != DTYPES[k] or ds.shape[1:] != tail:
        raise TrajectoryError(
            f"{path}: dataset {k!r} has dtype {ds.dtype.str} shape {ds.shape}, "
            f"expected {DTYPES[k].str} (rows, {', '.join(map(str, tail))})"
        )
    return ds
