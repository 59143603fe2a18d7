"""Room checks and failure-proof HDF5 files for every writer (epochs, exports, frames, films).

Two guards against a full disk (ENOSPC) or the process's file-size limit (RLIMIT_FSIZE,
EFBIG: Python ignores SIGXFSZ, so a write past the limit fails instead of killing):

* before writing, ``shortfall`` compares an estimated size with the free space of the
  target's file system and with the file-size limit, so a writer can refuse in one line
  before it starts;
* during, ``create_h5`` opens an HDF5 file through ``GuardedFile``, a file object that
  never reports a failed write to HDF5. HDF5 does not survive one: after a failed write its
  metadata cache is inconsistent, and closing the file, or releasing a dataset, or exiting
  the interpreter with the file open, then crashes the process (SIGSEGV, measured with
  HDF5 2.0 / h5py 3.16). The guard records the first error, keeps whatever HDF5 writes
  afterwards in memory (so HDF5 reads back what it wrote and closes cleanly), and
  ``check``/``close_h5`` raise the recorded error as an ordinary OSError once HDF5 is done.
"""

from __future__ import annotations

import errno
import io
import os
import resource
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import h5py
    from _typeshed import ReadableBuffer, WriteableBuffer

# HDF5 superblock, object headers and B-trees over the raw data (20-30 kB measured for a
# trajectory frame or an export)
H5_OVERHEAD = 32 << 10
# after a failure, writes up to this size are kept in memory for HDF5 to read back
# (metadata, a chunk being filled); larger raw data is dropped: the file is thrown away
_KEEP_AFTER_FAILURE = 8 << 20


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB" if n >= 100_000 else f"{n / 1e6:.3f} MB"


def file_size_limit() -> int | None:
    """The soft RLIMIT_FSIZE in bytes (None: unlimited)."""
    soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    return None if soft == resource.RLIM_INFINITY else int(soft)


def shortfall(directory: str | os.PathLike[str], need: int, largest_file: int | None = None) -> tuple[int, str] | None:
    """None if `need` bytes fit in `directory`'s file system and no single file of
    `largest_file` bytes (default: `need`) exceeds the file-size limit; else (errno, the
    reason, e.g. "needs about 1.2 MB, 0.3 MB free on its file system")."""
    need = max(0, int(need))
    largest = need if largest_file is None else max(0, int(largest_file))
    limit = file_size_limit()
    if limit is not None and largest > limit:
        return errno.EFBIG, f"needs about {_mb(largest)}, the file-size limit is {_mb(limit)}"
    st = os.statvfs(os.fspath(directory))
    free = st.f_bavail * st.f_frsize
    if free < need:
        return errno.ENOSPC, f"needs about {_mb(need)}, {_mb(free)} free on its file system"
    return None


def check_room(path: str | os.PathLike[str], need: int, largest_file: int | None = None) -> None:
    """Raise OSError(ENOSPC or EFBIG, reason, path) if `need` bytes cannot be written beside
    `path` (see ``shortfall``)."""
    parent = os.path.dirname(os.path.abspath(os.fspath(path)))
    short = shortfall(parent, need, largest_file)
    if short is not None:
        raise OSError(short[0], f"disk full or file too large: {short[1]}", os.fspath(path))


class GuardedFile(io.RawIOBase):
    """An unbuffered read/write file for h5py's ``fileobj`` driver that never fails a write
    towards HDF5 (see the module docstring): the first OSError is kept in ``error``."""

    def __init__(self, path: str | os.PathLike[str], truncate: bool) -> None:
        super().__init__()
        self.name = os.fspath(path)
        flags = os.O_RDWR | os.O_CLOEXEC | (os.O_TRUNC if truncate else os.O_CREAT | os.O_EXCL)
        self._fd = os.open(self.name, flags, 0o666)
        self._pos = 0
        self._eof = os.fstat(self._fd).st_size
        self._late: list[tuple[int, bytes]] = []  # writes after the failure, in order
        self.error: OSError | None = None

    def readable(self) -> bool:
        return True

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._pos, io.SEEK_END: self._eof}[whence]
        self._pos = max(0, base + offset)
        return self._pos

    def tell(self) -> int:
        return self._pos

    def readinto(self, b: WriteableBuffer) -> int:
        view = memoryview(b).cast("B")
        n = max(0, min(len(view), self._eof - self._pos))
        got = 0
        while got < n:
            chunk = os.pread(self._fd, n - got, self._pos + got)
            if not chunk:
                break
            view[got : got + len(chunk)] = chunk
            got += len(chunk)
        view[got:n] = bytes(n - got)
        for at, data in self._late:  # what HDF5 wrote after the failure, in order
            lo, hi = max(at, self._pos), min(at + len(data), self._pos + n)
            if lo < hi:
                view[lo - self._pos : hi - self._pos] = data[lo - at : hi - at]
        self._pos += n
        return n

    def write(self, b: ReadableBuffer) -> int:
        view = memoryview(b).cast("B")
        n = len(view)
        done = 0
        while self.error is None and done < n:
            try:
                done += os.pwrite(self._fd, view[done:], self._pos + done)
            except OSError as e:
                self.error = e
        if self.error is not None and n - done <= _KEEP_AFTER_FAILURE:
            self._late.append((self._pos + done, bytes(view[done:])))
        self._pos += n
        self._eof = max(self._eof, self._pos)
        return n

    def truncate(self, size: int | None = None) -> int:
        size = self._pos if size is None else int(size)
        if self.error is None:
            try:
                os.ftruncate(self._fd, size)
            except OSError as e:
                self.error = e
        self._eof = size
        return size

    def flush(self) -> None:
        pass

    def check(self) -> None:
        """Raise the first write error (with the file's name), if any."""
        e = self.error
        if e is not None:
            raise OSError(e.errno, e.strerror or str(e), self.name)

    def close(self) -> None:
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.close(fd)
        super().close()


def create_h5(path: str | os.PathLike[str], exclusive: bool = True, **kwargs: Any) -> tuple[h5py.File, GuardedFile]:
    """(h5py.File, GuardedFile) writing `path`: created (exclusive) or, with
    exclusive=False, an existing file truncated. kwargs go to h5py.File."""
    import h5py

    guard = GuardedFile(path, truncate=not exclusive)
    try:
        f = h5py.File(guard, "w", **kwargs)
    except BaseException:
        guard.close()
        raise
    return f, guard


def close_h5(f: h5py.File | None, guard: GuardedFile) -> None:
    """Close an HDF5 file of ``create_h5``; raise the first write error, if any."""
    try:
        if f is not None:
            f.close()
    finally:
        guard.close()
    guard.check()
