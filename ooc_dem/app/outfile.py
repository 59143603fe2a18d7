"""Writing an output file safely (exports, trajectory XDMF, films): the target checks
(``check_targets``: never a directory, device, FIFO or symlink, never inside an ooc-dem store)
and ``AtomicFile`` (written under a temporary name, renamed into place when complete). A
failure is an ``ExportError`` with one line naming the file."""

from __future__ import annotations

import contextlib
import os
import stat
from pathlib import Path
from types import TracebackType
from collections.abc import Callable
from typing import IO, Any, Literal

from ..errors import OocDemError
from ..storage.atomic import new_temp

STORE_MANIFEST = "MANIFEST.json"  # its presence marks a directory as an ooc-dem store


class ExportError(OocDemError):
    """An export cannot be written (one-line message)."""


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
            kind = (
                "a directory"
                if stat.S_ISDIR(st.st_mode)
                else ("a symlink" if stat.S_ISLNK(st.st_mode) else "not a regular file")
            )
            raise ExportError(f"--out {out}: {f} is {kind} (give a new file name or a regular file)")
        parent = f.parent.resolve()
        if not parent.is_dir():
            raise ExportError(f"--out {out}: directory {f.parent} does not exist")
        for d in (parent, *parent.parents):
            if (d / STORE_MANIFEST).exists():
                raise ExportError(
                    f"--out {out}: {f} would be inside the ooc-dem store {d} (write exports outside any store)"
                )


class AtomicFile:
    """Open `path` for writing under a temporary name; renamed into place on success.

    The temporary comes from ``atomic.new_temp`` (exclusive, unpredictable name).
    """

    def __init__(self, path: Path, mode: str = "w"):
        self.path = Path(path)
        self.mode = mode
        self.tmp: Path | None = None
        self.f: IO[Any] | None = None

    def __enter__(self) -> IO[Any]:
        try:
            self.tmp = new_temp(self.path)
            self.f = open(
                self.tmp,
                self.mode,
                encoding=None if "b" in self.mode else "ascii",
                newline=None if "b" in self.mode else "\n",
            )
        except OSError as e:
            if self.tmp is not None:
                remove_file(self.tmp)
            raise ExportError(write_failure(self.path, e)) from None
        return self.f

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> Literal[False]:
        f, tmp = self.f, self.tmp
        if f is None or tmp is None:  # never entered
            return False
        try:
            f.close()
            if exc_type is None:
                os.replace(tmp, self.path)
        except OSError as e:
            remove_file(tmp)
            raise ExportError(write_failure(self.path, e)) from None
        if exc_type is not None:
            remove_file(tmp)
            if isinstance(exc, OSError):
                raise ExportError(write_failure(self.path, exc)) from None
        return False


def remove_file(p: str | os.PathLike[str]) -> None:
    """Unlink `p` if it is there."""
    try:
        os.unlink(p)
    except FileNotFoundError:
        pass


def write_failure(path: str | os.PathLike[str], e: BaseException) -> str:
    """The one-line message of an OSError `e` writing `path`."""
    detail = getattr(e, "strerror", None) or " ".join(str(e).split()) or type(e).__name__
    return f"{path}: cannot write ({detail})"


def write_h5_replacing(h5: Path, fill: Callable[[Any, Any], None]) -> None:
    """Write the HDF5 file ``h5`` by ``fill(file, guard)`` into a temporary that replaces it
    when complete (a failed or interrupted write leaves no file). The file is written
    through the write guard: a full disk or the file-size limit reaches us as an OSError
    (an ExportError naming ``h5``), never HDF5, which crashes after a failed write; ``fill``
    calls ``guard.check()`` after each block it writes to stop at the first failure."""
    from ..storage.writeguard import close_h5, create_h5

    try:
        tmp = new_temp(h5)
    except OSError as e:
        raise ExportError(write_failure(h5, e)) from None
    f = guard = None
    try:
        f, guard = create_h5(tmp, exclusive=False)
        fill(f, guard)
        f, g = None, f
        close_h5(g, guard)
        os.replace(tmp, h5)
    except BaseException as e:
        if guard is not None:
            with contextlib.suppress(Exception):
                close_h5(f, guard)
        remove_file(tmp)
        if isinstance(e, OSError):
            raise ExportError(write_failure(h5, e)) from None
        raise
