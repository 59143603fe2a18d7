"""Output files written under a temporary name and renamed into place.

A kill leaves each output either absent or complete, never torn. The temporary is
created exclusively with an unpredictable name (mkstemp) beside its target, so a
file or symlink planted in a run directory (which may come from someone else) can
never redirect the write; `os.replace` then replaces the target's directory entry
itself, not whatever a symlink there points to.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

from ooc_dem.storage.writeguard import check_room


def new_temp(path: str | os.PathLike[str]) -> Path:
    """A new, empty temporary file beside `path`, with an ordinary file's permissions."""
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f"{path.name}.tmp-", dir=path.parent)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # not mkstemp's private 0600: outputs are for reading
    finally:
        os.close(fd)
    return Path(name)


def write_replacing(path: str | os.PathLike[str], write: Callable[[Path], object], need: int = 0) -> None:
    """Call ``write(temporary_path)``, then rename the temporary over `path`. `need`: the
    bytes it will write, about (OSError ENOSPC/EFBIG before anything is written when they
    cannot fit: storage.writeguard.check_room)."""
    if need:
        check_room(path, need)
    tmp = new_temp(path)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(e, OSError) and e.filename is None and e.errno is not None:
            raise OSError(e.errno, e.strerror, os.fspath(path)) from None  # name the file
        raise
