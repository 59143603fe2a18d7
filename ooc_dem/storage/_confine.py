"""A store is untrusted input: every path read from it is resolved here, and only here.

MANIFEST.json and the epochs it names may come from someone else. Nothing in them
may make the program read, write or delete outside the store, nor read something
that is not a regular file (a FIFO or /dev/zero would make a read hang or never end).
So:

* a path read from a store is a str, relative, "/"-separated, made of non-empty parts
  that are not "." or ".." and hold only the characters our own names use;
* an epoch path is exactly ``epochs/<name>`` where <name> is an epoch file name of the
  store's backend for that very step; a file entry is the epoch path itself (HDF5, the
  memory backend's pseudo-files aside) or strictly below it (zarr, memory);
* after resolving symbolic links the path lies inside the store's real ``epochs/``
  directory, which must itself be a real directory (not a symbolic link);
* files are opened with O_NOFOLLOW | O_NONBLOCK and must be regular files (fstat),
  and are never read beyond the size the manifest (or a fixed cap) allows.

Anything else is refused with a one-line StoreError; nothing is guessed.
"""

from __future__ import annotations

import contextlib
import os
import re
import stat
from collections.abc import Iterable

from ._util import EPOCH_DIR, StoreError, new_digest

# the characters of every name the store itself writes (epoch names, groups, array names,
# zarr keys, the memory backend's ".attrs" pseudo-files)
_PART_RE = re.compile(r"^[A-Za-z0-9_.+\-]+$")
# e000000001234.h5, e000000001234.r1.zarr, e000000001234.p2.h5, e000000001234.mem: step,
# revision, part, extension
_EPOCH_NAME_RE = re.compile(r"^e(\d{12,})(?:\.r(\d+))?(?:\.p(\d+))?\.([a-z0-9]+)$")
# O_NONBLOCK: opening a FIFO for reading must not wait for a writer (it is refused after fstat)
_OPEN_FLAGS = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)


def _short(v: object) -> str:
    """A value from a store as a message may show it: short (at most 80 characters, the
    middle of a longer one cut out), and never an int-to-decimal conversion past Python's
    digit limit (which raises)."""
    if isinstance(v, int) and not isinstance(v, bool) and v.bit_length() > 200:
        return f"<an integer of {v.bit_length()} bits>"
    r = repr(v)
    # a long path's end names what it points at: keep both ends
    return r if len(r) <= 80 else r[:38] + "..." + r[-39:]


def rel_path(value: object, what: str) -> str:
    """A relative "/"-separated path read from a store, checked, or StoreError."""
    if not isinstance(value, str):
        raise StoreError(f"{what}: path must be a string, got {type(value).__name__}")
    if not value or "\0" in value or value.startswith("/"):
        raise StoreError(f"{what}: path {_short(value)} must be relative, non-empty and without NUL")
    parts = value.split("/")
    for p in parts:
        if p in ("", ".", "..") or not _PART_RE.match(p):
            raise StoreError(
                f"{what}: path {_short(value)} has a forbidden part {_short(p)} "
                f"(parts are non-empty names of letters, digits and _ . + -, "
                f"not . or ..)"
            )
    return value


def rel_parts(value: object, what: str) -> list[str]:
    """The parts of a relative "/"-separated path read from a store, or StoreError."""
    return rel_path(value, what).split("/")


def epoch_path(value: object, exts: str | Iterable[str], step: int, what: str, part: int | None = None) -> str:
    """Check an epoch path: exactly "epochs/<name>", <name> an epoch name with one of the
    extensions `exts` (a str or a tuple of them) for `step`; of part `part` of an epoch
    (its ".p<part>"), or of an epoch's main file (no part) when `part` is None."""
    exts = (exts,) if isinstance(exts, str) else tuple(exts)
    path = rel_path(value, what)
    parts = path.split("/")
    name = parts[-1]
    m = _EPOCH_NAME_RE.match(name)
    if len(parts) != 2 or parts[0] != EPOCH_DIR or m is None or m.group(4) not in exts:
        raise StoreError(
            f"{what}: path {_short(value)} is not an epoch path "
            f"({EPOCH_DIR}/e<step, 12+ digits>[.r<n>][.p<k>].{'|'.join(exts)})"
        )
    if int(m.group(1)) != step:
        raise StoreError(f"{what}: path {_short(value)} names step {int(m.group(1))}, the entry says {step}")
    got = None if m.group(3) is None else int(m.group(3))
    if got != part:
        raise StoreError(
            f"{what}: path {_short(value)} is "
            + (f"not part {part} of its epoch" if part is not None else "a part, not an epoch")
        )
    return path


def file_path(value: object, epoch: str, inside: bool, what: str) -> str:
    """Check a file entry of epoch `epoch`: strictly below it (inside=True) or the epoch itself."""
    path = rel_path(value, what)
    if inside and not path.startswith(epoch + "/"):
        raise StoreError(f"{what}: file {_short(path)} is not inside its epoch {epoch}")
    if not inside and path != epoch:
        raise StoreError(f"{what}: file {_short(path)} is not the epoch file {epoch}")
    return path


class Resolver:
    """Turns checked relative paths of one store directory into paths on disk, confined to
    the store's real epochs/ directory."""

    def __init__(self, root: str):
        self.root = root
        self.edir = os.path.join(root, EPOCH_DIR)
        self._real_edir = os.path.join(os.path.realpath(root), EPOCH_DIR)

    def check_epoch_dir(self) -> None:
        """epochs/ must be a real directory (or absent): a symbolic link would send every
        read, write and delete of the store somewhere else."""
        try:
            st = os.lstat(self.edir)
        except FileNotFoundError:
            return
        except OSError as e:
            raise StoreError(f"{self.edir}: cannot examine ({e.strerror or e})") from None
        if stat.S_ISLNK(st.st_mode):
            raise StoreError(
                f"{self.edir}: is a symbolic link; a store's {EPOCH_DIR}/ must be a real directory (refusing to use it)"
            )
        if not stat.S_ISDIR(st.st_mode):
            raise StoreError(f"{self.edir}: is not a directory")

    def path(self, rel: str, what: str) -> str:
        """The on-disk path of a checked relative path; refused if it resolves outside epochs/."""
        p = os.path.join(self.root, *rel_parts(rel, what))
        real = os.path.realpath(p)
        if not real.startswith(self._real_edir + os.sep):
            raise StoreError(
                f"{what}: {rel!r} resolves to {real}, outside the store's {EPOCH_DIR}/ directory (refusing to use it)"
            )
        return p

    def has_no_links(self, p: str) -> bool:
        """Whether no part of `p` (a path from `path`) below the store root is a symbolic link."""
        return os.path.realpath(p) == os.path.join(os.path.dirname(self._real_edir), os.path.relpath(p, self.root))


def open_regular(path: str, what: str | None = None) -> int:
    """A read-only fd of `path` if it is a regular file (not followed if a symbolic link)."""
    where = what or path
    try:
        fd = os.open(path, _OPEN_FLAGS)
    except FileNotFoundError:
        raise StoreError(f"{where}: missing") from None
    except OSError as e:
        if os.path.islink(path):
            raise StoreError(f"{where}: is a symbolic link, not a regular file") from None
        raise StoreError(f"{where}: unreadable ({e.strerror or e})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise StoreError(f"{where}: not a regular file")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_regular(path: str, limit: int, what: str | None = None) -> bytes:
    """The bytes of a regular file of at most `limit` bytes (checked before reading)."""
    where = what or path
    fd = open_regular(path, where)
    try:
        size = os.fstat(fd).st_size
        if size > limit:
            raise StoreError(f"{where}: {size} bytes, more than the {limit} allowed")
        chunks, got = [], 0
        while got <= limit:  # never more than limit + 1 bytes, even if the file grows
            b = os.read(fd, min(1 << 20, limit + 1 - got))
            if not b:
                break
            chunks.append(b)
            got += len(b)
        if got > limit:
            raise StoreError(f"{where}: grew beyond the {limit} bytes allowed while being read")
        return b"".join(chunks)
    except OSError as e:
        raise StoreError(f"{where}: unreadable ({e.strerror or e})") from None
    finally:
        os.close(fd)


def digest_regular(path: str, size: int, name: str, what: str | None = None) -> str:
    """Hex digest `name` (one of ``DIGESTS``) of the first `size` bytes of a regular file that
    must be exactly `size` long (the size is checked before reading; no more than `size`
    bytes are ever read)."""
    where = what or path
    fd = open_regular(path, where)
    try:
        actual = os.fstat(fd).st_size
        if actual != size:
            raise StoreError(f"{where}: size {actual} != recorded {size} (truncated?)")
        h = new_digest(name)
        buf = bytearray(1 << 20)
        mv = memoryview(buf)
        left = size
        while left:
            k = os.readv(fd, [mv[: min(left, len(buf))]])
            if not k:
                raise StoreError(f"{where}: shorter than recorded {size} bytes (truncated?)")
            h.update(mv[:k])
            left -= k
        if hasattr(os, "posix_fadvise"):
            with contextlib.suppress(OSError):
                os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
        return h.hexdigest()
    except OSError as e:
        raise StoreError(f"{where}: unreadable ({e.strerror or e})") from None
    finally:
        os.close(fd)
