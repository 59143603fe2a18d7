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
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ooc_dem.storage.writeguard import H5_OVERHEAD, GuardedFile, check_room, close_h5, create_h5

from ..storage.atomic import new_temp
from .runfiles import RunFileError, one_line, run_file
from .trajectory_format import (
    DTYPES,
    FORMAT_NAME,
    FORMAT_VERSION,
    MAX_CHUNK_ROWS,
    MAX_STEP,
    ROW_FIELDS,
    TRAJECTORY_FILE,
    TrajectoryError,
    frame_every,
    frame_name,
    open_frame,
    row_bytes,
    row_tails,
    scan_frames,
    trajectory_folder,
)
from .trajectory_read import Trajectory

if TYPE_CHECKING:
    from ..model.scenario import Scenario
    from ..model.state import Particles


def _fsync(path: str | os.PathLike[str]) -> None:
    fd = os.open(os.fspath(path), os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class TrajectoryWriter:
    """Write frames to ``RUN/trajectory/``, one file a frame (see the module docstring).

    ``due(step)`` tells whether a frame is written at ``step``; ``write_part(step, p)``
    appends discs of that frame to its temporary file (any order, any number of parts);
    ``end(step, time, ws)`` publishes it.
    """

    def __init__(self, folder: Path, sc: Scenario, dim: int, n: int, every: int, durable: bool = False) -> None:
        self.folder = folder
        self.path = folder
        self.every = every
        self.dim = dim
        self.n = n
        self.durable = durable
        self.header: dict[str, Any] = {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "dim": dim,
            "frame_every_steps": every,
            "dt": float(sc.physics.dt),
            "scenario_hash": sc.hash(),
            "n_discs": n,
        }
        self.steps: list[int] = []  # the published frames' steps, rising
        self._pending_step: int | None = None
        # the pending frame's temporary (path, h5py file, its guard); set with _pending_step
        self._tmp: tuple[Path, Any, GuardedFile] | None = None

    @property
    def committed(self) -> int:
        return len(self.steps)

    # ---- opening
    @classmethod
    def create(
        cls, out: str | os.PathLike[str], sc: Scenario, dim: int, n: int, durable: bool = False
    ) -> TrajectoryWriter | None:
        """A new trajectory for a run starting at step 0 (None if the scenario has none);
        frames a stopped run left in its own folder are deleted (our names only)."""
        every = frame_every(sc)
        if not every:
            return None
        w = cls(trajectory_folder(out, create=True), sc, dim, n, every, durable)
        w._drop_after(-1)
        return w

    @classmethod
    def reopen(
        cls, out: str | os.PathLike[str], sc: Scenario, dim: int, n: int, step: int, durable: bool = False
    ) -> TrajectoryWriter | None:
        """The trajectory of a run resumed at ``step``: frames after it and leftover temporaries
        are deleted; a published frame that does not belong to this run (unreadable, another
        scenario or interval) is set aside as ``*.damaged`` with a warning."""
        every = frame_every(sc)
        if not every:
            return None
        w = cls(trajectory_folder(out, create=True), sc, dim, n, every, durable)
        w._drop_after(step)
        w._migrate_legacy(Path(out), step)
        w.steps = []
        for s, p in scan_frames(w.folder)[0].items():
            try:
                f, head = open_frame(p, s)
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
            print(
                f"ooc-dem: warning: {w.folder}: no frame up to step {step}; the trajectory restarts there",
                file=sys.stderr,
            )
        return w

    def _drop_after(self, step: int) -> None:
        """Delete the published frames after ``step`` (last first: a kill meanwhile leaves a
        prefix) and every leftover temporary of our name pattern."""
        frames, temps = scan_frames(self.folder)
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
            with Trajectory(run_file(out, TRAJECTORY_FILE, required=True)) as old:
                if (
                    old.dim != self.dim
                    or old.frame_every != self.every
                    or old.scenario_hash != self.header["scenario_hash"]
                ):
                    raise TrajectoryError(f"{old.path}: written by another scenario or interval")
                for i in range(len(old)):
                    if old.steps[i] <= step and int(old.steps[i]) not in have:
                        fr = old[i]
                        self.write_frame(fr["step"], fr["time"], fr["wheel_state"], [fr])
        except RunFileError as e:
            print(
                f"ooc-dem: warning: {one_line(e)}; the trajectory continues in {self.folder} without its frames",
                file=sys.stderr,
            )

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

    def _begin(self, step: int) -> tuple[Path, Any, GuardedFile]:
        self._discard()
        if not 0 <= step <= MAX_STEP:
            raise TrajectoryError(f"step {step}: out of the frame names' range")
        target = self.folder / frame_name(step)
        # the whole frame is refused up front when it cannot fit (one line, nothing written);
        # a failure while writing is the guard's (writeguard), raised as an OSError
        check_room(target, self.n * row_bytes(self.dim) + H5_OVERHEAD)
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
            tail = row_tails(self.dim)[k]
            f.create_dataset(k, shape=(0, *tail), maxshape=(None, *tail), dtype=DTYPES[k], chunks=(chunk, *tail))
        return self._tmp

    def _frame(self, step: int) -> tuple[Path, Any, GuardedFile]:
        """The temporary of the frame at ``step``: a new frame drops any unfinished one."""
        if self._pending_step != step or self._tmp is None:
            return self._begin(step)
        return self._tmp

    def write_part(self, step: int, arrays: Particles | dict[str, NDArray[Any]]) -> None:
        """Append discs of the frame at ``step`` to its temporary file: ``arrays`` has id, pos,
        vel, spin, r, mat (a ``Particles`` or a store record)."""

        def get(k: str) -> NDArray[Any]:
            return arrays[k] if isinstance(arrays, dict) else getattr(arrays, k)

        _, f, guard = self._frame(step)
        ids = np.asarray(get("id"))
        m = len(ids)
        if m == 0:
            return
        try:
            start = f["id"].shape[0]
            for k in ROW_FIELDS:
                ds = f[k]
                ds.resize(start + m, axis=0)
                ds[start : start + m] = np.asarray(get(k), DTYPES[k])
            guard.check()
        except BaseException:
            self._discard()
            raise

    def end(self, step: int, time: float, wheel_state: NDArray[np.float64]) -> None:
        """Publish the frame at ``step`` (its rows written by write_part): its step, time and
        wheel state, close, (fsync,) rename into place (, fsync the folder)."""
        tmp, f, guard = self._frame(step)
        try:
            f.attrs["step"] = int(step)
            f.attrs["time"] = float(time)
            f.attrs["wheel_state"] = np.asarray(wheel_state, DTYPES["wheel_state"])
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

    def write_frame(
        self,
        step: int,
        time: float,
        wheel_state: NDArray[np.float64],
        parts: Iterable[Particles | dict[str, NDArray[Any]]],
    ) -> None:
        """A whole frame from an iterable of parts."""
        self._discard()
        for p in parts:
            self.write_part(step, p)
        self.end(step, time, wheel_state)

    def close(self) -> None:
        self._discard()


class FrameParts:
    """The parts of the trajectory frame at ``step``, as an engine writes them during an
    advance (``engine.interface.FrameParts``)."""

    def __init__(self, frames: TrajectoryWriter, step: int) -> None:
        self.frames = frames
        self.step = step

    def write_part(self, part: dict[str, NDArray[Any]]) -> None:
        self.frames.write_part(self.step, part)


# ------------------------------------------------------------------ wheel outline


def wheel_outline(
    x: float,
    y: float,
    theta: float,
    radius: float,
    n_lugs: int,
    lug_tip_radius: float,
    lug_thickness: float,
    arc_points: int = 6,
) -> np.ndarray:
    """The 2D wheel as one closed polygon (P x 2, counter-clockwise): the rim, and each of the
    ``n_lugs`` lugs (at angles theta + 2 pi k / n, ``lug_thickness`` wide, from the rim out to
    ``lug_tip_radius``) as an outward notch; a plain circle of 72 points without lugs."""
    n = int(n_lugs)
    if n <= 0 or lug_tip_radius <= radius:
        circle = theta + np.linspace(0.0, 2.0 * np.pi, 72, endpoint=False)
        return np.column_stack([x + radius * np.cos(circle), y + radius * np.sin(circle)])
    half = 0.5 * lug_thickness
    a = float(np.arcsin(min(1.0, half / radius)))
    b = float(np.arcsin(min(1.0, half / lug_tip_radius)))
    step = 2.0 * np.pi / n
    radii: list[float] = []
    angles: list[float] = []
    for k in range(n):
        phi = theta + k * step
        radii += [radius, lug_tip_radius, lug_tip_radius, radius]
        angles += [phi - a, phi - b, phi + b, phi + a]
        gap = np.linspace(phi + a, phi + step - a, arc_points + 2)[1:-1]
        radii += [radius] * len(gap)
        angles += list(gap)
    rr, aa = np.asarray(radii), np.asarray(angles)
    return np.column_stack([x + rr * np.cos(aa), y + rr * np.sin(aa)])
