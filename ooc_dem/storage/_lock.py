"""One writer per store: an exclusive flock on STORE/.ooc-dem.lock.

A Store open for writing (create_store, open_store(repair=True)) holds the lock until
it is closed; the kernel drops it when the process dies, however it dies, so a killed
run never leaves a stale lock. Read-only opens take no lock and are never refused.

flock locks belong to an open file description: a second open of the lock file in the
*same* process conflicts with the first, which is what we want (two Store writers in one
process would write the same ``*.tmp-<pid>`` names).
"""

from __future__ import annotations

import fcntl
import os
import stat
import time

from ._util import LOCK_FILE, StoreError

# a read-only `live_writer` probe holds a shared lock for microseconds; a writer starting at
# that moment retries for this long before it concludes that another writer holds the store
_ACQUIRE_GRACE_S = 0.5
_RETRY_S = 0.01
_PID_TEXT_MAX = 32  # the lock file holds the holder's pid as text, nothing more
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)


def _holder_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, _PID_TEXT_MAX, 0).decode("ascii", "replace").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() and len(text) <= 10 else None


def _open(path: str, flags: int) -> int:
    """The lock file, which a hostile store may have made a link, a FIFO or a hard link to a
    file elsewhere: only a regular file of one link is used (the pid is written into it)."""
    fd = os.open(path, flags | _NOFOLLOW | getattr(os, "O_NONBLOCK", 0), 0o644)
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
        os.close(fd)
        raise OSError("not a regular file of one link")
    return fd


class StoreLock:
    """The exclusive lock of one store directory, held from construction until release()."""

    def __init__(self, root: str):
        self.path = os.path.join(root, LOCK_FILE)
        self._fd: int | None = None
        try:
            fd = _open(self.path, os.O_RDWR | os.O_CREAT)
        except OSError as e:
            raise StoreError(f"{self.path}: cannot open the store's lock file ({e.strerror or e})") from None
        deadline = time.monotonic() + _ACQUIRE_GRACE_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                pid = _holder_pid(fd)
                if pid != os.getpid() and time.monotonic() < deadline:
                    time.sleep(_RETRY_S)
                    continue
                os.close(fd)
                if pid == os.getpid():
                    raise StoreError(
                        f"{root}: this process already has this store open for writing (close that Store first)"
                    ) from None
                raise StoreError(
                    f"{root}: another process is writing this store "
                    f"(pid {pid if pid is not None else 'unknown'}); wait for it to "
                    f"finish or stop it"
                ) from None
            except OSError as e:
                os.close(fd)
                raise StoreError(f"{self.path}: cannot lock the store ({e.strerror or e})") from None
        try:  # the pid is for messages only: the lock itself is the flock
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        except OSError:
            pass
        self._fd = fd

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)  # closing the last fd of the description drops the flock

    def __del__(self) -> None:  # a Store dropped without close() must not keep the store locked
        self.release()


def live_writer(root: str) -> int | None:
    """Pid of the process holding the store's write lock (0 if unknown), or None if none does.

    Probes with a shared lock, taken and dropped at once; creates nothing.
    """
    path = os.path.join(root, LOCK_FILE)
    try:
        fd = _open(path, os.O_RDONLY)
    except OSError:
        return None  # no lock file (or not a file): nobody can hold it
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = _holder_pid(fd)
            return pid if pid is not None else 0
        except OSError:
            return None
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)
