"""Helpers shared by the storage backends (no physics, no backend imports)."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import shutil
from collections.abc import Callable, Iterable, Mapping
from typing import TYPE_CHECKING, Any, Protocol, TypeAlias

import numpy as np
from numpy.typing import DTypeLike, NDArray

if TYPE_CHECKING:
    from _typeshed import ReadableBuffer

from ..errors import OocDemError

FORMAT = "ooc-dem-store"
FORMAT_VERSION = 2  # written; what the arrays mean is the application's business
SUPPORTED_VERSIONS = (1, 2)  # read: an epoch records the version it was written in
MANIFEST = "MANIFEST.json"
MANIFEST_TMP = "MANIFEST.json.tmp"
EPOCH_DIR = "epochs"
ATTRS_KEY = "ooc_dem_attrs"  # JSON string attribute holding a group's attrs
# held (flock, exclusive) by the one process writing the store; never deleted, since a
# process may hold it open: a new file under the same name would not exclude anybody
LOCK_FILE = ".ooc-dem.lock"
# a manifest lists a few files per array of two epochs: far below this even for huge runs;
# anything bigger is not ours and is refused before it is read
MAX_MANIFEST_BYTES = 64 << 20
# our manifests and attrs nest a few levels; deeper JSON is refused (it would exhaust the
# interpreter's recursion in json, copy or h5py/zarr code reading it later)
MAX_JSON_DEPTH = 100
# A file's checksum in the manifest: its name is the entry's key (exactly one per file), its
# value the digest in lowercase hex of the length below. It detects a torn, truncated or
# altered epoch file; it is not an authenticity check (whoever can rewrite a file can
# rewrite the manifest). Epochs are written with XXH3-128, which runs at memory speed
# (27 GB/s on this machine against sha256's 1.8 GB/s), so the commit's read-back and
# `verify` are bound by the disk; sha256, what older stores recorded, is still checked.
DIGESTS = {"xxh3_128": 32, "sha256": 64}  # name -> hex digits
_LOWER_HEX = re.compile(r"[0-9a-f]+")
DIGEST = "xxh3_128"

# e000000001234.h5, e000000001234.r1.zarr (".rN" = rewrite of a step still named by the manifest),
# e000000001234.p2.h5 (".pK" = part K of an epoch whose groups several processes wrote, e.g. MPI ranks)
EPOCH_NAME_RE = re.compile(r"^e(\d{12,})(\.r\d+)?(\.p\d+)?\.(h5|zarr|zip)$")
# the temporary an epoch (or a part) is written under by process <pid>: e000000001234.h5.tmp-<pid>
TMP_NAME_RE = re.compile(r"^(e\d{12,}(?:\.r\d+)?(?:\.p\d+)?\.(?:h5|zarr|zip))\.tmp-(\d{1,10})$")
# the most parts an epoch may have (one per MPI rank that owns sub-domains)
MAX_PARTS = 1 << 16
ARRAY_NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.+\-]{0,199}$")
_RESERVED_NAMES = {"zarr.json"}

_DISK_FULL_ERRNOS = {errno.ENOSPC, errno.EFBIG, getattr(errno, "EDQUOT", errno.ENOSPC)}
_DISK_FULL_TEXT = re.compile(
    r"errno = (%s)\b|No space left|File too large|Disk quota exceeded"
    % "|".join(str(e) for e in sorted(_DISK_FULL_ERRNOS))
)


class StoreError(OocDemError):
    """Storage failure; the message names the path and what is wrong (one line)."""


# --------------------------------------------------------------------------- types

StrPath: TypeAlias = "str | os.PathLike[str]"
# a JSON object as parsed (a manifest, an epoch entry, a file entry, a metadata document);
# its values are whatever the JSON held: the validating code checks each before use
JSONObject: TypeAlias = "dict[str, Any]"
# how an array's rows were asked for, normalised (normalize_rows): all, a range, or indices
Rows: TypeAlias = "tuple[int, int] | NDArray[np.int64] | None"


class Digest(Protocol):
    """A hash object of one of ``DIGESTS`` (hashlib's or xxhash's)."""

    def update(self, data: ReadableBuffer, /) -> None: ...

    def hexdigest(self) -> str: ...


class GroupReader(Protocol):
    """An open epoch of any backend, read group by group (memory, HDF5, zarr)."""

    def has_group(self, group: str) -> bool: ...

    def array_info(self, group: str, name: str) -> tuple[tuple[int, ...], np.dtype[Any]] | None: ...

    def attrs_json(self, group: str) -> str | None: ...

    def read_full(self, group: str, name: str, shape: tuple[int, ...], dtype: DTypeLike) -> NDArray[Any]: ...

    def read_range(self, group: str, name: str, start: int, stop: int, out: NDArray[Any]) -> None: ...

    def after_read(self) -> None: ...

    def close(self) -> None: ...


class FormatReader(GroupReader, Protocol):
    """An open epoch file (or directory) of an on-disk format."""

    def root_step(self) -> object: ...


class FormatWriter(Protocol):
    """An epoch being written in an on-disk format, under its temporary name."""

    def write_group(self, group: str, arrays: dict[str, NDArray[Any]], attrs_json: str) -> None: ...

    def finish(self, durable: bool) -> list[tuple[str, int, str]]: ...

    def abort(self) -> None: ...


class EpochFormat(Protocol):
    """An on-disk epoch format: the modules ``_hdf5``, ``_zarr_zip`` and ``_zarr``."""

    @property
    def EXT(self) -> str: ...

    @property
    def IS_DIR(self) -> bool: ...

    @property
    def Writer(self) -> Callable[[str, int, str | None], FormatWriter]: ...

    @property
    def Reader(self) -> Callable[[str], FormatReader]: ...


def attrs_text(v: object) -> str | None:
    """A group's attrs as its file holds them: JSON text (bytes are decoded), None if absent.
    Anything else is refused as json.loads would refuse it."""
    if isinstance(v, bytes):
        v = v.decode()
    if v is None or isinstance(v, str):
        return v
    raise TypeError(f"the JSON object must be str, bytes or bytearray, not {type(v).__name__}")


def epoch_basename(step: int, ext: str, rev: int = 0) -> str:
    return f"e{step:012d}" + (f".r{rev}" if rev else "") + f".{ext}"


def part_basename(basename: str, part: int) -> str:
    """The name of part `part` (>= 1) of the epoch named `basename`: e...[.rN].pK.<ext>."""
    stem, _, ext = basename.rpartition(".")
    return f"{stem}.p{part}.{ext}"


def domain_group(d: int) -> str:
    return f"domains/d{d:04d}"


GLOBALS_GROUP = "globals"


# --------------------------------------------------------------------------- errors


def is_disk_full(exc: BaseException) -> bool:
    if isinstance(exc, OSError) and exc.errno in _DISK_FULL_ERRNOS:
        return True
    return bool(_DISK_FULL_TEXT.search(str(exc)))


def write_error(path: StrPath, exc: BaseException) -> StoreError:
    """StoreError for a failed write of `path` (disk full is named as such)."""
    detail = " ".join(str(exc).split()) or type(exc).__name__
    m = re.search(r"errno = (\d+), error message = '([^']*)'", detail)  # HDF5's verbose form
    if m:
        detail = f"[Errno {m.group(1)}] {m.group(2)}"
    elif len(detail) > 240:
        detail = detail[:240] + "..."
    if is_disk_full(exc):
        return StoreError(f"{path}: disk full or file too large ({detail})")
    return StoreError(f"{path}: write failed ({type(exc).__name__}: {detail})")


# --------------------------------------------------------------------------- JSON


def _json_default(o: object) -> object:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"object of type {type(o).__name__} is not JSON serialisable")


def to_json(obj: object, what: str, indent: int | None = None) -> str:
    try:
        return json.dumps(obj, default=_json_default, indent=indent)
    except (TypeError, ValueError) as e:
        raise StoreError(f"{what}: not JSON-serialisable ({e})") from None


def json_roundtrip(obj: object, what: str) -> Any:
    return json.loads(to_json(obj, what))


def json_depth(obj: object) -> int:
    """Nesting depth of a JSON value (0 for a scalar), without recursion."""
    depth, stack = 0, [(obj, 1)]
    while stack:
        o, d = stack.pop()
        if isinstance(o, dict):
            o = list(o.values())
        if isinstance(o, list):
            depth = max(depth, d)
            stack.extend((v, d + 1) for v in o if isinstance(v, (dict, list)))
    return depth


def parse_json(data: bytes, what: str) -> object:
    """json.loads for untrusted bytes: every failure (bad syntax, bad UTF-8, nesting that
    exhausts the recursion limit, over-long integers) is a one-line StoreError."""
    try:
        obj = json.loads(data)
    except RecursionError:
        raise StoreError(f"{what}: JSON nested too deeply") from None
    except ValueError as e:  # JSONDecodeError, UnicodeDecodeError, int digit limit
        raise StoreError(f"{what}: not valid JSON ({' '.join(str(e).split())[:200]})") from None
    if json_depth(obj) > MAX_JSON_DEPTH:
        raise StoreError(f"{what}: JSON nested deeper than {MAX_JSON_DEPTH} levels")
    return obj


# --------------------------------------------------------------------------- arrays


def check_array_name(name: object, where: str) -> str:
    if not isinstance(name, str) or not ARRAY_NAME_RE.match(name) or name in _RESERVED_NAMES:
        raise StoreError(f"{where}: invalid array name {name!r} (letters, digits, _ . + -; not starting with . or -)")
    return name


def prepare_arrays(arrays: object, where: str, min_ndim: int) -> dict[str, NDArray[Any]]:
    """Validate names/dtypes; return C-contiguous native-byte-order arrays."""
    if not isinstance(arrays, Mapping):
        raise StoreError(f"{where}: arrays must be a dict name -> numpy array")
    out: dict[str, NDArray[Any]] = {}
    for name, a in arrays.items():
        check_array_name(name, where)
        a = np.asarray(a)
        if a.dtype.kind not in "biufc" or a.dtype.fields is not None:
            raise StoreError(f"{where}: array {name!r} has non-numeric dtype {a.dtype}")
        if a.ndim < min_ndim:
            raise StoreError(f"{where}: array {name!r} must have at least {min_ndim} dimension(s)")
        if not a.dtype.isnative:
            a = a.astype(a.dtype.newbyteorder("="))
        out[name] = a if a.flags.c_contiguous else a.copy(order="C")  # (ascontiguousarray makes 0-d 1-d)
    return out


def array_meta(arrays: dict[str, NDArray[Any]]) -> dict[str, list[Any]]:
    return {n: [list(a.shape), a.dtype.str] for n, a in arrays.items()}


def normalize_rows(rows: object, n: int, where: str) -> Rows:
    """None -> None; slice -> (start, stop) if step 1; otherwise a 1-D int64 index array."""
    if rows is None:
        return None
    if isinstance(rows, slice):
        start, stop, step = rows.indices(n)
        if step == 1:
            return (start, max(start, stop))
        return np.arange(start, stop, step, dtype=np.int64)
    idx = np.asarray(rows)
    if idx.dtype == bool:
        if idx.shape != (n,):
            raise StoreError(f"{where}: boolean row mask has shape {idx.shape}, expected ({n},)")
        return np.flatnonzero(idx).astype(np.int64)
    if idx.ndim != 1 or (idx.size and idx.dtype.kind not in "iu"):
        raise StoreError(f"{where}: rows must be a slice, a 1-D integer index array or a boolean mask")
    idx = idx.astype(np.int64, copy=True)
    idx[idx < 0] += n
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise StoreError(f"{where}: row index out of range for {n} rows")
    return idx


def gather_rows(
    read_range: Callable[[int, int, NDArray[Any]], object],
    idx: NDArray[np.int64],
    shape: tuple[int, ...],
    dtype: DTypeLike,
    window_bytes: int = 1 << 20,
) -> NDArray[Any]:
    """Read rows `idx` using read_range(start, stop, out_view) over windows of nearby rows.

    Only the rows spanned by each window are read (windows are at most
    `window_bytes` wide), so a sparse selection never reads the whole array.
    """
    out = np.empty((idx.size,) + tuple(shape[1:]), dtype=dtype)
    if idx.size == 0:
        return out
    order: NDArray[np.intp] | None = None
    if np.any(idx[1:] < idx[:-1]):
        order = np.argsort(idx, kind="stable")
        idx = idx[order]
    row_bytes = max(1, int(np.prod(shape[1:], dtype=np.int64)) * np.dtype(dtype).itemsize)
    max_span = max(1, window_bytes // row_bytes)
    i = 0
    m = idx.size
    buf: NDArray[Any] | None = None
    while i < m:
        start = int(idx[i])
        j = int(np.searchsorted(idx, start + max_span, side="left"))
        stop = int(idx[j - 1]) + 1
        if stop - start == j - i and np.all(np.diff(idx[i:j]) == 1):
            read_range(start, stop, out[i:j])  # contiguous run: read straight into place
        else:
            if buf is None or buf.shape[0] < stop - start:
                buf = np.empty((max(stop - start, 1),) + tuple(shape[1:]), dtype=dtype)
            view = buf[: stop - start]
            read_range(start, stop, view)
            out[i:j] = view[idx[i:j] - start]
        i = j
    if order is not None:
        res = np.empty_like(out)
        res[order] = out
        out = res
    return out


# --------------------------------------------------------------------------- files


def drop_page_cache(path: StrPath, sync: bool = False) -> None:
    """Ask the kernel to drop cached pages of `path` (a file, or every file under a directory).

    Uses posix_fadvise(POSIX_FADV_DONTNEED); dirty pages cannot be dropped until
    written back (the call starts write-back), pass sync=True to fdatasync first.
    Never raises: it is a hint.
    """
    if not hasattr(os, "posix_fadvise"):
        return
    path = os.fspath(path)
    if os.path.isdir(path):
        for root, _dirs, files in os.walk(path):
            for f in files:
                drop_page_cache(os.path.join(root, f), sync)
        return
    try:  # never blocks on a FIFO, never follows a link: a hint is not worth a risk
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return
    try:
        if sync:
            os.fdatasync(fd)
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    except OSError:
        pass
    finally:
        os.close(fd)


def _sync_file_range() -> Callable[[int, int, int, int], int] | None:
    """libc's sync_file_range (Linux), or None."""
    import ctypes

    try:
        f = ctypes.CDLL(None, use_errno=True).sync_file_range
    except (AttributeError, OSError):
        return None
    f.argtypes = [ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_uint]
    return f


_SYNC_FILE_RANGE = _sync_file_range()
_SYNC_FILE_RANGE_WRITE = 2


def start_writeback(path: StrPath) -> None:
    """Start writing a file's dirty pages to disk without waiting and without dropping them
    (sync_file_range SYNC_FILE_RANGE_WRITE): dirty pages never pile up, and the file is
    still in the page cache when its checksum is read back at the commit, which then drops
    it. Where that call is missing, the pages are dropped now (``drop_page_cache``). Never
    raises: it is a hint."""
    if _SYNC_FILE_RANGE is None or os.path.isdir(path):
        drop_page_cache(path)
        return
    try:
        fd = os.open(os.fspath(path), os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return
    try:
        _SYNC_FILE_RANGE(fd, 0, 0, _SYNC_FILE_RANGE_WRITE)
    finally:
        os.close(fd)


def new_digest(name: str = DIGEST) -> Digest:
    """A fresh hash object of checksum `name` (one of ``DIGESTS``)."""
    if name == "xxh3_128":
        import xxhash

        return xxhash.xxh3_128()
    return hashlib.new(name)


def bytes_digest(raw: ReadableBuffer, name: str = DIGEST) -> str:
    """Hex digest `name` of bytes already in memory."""
    h = new_digest(name)
    h.update(raw)
    return h.hexdigest()


def show(v: object) -> str:
    """A value from a manifest for a one-line message (short, whatever it is)."""
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


def file_checksum(entry: Mapping[str, object], what: str) -> tuple[str, str]:
    """(digest name, hex) of a manifest file entry: exactly one of ``DIGESTS``' keys, its
    value that digest's hex length in lowercase; StoreError otherwise (hostile manifests)."""
    names = [k for k in DIGESTS if k in entry]
    if len(names) != 1:
        raise StoreError(f"{what}: {'no' if not names else 'more than one'} checksum (one of {', '.join(DIGESTS)})")
    name = names[0]
    hexv = entry[name]
    if not (isinstance(hexv, str) and len(hexv) == DIGESTS[name] and _LOWER_HEX.fullmatch(hexv)):
        raise StoreError(f"{what}: {name} {show(hexv)} is not {DIGESTS[name]} lowercase hex digits")
    return name, hexv


def file_entries(rel: str, inner: Iterable[tuple[str, int, str]]) -> list[JSONObject]:
    """Manifest file entries of an epoch at `rel` from its writer's [(relpath inside, size,
    digest)] ("" = the epoch is the file itself)."""
    return [{"path": rel if r == "" else f"{rel}/{r}", "size": size, DIGEST: digest} for r, size, digest in inner]


def file_digest(path: StrPath, drop_cache: bool = True, name: str = DIGEST) -> tuple[int, str]:
    """(size, hex digest `name`) of a file's bytes."""
    h = new_digest(name)
    size = 0
    with open(path, "rb", buffering=0) as f:
        buf = bytearray(1 << 20)
        mv = memoryview(buf)
        while True:
            k = f.readinto(buf)
            if not k:
                break
            h.update(mv[:k])
            size += k
        if drop_cache and hasattr(os, "posix_fadvise"):
            with contextlib.suppress(OSError):
                os.posix_fadvise(f.fileno(), 0, 0, os.POSIX_FADV_DONTNEED)
    return size, h.hexdigest()


def fsync_path(path: StrPath) -> None:
    fd = os.open(os.fspath(path), os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_tree(path: StrPath) -> None:
    """fsync every file and directory under `path` (bottom-up), then `path` itself."""
    for root, dirs, files in os.walk(path, topdown=False):
        for f in files:
            fsync_path(os.path.join(root, f))
        fsync_path(root)


def remove_path(path: StrPath) -> None:
    """Remove a file or a directory tree; missing is fine."""
    try:
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path)
        else:
            os.unlink(path)
    except FileNotFoundError:
        pass


def pread_into(fd: int, out: NDArray[Any], offset: int, what: str) -> None:
    """Fill the C-contiguous array `out` with bytes read at `offset`."""
    mv = out.reshape(-1).view(np.uint8).data if out.size else memoryview(b"")
    done = 0
    total = len(mv)
    while done < total:
        k = os.preadv(fd, [mv[done:]], offset + done)
        if k <= 0:
            raise StoreError(f"{what}: file is truncated (wanted {total} bytes at offset {offset})")
        done += k
