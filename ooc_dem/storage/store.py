"""Store / EpochWriter / EpochReader on top of a place (store directory or memory backing)."""

from __future__ import annotations

import copy
import dataclasses
import datetime as _dt
import json
import operator
import os
import re
import weakref
from collections.abc import Mapping

import numpy as np

from . import _confine, _disk, _lock, _memory
from .writeguard import shortfall
from ._util import (EPOCH_DIR, FORMAT, FORMAT_VERSION, SUPPORTED_VERSIONS, GLOBALS_GROUP, LOCK_FILE, MANIFEST,
                    MANIFEST_TMP, MAX_JSON_DEPTH, MAX_PARTS, StoreError, array_meta, check_array_name,
                    domain_group, epoch_basename, file_checksum, file_entries, gather_rows, json_depth, json_roundtrip, normalize_rows,
                    part_basename, prepare_arrays, remove_path, to_json, write_error)
from ._util import TMP_NAME_RE as _TMP_RE
from ._util import show as _show

BACKENDS = ("hdf5", "zarr", "memory")
# the extension of the epochs a backend writes, and of those it reads (zarr: one zip archive
# per epoch; directories, written before, are still read)
_EXT = {"hdf5": "h5", "zarr": "zip", "memory": "mem"}
_READ_EXTS = {"hdf5": ("h5",), "zarr": ("zip", "zarr"), "memory": ("mem",)}
# optional compression of a store's arrays, per backend: zarr codecs (zstd; blosc = lz4 with
# byte shuffle) or HDF5 filters (gzip = deflate level 4 with shuffle; lzf with shuffle);
# measured by tools/iobench.py (off by default: see the README's "Disk economy")
COMPRESSIONS = {"hdf5": ("gzip", "lzf"), "zarr": ("zstd", "blosc"), "memory": ()}
# a compressed epoch's arrays may hold at most this many times the bytes of its files (a
# bound on what a manifest can make a reader allocate; real states compress ~1.1-2x)
_MAX_RATIO = 64
_IO_ERRORS = (OSError, RuntimeError, KeyError, ValueError, TypeError)

# the limits of what a manifest may say (beyond them it is not ours): steps, sizes and array
# dimensions are stored as int64; numpy arrays have at most 64 dimensions, ours far fewer
_MAX_INT64 = 2**63 - 1
_MAX_NDIM = 32
_MAX_DOMAIN_ID = 10**9 - 1
_MAX_NAME_CHARS = 200          # ARRAY_NAME_RE's limit, checked first to keep messages short
_DOMAIN_KEY_RE = re.compile(r"^(0|[1-9][0-9]{0,8})$")   # str(d) of a domain id d >= 0


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _key(path) -> str:
    try:
        return os.fspath(path)
    except TypeError:
        raise StoreError(f"{path!r}: store path must be a str or os.PathLike") from None


# ============================================================================ open / create

def create_store(path, backend: str, meta: dict, compression: str | None = None) -> "Store":
    """Create a new, empty store at `path` and hold its write lock until closed.

    An existing ooc-dem store at `path` is replaced (its manifest and epochs are
    deleted; other files in the directory are left alone) unless another process is
    writing it. An existing non-empty path that is not an ooc-dem store is refused.
    `compression` (None, or one of ``COMPRESSIONS[backend]``) applies to every epoch the
    store is written with, also after it is opened again.
    """
    key = _key(path)
    if backend not in BACKENDS:
        raise StoreError(f"{key}: unknown backend {backend!r} (expected one of {', '.join(BACKENDS)})")
    if not isinstance(meta, Mapping):
        raise StoreError(f"{key}: meta must be a dict")
    if compression is not None and compression not in COMPRESSIONS[backend]:
        have = ", ".join(COMPRESSIONS[backend]) or "none"
        raise StoreError(f"{key}: compression {compression!r} is not one of the {backend} "
                         f"backend's ({have})")
    manifest = {"format": FORMAT, "format_version": FORMAT_VERSION, "backend": backend,
                "meta": json_roundtrip(dict(meta), f"{key}: meta"),
                "created_at": _now(), "current": None, "previous": None}
    if compression is not None:
        manifest["compression"] = compression
    if json_depth(manifest) > MAX_JSON_DEPTH:    # it could not be opened again
        raise StoreError(f"{key}: meta nested deeper than {MAX_JSON_DEPTH - 1} levels")
    if backend == "memory":
        backing = _memory.Backing()
        place = _memory.Place(key, backing)
        place.write_manifest(manifest)
        _memory._REGISTRY[key] = backing
        return Store(place, key, manifest)
    kind, why = _disk.classify(key)
    if kind == "foreign":
        raise StoreError(f"{key}: refusing to create a store here: path exists and is not an "
                         f"ooc-dem store ({why})")
    try:
        os.makedirs(key, exist_ok=True)
    except OSError as e:
        raise write_error(key, e) from e
    lock = _lock.StoreLock(key)         # before anything is deleted: not under a running writer
    try:
        kind, why = _disk.classify(key)
        if kind == "foreign":
            raise StoreError(f"{key}: refusing to create a store here: path exists and is not an "
                             f"ooc-dem store ({why})")
        try:
            if kind in ("store", "damaged"):
                _disk.wipe(key)
            os.makedirs(os.path.join(key, "epochs"), exist_ok=True)
        except OSError as e:
            raise write_error(key, e) from e
        _memory._REGISTRY.pop(key, None)
        place = _disk.Place(key, backend)
        place.write_manifest(manifest, durable=True)
    except BaseException:
        lock.release()
        raise
    return Store(place, key, manifest, lock)


def _int(v, what: str, lo: int = 0, hi: int = _MAX_INT64) -> int:
    if type(v) is not int or not lo <= v <= hi:      # (bool is an int subclass: refused)
        raise StoreError(f"{what}: must be an integer in [{lo}, {hi}], got {_show(v)}")
    return v


def _dict(v, what: str) -> dict:
    if not isinstance(v, dict):
        raise StoreError(f"{what}: malformed (must be a JSON object, got {_show(v)})")
    return v


def _check_arrays(arrays, what: str, min_ndim: int) -> int:
    """Check {name: [shape, dtype]}; return the bytes the arrays need."""
    nbytes = 0
    for name, spec in _dict(arrays, what).items():
        if not isinstance(name, str) or len(name) > _MAX_NAME_CHARS:
            raise StoreError(f"{what}: invalid array name {_show(name)}")
        check_array_name(name, what)
        where = f"{what} {name!r}"
        if not (isinstance(spec, list) and len(spec) == 2):
            raise StoreError(f"{where}: malformed (must be [shape, dtype], got {_show(spec)})")
        shape, dtype = spec
        if not (isinstance(shape, list) and min_ndim <= len(shape) <= _MAX_NDIM):
            raise StoreError(f"{where}: malformed shape {_show(shape)} (a list of {min_ndim} to "
                             f"{_MAX_NDIM} non-negative integers)")
        count = 1
        for n in shape:
            count *= _int(n, f"{where} shape")
        dt = None
        if isinstance(dtype, str) and len(dtype) <= 8:
            try:
                dt = np.dtype(dtype)
            except (TypeError, ValueError):
                dt = None
        if dt is None or dt.kind not in "biufc" or dt.fields is not None or dt.str != dtype:
            raise StoreError(f"{where}: dtype {_show(dtype)} is not a numeric numpy dtype string "
                             f"(such as '<f8', '<i8', '|b1')")
        nbytes += count * dt.itemsize
        if nbytes > _MAX_INT64:
            raise StoreError(f"{where}: arrays larger than 2**63 bytes")
    return nbytes


def _check_entry(e, role: str, where: str, place, ext) -> None:
    """Check one epoch entry of a manifest, confining its paths (see _confine)."""
    what = f"{where}/{MANIFEST}: {role} epoch"
    e = _dict(e, what)
    step = _int(e.get("step"), f"{what} step")
    if "format_version" in e:
        v = e["format_version"]
        if type(v) is not int or v not in SUPPORTED_VERSIONS:
            raise StoreError(f"{what}: unsupported format_version {_show(v)} (this code reads "
                             f"{', '.join(map(str, SUPPORTED_VERSIONS))})")
    epoch = _confine.epoch_path(e.get("path"), ext, step, what)
    files = e.get("files")
    if not isinstance(files, list):
        raise StoreError(f"{what}: malformed \"files\" (must be a list of file entries)")
    comp = e.get("compression")
    if comp is not None and (not isinstance(comp, str) or comp not in COMPRESSIONS[place.backend]):
        raise StoreError(f"{what}: unknown compression {_show(comp)}")
    seen, stored = set(), 0

    def check_files(epoch, files, what):
        nonlocal stored
        inside = place.is_memory or place.fmt_of(epoch).IS_DIR
        listed = 0
        for f in files:
            f = _dict(f, f"{what} file entry")
            p = _confine.file_path(f.get("path"), epoch, inside, what)
            if p in seen:
                raise StoreError(f"{what}: file {p!r} listed twice")
            seen.add(p)
            listed += 1
            stored += _int(f.get("size"), f"{what} file {p!r} size")
            file_checksum(f, f"{what}: file {p!r}")
        # the checksums must cover the epoch's own files, always (see check_files for zarr:
        # the files found must be exactly the listed ones)
        if not place.is_memory and not listed:
            raise StoreError(f"{what}: lists no files (its data would go unchecked)")

    check_files(epoch, files, what)
    # parts: files of the same epoch that other processes wrote (write_part), each holding
    # some of its domain groups; part k is "epochs/<the epoch's name>.p<k>"
    parts = e.get("parts", [])
    if not isinstance(parts, list) or len(parts) > MAX_PARTS or (parts and place.is_memory):
        raise StoreError(f"{what}: malformed \"parts\" (must be a list of at most {MAX_PARTS} part "
                         f"entries, on disk)")
    for k, part in enumerate(parts, start=1):
        pw = f"{what} part {k}"
        part = _dict(part, pw)
        ppath = _confine.epoch_path(part.get("path"), ext, step, pw, part=k)
        if ppath != f"{EPOCH_DIR}/{part_basename(epoch.rpartition('/')[2], k)}":
            raise StoreError(f"{pw}: path {_show(ppath)} is not part {k} of epoch {epoch}")
        pfiles = part.get("files")
        if not isinstance(pfiles, list):
            raise StoreError(f"{pw}: malformed \"files\" (must be a list of file entries)")
        check_files(ppath, pfiles, pw)
        if not place.is_memory:
            place.resolver.path(ppath, pw)
    domains = _dict(e.get("domains"), f"{what} domains")
    needed = 0
    for d, info in domains.items():
        if not (isinstance(d, str) and _DOMAIN_KEY_RE.match(d)):
            raise StoreError(f"{what}: domain key {_show(d)} is not a domain id "
                             f"(0 to {_MAX_DOMAIN_ID}, written without sign or leading zeros)")
        info = _dict(info, f"{what} domain {d}")
        _int(info.get("n"), f"{what} domain {d} n")
        if "part" in info:
            _int(info["part"], f"{what} domain {d} part", 1, len(parts))
        needed += _check_arrays(info.get("arrays"), f"{what} domain {d} arrays", 1)
    g = e.get("globals")
    if g is not None:
        needed += _check_arrays(_dict(g, f"{what} globals").get("arrays"), f"{what} globals arrays", 0)
    # uncompressed arrays' bytes are all in the files; compressed ones at most _MAX_RATIO x
    if needed > stored * (1 if comp is None else _MAX_RATIO):
        raise StoreError(f"{what}: arrays need {needed} bytes but its files hold only {stored}"
                         + ("" if comp is None else f" ({comp}, at most {_MAX_RATIO}x)"))
    if not isinstance(e.get("committed_at", ""), str):
        raise StoreError(f"{what}: malformed committed_at {_show(e.get('committed_at'))}")
    if not place.is_memory:
        # the epoch itself must resolve inside epochs/; its files are strictly below it (checked
        # above), so only links inside the epoch could lead elsewhere: those are verification
        # problems of that epoch (Place.check_files), not reasons to refuse the whole store
        place.resolver.path(epoch, what)


def _validate_manifest(m, where: str, backends, place_for):
    """Check everything later code relies on, so that it can trust the manifest's entries.

    `place_for(backend)` gives the place whose paths the entries must resolve in.
    Returns (manifest, place)."""
    if not isinstance(m, dict) or m.get("format") != FORMAT:
        raise StoreError(f"{where}: not an ooc-dem store (MANIFEST.json has no "
                         f"\"format\": \"{FORMAT}\")")
    v = m.get("format_version")
    if type(v) is not int or v not in SUPPORTED_VERSIONS:
        raise StoreError(f"{where}: unsupported format_version {_show(v)} (this code reads "
                         f"{', '.join(map(str, SUPPORTED_VERSIONS))})")
    backend = m.get("backend")
    if not isinstance(backend, str) or backend not in backends:
        raise StoreError(f"{where}: MANIFEST.json names backend {_show(backend)}, "
                         f"expected one of {', '.join(backends)}")
    place = place_for(backend)
    if not place.is_memory:
        place.resolver.check_epoch_dir()
    if not isinstance(m.get("meta", {}), dict):
        raise StoreError(f"{where}: MANIFEST.json missing or unreadable (malformed: meta is not "
                         f"an object)")
    if not isinstance(m.get("created_at", ""), str):
        raise StoreError(f"{where}: MANIFEST.json missing or unreadable (malformed: created_at)")
    comp = m.get("compression")
    if comp is not None and (not isinstance(comp, str) or comp not in COMPRESSIONS[backend]):
        raise StoreError(f"{where}: MANIFEST.json names compression {_show(comp)}, expected one "
                         f"of the {backend} backend's ({', '.join(COMPRESSIONS[backend]) or 'none'})")
    cur, prev = m.get("current"), m.get("previous")
    ext = _READ_EXTS[backend]
    for role, e in (("current", cur), ("previous", prev)):
        if e is not None:
            _check_entry(e, role, where, place, ext)
    if prev is not None:
        what = f"{where}/{MANIFEST}"
        if cur is None:
            raise StoreError(f"{what}: names a previous epoch but no current one")
        if prev["path"] == cur["path"]:
            raise StoreError(f"{what}: previous and current epoch are the same path {cur['path']!r}")
        if not prev["step"] < cur["step"]:
            raise StoreError(f"{what}: previous epoch step {prev['step']} is not older than the "
                             f"current {cur['step']}")
    m.setdefault("meta", {})
    m.setdefault("previous", None)
    m.setdefault("current", None)
    return m, place


def open_store(path, repair: bool = True) -> "Store":
    """Open an existing store.

    repair=True opens it for writing: takes the store's write lock (StoreError if another
    process holds it) and deletes temporaries and unnamed epoch files. repair=False opens
    it read-only: no lock, nothing deleted, writing refused; it works while a run writes.
    """
    key = _key(path)
    backing = _memory._REGISTRY.get(key)
    if backing is not None:
        place = _memory.Place(key, backing)
        m, _ = _validate_manifest(place.read_manifest(), key, ("memory",), lambda _b: place)
        store = Store(place, key, m, writable=repair)
        if repair:
            store.repaired = place.repair(m)
        return store
    if key.startswith("mem://"):
        raise StoreError(f"{key}: no such memory store in this process")
    _kind, info = _classify_existing(key)
    m, place = _validate_manifest(info, key, ("hdf5", "zarr"), lambda b: _disk.Place(key, b))
    if not repair:
        return Store(place, key, m, writable=False)
    lock = _lock.StoreLock(key)   # only now: a store refused above is left exactly as it was
    try:
        _kind, info = _classify_existing(key)   # again: a writer may have committed meanwhile
        m, place = _validate_manifest(info, key, ("hdf5", "zarr"), lambda b: _disk.Place(key, b))
        store = Store(place, key, m, lock)
        try:
            store.repaired = place.repair(m)
        except OSError as e:
            raise StoreError(f"{key}: repair failed ({e})") from e
    except BaseException:
        lock.release()
        raise
    return store


def _classify_existing(key: str) -> tuple[str, dict]:
    kind, info = _disk.classify(key)
    if kind == "absent":
        raise StoreError(f"{key}: no such store (path does not exist)")
    if kind in ("empty", "foreign"):
        raise StoreError(f"{key}: not an ooc-dem store ({info or 'empty directory'})")
    if kind == "damaged":
        raise StoreError(f"{key}: MANIFEST.json missing or unreadable ({info})")
    return kind, info


def drop_memory_store(path) -> bool:
    """Forget a memory store (frees its arrays). Returns whether it existed."""
    return _memory._REGISTRY.pop(_key(path), None) is not None


# ============================================================================ Store

class Problem(str):
    """One problem ``Store.verify`` found: the one-line message (the string itself) and
    ``step``, the epoch it belongs to (None for a problem of no one epoch, such as a step
    the manifest does not name). Callers decide by ``step``, never by parsing the text."""

    step: int | None

    def __new__(cls, message: str, step: int | None = None):
        problem = super().__new__(cls, message)
        problem.step = step
        return problem


@dataclasses.dataclass(frozen=True)
class EpochInfo:
    """One committed epoch of a manifest, as `Store.list_epochs` reports it (no data read)."""
    role: str                   # "previous" or "current"
    step: int
    path: str                   # relative to the store: "epochs/<name>"
    location: str               # where it is (the store path joined with `path`)
    nbytes: int                 # total recorded size of its files
    n_domains: int
    problems: tuple[str, ...]   # missing, special or wrong-sized files (sizes only, no checksums)


@dataclasses.dataclass(frozen=True)
class Leftover:
    """What an interrupted write left in a store (`open_store(repair=True)` deletes it)."""
    path: str
    pid: int | None             # the writing process of a ``*.tmp-<pid>`` temporary
    running: bool               # whether that process is running (it may still be writing)


def _pid_running(pid: int) -> bool:
    if pid == os.getpid():      # our own pid on a leftover: an earlier process that had it
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:     # exists, belongs to someone else
        return True
    except OverflowError:
        return False
    return True


class Store:
    """A run's epochs. See the package docstring for layout and guarantees."""

    def __init__(self, place, path: str, manifest: dict, lock=None, writable: bool = True):
        self._place = place
        self.path = path
        self.backend = manifest["backend"]
        self._m = manifest
        self.warnings: list[str] = []     # e.g. fallback to the previous epoch
        self.repaired: list[str] = []     # what open_store(repair=True) deleted
        self._verified: set[str] = set()  # epoch paths known good (written or verified here)
        self._writer: EpochWriter | None = None
        self._readers: weakref.WeakSet = weakref.WeakSet()
        self._closed = False
        self._lock = lock                 # the store's write lock (disk stores open for writing)
        self.writable = writable

    def __repr__(self):
        return f"Store({self.path!r}, backend={self.backend!r}, current={self.current()})"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    @property
    def meta(self) -> dict:
        return copy.deepcopy(self._m["meta"])

    def _check_open(self):
        if self._closed:
            raise StoreError(f"{self.path}: store is closed")

    def _check_writable(self):
        self._check_open()
        if not self.writable:
            raise StoreError(f"{self.path}: store was opened read-only (repair=False); open it "
                             f"with repair=True to write")

    def _entries(self) -> list[dict]:
        """previous, current (those present in the manifest), oldest first."""
        return [e for e in (self._m["previous"], self._m["current"]) if e is not None]

    @staticmethod
    def _files_of(e: dict) -> list[dict]:
        """The epoch's main file(s) and every part's, each as an entry of its own (the
        Place's checks, sizes and deletion work on one path with its files)."""
        return [e] + [{"step": e["step"], "path": p["path"], "files": p["files"]} for p in e.get("parts", ())]

    def _entry(self, step: int) -> dict:
        for e in self._entries():
            if e["step"] == step:
                return e
        raise StoreError(f"{self.path}: epoch {step} is not in the manifest "
                         f"(have {[e['step'] for e in self._entries()]})")

    # ------------------------------------------------------------------ queries
    def epochs(self) -> list[int]:
        self._check_open()
        return [e["step"] for e in self._entries() if self._place.exists(e)]

    def current(self) -> int | None:
        cur = self._m["current"]
        return None if cur is None else cur["step"]

    def manifest(self, fresh: bool = False) -> dict:
        """A copy of the (validated) manifest; fresh=True reads it again from the store, e.g. to
        see what a run writing the store has committed since this Store was opened."""
        self._check_open()
        if not fresh:
            return copy.deepcopy(self._m)
        backends = ("memory",) if self._place.is_memory else ("hdf5", "zarr")
        m, _ = _validate_manifest(self._place.read_manifest(), self.path, backends,
                                  lambda _b: self._place)
        return m

    def list_epochs(self) -> list[EpochInfo]:
        """The committed epochs, oldest first, with sizes checked (not their checksums)."""
        self._check_open()
        out = []
        for role, e in (("previous", self._m["previous"]), ("current", self._m["current"])):
            if e is not None:
                subs = self._files_of(e)
                out.append(EpochInfo(role, e["step"], e["path"], self._where(e),
                                     sum(f["size"] for x in subs for f in x["files"]), len(e["domains"]),
                                     tuple(p for x in subs for p in self._place.size_problems(x))))
        return out

    def leftovers(self, manifest: dict | None = None) -> list[Leftover]:
        """Temporaries and unnamed epoch files (what open_store(repair=True) would delete).

        `manifest` (from ``manifest(fresh=True)``) judges "unnamed" by what is committed now
        rather than when this Store was opened (a run may be writing the store)."""
        self._check_open()
        m = self._m if manifest is None else manifest
        return [Leftover(p, pid, pid is not None and _pid_running(pid))
                for p, pid in self._place.leftovers(m)]

    def live_writers(self) -> list[int]:
        """Pids of processes writing this store: the holder of its write lock (0 if its pid is
        unknown) and running processes with a temporary epoch in it; [] if none."""
        self._check_open()
        if self._place.is_memory:
            return []
        pids = {x.pid for x in self.leftovers() if x.running}
        holder = None if self._lock is not None else _lock.live_writer(self.path)
        if holder is not None:
            pids.add(holder)
        return sorted(pids)

    # ------------------------------------------------------------------ writing
    def begin_epoch(self, step: int, expected_bytes: int | None = None) -> "EpochWriter":
        """Start writing epoch `step`. Nothing is visible until commit().

        `step` must be newer than the previous epoch. Normally it is newer than the
        current one too; a step <= current (e.g. resuming after a fallback to the
        previous epoch) replaces the current epoch when committed. The disk space is
        checked first (``check_room``, `expected_bytes`).
        """
        self._check_writable()
        try:
            step = operator.index(step)
        except TypeError:
            raise StoreError(f"{self.path}: epoch step must be an int, got {step!r}") from None
        if not 0 <= step <= _MAX_INT64:
            raise StoreError(f"{self.path}: epoch step must be in [0, 2**63), got {step}")
        if self._writer is not None and self._writer._state == "open":
            raise StoreError(f"{self.path}: epoch {self._writer.step} is still being written "
                             f"(commit or abort it first)")
        prev = self._m["previous"]
        if prev is not None and step <= prev["step"]:
            raise StoreError(f"{self.path}: cannot write epoch {step}: not newer than the previous "
                             f"committed epoch {prev['step']}")
        # never reuse the name of an epoch the manifest still names (no in-place modification)
        named = {os.path.basename(e["path"]) for e in self._entries()}
        rev = 0
        while epoch_basename(step, _EXT[self.backend], rev) in named:
            rev += 1
        self.check_room(step, expected_bytes)
        self._writer = EpochWriter(self, step, epoch_basename(step, _EXT[self.backend], rev))
        return self._writer

    @property
    def compression(self) -> str | None:
        """The compression epochs are written with (None: uncompressed)."""
        return self._m.get("compression")

    def check_room(self, step: int, expected_bytes: int | None = None) -> None:
        """Refuse to start epoch `step` when it cannot fit: StoreError "disk full" if the free
        space of the file system (or the process's file-size limit, for a one-file epoch) is
        below `expected_bytes` (default: the newest verified epoch's size plus room for growth: 1/64
        and 4 KiB; states grow slowly, and a refusal should not come before it must),
        so that a sweep is never computed for an epoch that cannot be stored.

        The writers still turn ENOSPC/EFBIG during the write into the same error (and remove
        the partial epoch): this check cannot see other processes filling the disk."""
        if self._place.is_memory:
            return
        if expected_bytes is None:
            # the newest epoch known good: a damaged entry's recorded sizes are not to be trusted
            good = [e for e in self._entries() if e["path"] in self._verified]
            if not good:
                return
            size = sum(f["size"] for x in self._files_of(good[-1]) for f in x["files"])
            expected_bytes = size + size // 64 + (4 << 10)
        need = int(expected_bytes)
        where = self._place.tmp_name(epoch_basename(step, _EXT[self.backend]))
        try:
            # a directory epoch's files are small each: only a one-file epoch meets the file-size limit
            short = shortfall(self._place.edir, need, 0 if self._place.fmt.IS_DIR else need)
        except OSError as e:
            raise write_error(self._place.edir, e) from e
        if short is not None:
            raise StoreError(f"{where}: disk full or file too large (epoch {step} {short[1]}; "
                             f"committed epochs are untouched)")

    def _commit(self, w: "EpochWriter", durable: bool) -> None:
        if sorted(w._parts) != list(range(1, len(w._parts) + 1)):
            raise StoreError(f"{self.path}: epoch {w.step} has parts {sorted(w._parts)}, not 1 to {len(w._parts)}")
        rel, files = self._place.publish(w._w, w._basename, durable)
        entry = {"step": w.step, "path": rel, "files": files, "domains": w._domains,
                 "globals": w._globals, "committed_at": _now(), "format_version": FORMAT_VERSION}
        if w._parts:
            # phase 2 of the parts' commit: every part is complete (its writer finished it and
            # reported its checksums); they take their names, then the manifest names them all
            entry["parts"] = []
            try:
                for k in sorted(w._parts):
                    part = w._parts[k]
                    self._place.publish_part(part["tmp"], part["path"].rpartition("/")[2], durable)
                    entry["parts"].append({"path": part["path"], "files": part["files"]})
            except StoreError:
                for x in self._files_of(entry):
                    self._place.remove_epoch(x)
                raise
        if self.compression is not None:
            entry["compression"] = self.compression
        old_cur, old_prev = self._m["current"], self._m["previous"]
        # an epoch of an older store keeps the version it was written in (named in its entry)
        # when the manifest moves on to this code's version
        old_v = self._m.get("format_version", FORMAT_VERSION)
        old_cur, old_prev = ({**e, "format_version": e.get("format_version", old_v)}
                             if e is not None else None for e in (old_cur, old_prev))
        if old_cur is None:
            new_prev = None
        elif w.step > old_cur["step"]:
            new_prev = old_cur
        else:                       # rewrite of a step <= current: current is replaced
            new_prev = old_prev
        new_m = dict(self._m, current=entry, previous=new_prev, format_version=FORMAT_VERSION)
        try:
            self._place.write_manifest(new_m, durable)
        except StoreError:
            for x in self._files_of(entry):
                self._place.remove_epoch(x)
            raise
        self._m = new_m
        self._verified.add(rel)
        keep = {rel} | ({new_prev["path"]} if new_prev else set())
        for e in (old_cur, old_prev):                  # only after the new manifest is in place
            if e is not None and e["path"] not in keep:
                self._verified.discard(e["path"])
                try:
                    for x in self._files_of(e):
                        self._place.remove_epoch(x)
                except (OSError, StoreError) as ex:
                    self.warnings.append(f"{self.path}: could not delete old epoch {e['path']}: {ex}")

    # ------------------------------------------------------------------ reading / checking
    def _problems(self, e: dict, structure_if_damaged: bool = True) -> list[str]:
        """Checksums of every listed file, then groups/arrays named by the manifest.

        With structure_if_damaged=False, files that failed their checksums are not
        opened (a damaged HDF5 file is not handed to the HDF5 library on the read path).
        """
        subs = self._files_of(e)
        problems = [p for x in subs for p in self._place.check_files(x)]
        if problems and not structure_if_damaged:
            return problems
        for k, x in enumerate(subs):
            groups = [(domain_group(int(d)), info["arrays"]) for d, info in e["domains"].items()
                      if info.get("part", 0) == k]
            if k == 0 and e.get("globals") is not None:
                groups.append((GLOBALS_GROUP, e["globals"]["arrays"]))
            problems += self._group_problems(x, groups)
        return problems

    def _group_problems(self, e: dict, groups) -> list[str]:
        """Groups, arrays (shape, dtype) and attrs of one epoch file as the manifest names them."""
        problems = []
        try:
            r = self._place.open_reader(e)
        except Exception as ex:  # noqa: BLE001 - any failure to open is a problem to report
            return [f"{self._where(e)}: cannot open ({type(ex).__name__}: {ex})"]
        own = _own_step_problem(self._place, r, self._where(e), e["step"])
        if own:
            problems.append(own)
        try:
            for g, arrays in groups:
                try:
                    if not r.has_group(g):
                        problems.append(f"{self._where(e)}: group /{g} missing")
                        continue
                    for name, (shape, dtype) in arrays.items():
                        info = r.array_info(g, name)
                        if info is None:
                            problems.append(f"{self._where(e)}: array /{g}/{name} missing")
                        elif tuple(info[0]) != tuple(shape) or np.dtype(info[1]) != np.dtype(dtype):
                            problems.append(f"{self._where(e)}: array /{g}/{name} is {info[0]} "
                                            f"{np.dtype(info[1])}, manifest says {tuple(shape)} "
                                            f"{np.dtype(dtype)}")
                    a = r.attrs_json(g)
                    if a is None:
                        problems.append(f"{self._where(e)}: attrs of /{g} missing")
                    else:
                        json.loads(a)
                except Exception as ex:  # noqa: BLE001
                    problems.append(f"{self._where(e)}: group /{g} unreadable ({type(ex).__name__}: {ex})")
        finally:
            try:
                r.close()
            except Exception:  # noqa: BLE001
                pass
        return problems

    def _where(self, e) -> str:
        if self._place.is_memory:
            return f"{self.path}/{e['path']}"
        return os.path.join(self.path, e["path"])

    def verify(self, step: int | None = None) -> list[Problem]:
        """Problems found (empty list = OK) in epoch `step`, or in every epoch of the manifest;
        each names its epoch (``Problem.step``)."""
        self._check_open()
        if step is None:
            entries = self._entries()
        else:
            try:
                entries = [self._entry(operator.index(step))]
            except StoreError as ex:
                return [Problem(str(ex))]
        out = []
        for e in entries:
            p = self._problems(e)
            out += [Problem(f"epoch {e['step']}: {x}", e["step"]) for x in p]
            if not p:
                self._verified.add(e["path"])
        return out

    def read_epoch(self, step: int | None = None, verify: bool = True) -> "EpochReader":
        """Reader for epoch `step` (None = current, falling back to the previous epoch if the
        current one fails verification). Checksums are checked once per Store object."""
        self._check_open()
        if step is not None:
            e = self._entry(operator.index(step))
            if verify:
                self._ensure_ok(e)
            return EpochReader(self, e)
        cur, prev = self._m["current"], self._m["previous"]
        if cur is None:
            raise StoreError(f"{self.path}: no committed epoch")
        if not verify:
            return EpochReader(self, cur)
        bad = self._bad(cur)
        if not bad:
            return EpochReader(self, cur)
        if prev is not None:
            bad_prev = self._bad(prev)
            if not bad_prev:
                self.warnings.append(
                    f"{self.path}: current epoch {cur['step']} failed verification ({bad[0]}"
                    f"{f' and {len(bad) - 1} more problem(s)' if len(bad) > 1 else ''}); "
                    f"using previous epoch {prev['step']}")
                return EpochReader(self, prev)
            raise StoreError(f"{self.path}: epoch {cur['step']} is corrupt ({bad[0]}) and previous "
                             f"epoch {prev['step']} too ({bad_prev[0]})")
        raise StoreError(f"{self.path}: epoch {cur['step']} is corrupt ({bad[0]}) and there is no "
                         f"previous epoch")

    def _bad(self, e) -> list[str]:
        if e["path"] in self._verified:
            return []
        p = self._problems(e, structure_if_damaged=False)
        if not p:
            self._verified.add(e["path"])
        return p

    def _ensure_ok(self, e) -> None:
        bad = self._bad(e)
        if bad:
            raise StoreError(f"{self.path}: epoch {e['step']} is corrupt ({bad[0]})")

    # ------------------------------------------------------------------ maintenance
    def prune(self, keep: int) -> list[int]:
        """Delete committed epochs beyond the newest `keep` (the current one is always kept).

        Only the previous epoch can go: it is an epoch the manifest names, distinct from the
        current one (checked when the store was opened), inside the real epochs/ directory
        (checked again when it is deleted). The manifest, epochs/ and the store stay."""
        self._check_writable()
        keep = max(1, operator.index(keep))
        prev = self._m["previous"]
        if keep >= 2 or prev is None:
            return []
        new_m = dict(self._m, previous=None)
        self._place.write_manifest(new_m, durable=False)   # first forget it, then delete it
        self._m = new_m
        self._verified.discard(prev["path"])
        for x in self._files_of(prev):
            self._place.remove_epoch(x)
        return [prev["step"]]

    def close(self) -> None:
        if self._closed:
            return
        if self._writer is not None and self._writer._state == "open":
            self._writer.abort()
        for r in list(self._readers):
            r.close()
        self._closed = True
        lock, self._lock = self._lock, None
        if lock is not None:
            lock.release()


# ============================================================================ writer

class EpochWriter:
    """Writes one epoch under temporary names; commit() publishes it atomically."""

    def __init__(self, store: Store, step: int, basename: str):
        self._store = store
        self.step = step
        self._basename = basename
        self._domains: dict[str, dict] = {}
        self._globals: dict | None = None
        self._parts: dict[int, dict] = {}
        self._state = "open"
        self._tmp = store._place.tmp_name(basename)
        try:
            self._w = store._place.new_writer(step, basename, store.compression)
        except (OSError, RuntimeError) as e:
            self._state = "aborted"
            if not store._place.is_memory:
                remove_path(self._tmp)
            raise write_error(self._tmp, e) from e

    def __repr__(self):
        return f"EpochWriter({self._store.path!r}, step={self.step}, state={self._state})"

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if self._state == "open":   # exception, or left without commit(): discard the epoch
            self.abort()
        return False

    def _check_open(self):
        if self._state != "open":
            raise StoreError(f"{self._store.path}: epoch {self.step} writer is {self._state}")

    def _write(self, group: str, arrays, attrs_json: str):
        try:
            self._w.write_group(group, arrays, attrs_json)
        except (OSError, RuntimeError) as e:
            self.abort()
            raise write_error(self._tmp, e) from e
        except BaseException:
            self.abort()
            raise

    def write_domain(self, d: int, arrays: dict, attrs: dict | None = None) -> None:
        """Write sub-domain `d` (once per d): arrays of >= 1 dimension, JSON-able attrs."""
        self._check_open()
        try:
            d = operator.index(d)
        except TypeError:
            raise StoreError(f"{self._store.path}: domain id must be an int, got {d!r}") from None
        where = f"{self._store.path}: epoch {self.step} domain {d}"
        if d < 0:
            raise StoreError(f"{where}: domain id must be >= 0")
        if str(d) in self._domains:
            raise StoreError(f"{where}: already written in this epoch")
        if attrs is not None and not isinstance(attrs, Mapping):
            raise StoreError(f"{where}: attrs must be a dict")
        arrs = prepare_arrays(arrays, where, min_ndim=1)
        attrs_json = to_json(dict(attrs or {}), f"{where} attrs")
        self._write(domain_group(d), arrs, attrs_json)
        first = next(iter(arrs.values()), None)
        self._domains[str(d)] = {"n": 0 if first is None else int(first.shape[0]),
                                 "arrays": array_meta(arrs)}

    @property
    def basename(self) -> str:
        """The epoch's file name: the processes that write its parts name them after it
        (``write_part(..., writer.basename, k, ...)``)."""
        return self._basename

    def add_part(self, part: dict) -> None:
        """Phase 1 of a parts' commit: part ``part["part"]`` (what ``write_part`` returned in
        another process, complete on disk under its temporary name) is in this epoch. It is
        published with the epoch by commit(), and removed if the epoch is aborted."""
        self._check_open()
        where = f"{self._store.path}: epoch {self.step}"
        if self._store._place.is_memory:
            raise StoreError(f"{where}: a memory store keeps no parts (one process holds it)")
        k = part.get("part")
        if type(k) is not int or not 1 <= k <= MAX_PARTS or k in self._parts:
            raise StoreError(f"{where}: part {_show(k)} is not a new part number (1 to {MAX_PARTS})")
        name = part_basename(self._basename, k)
        tmp = part.get("tmp", "")
        m = _TMP_RE.match(os.path.basename(tmp)) if isinstance(tmp, str) else None
        if part.get("path") != f"{EPOCH_DIR}/{name}" or m is None or m.group(1) != name \
                or os.path.dirname(tmp) != self._store._place.edir:
            raise StoreError(f"{where}: part {k} was not written as part {k} of this epoch ({name})")
        self._parts[k] = part   # its tmp is ours to remove from now on (abort)
        for d, info in part["domains"].items():
            if d in self._domains:
                self.abort()
                raise StoreError(f"{where} domain {d}: written twice (part {k} and another)")
            self._domains[d] = {**info, "part": k}

    def write_globals(self, arrays: dict, attrs: dict | None = None) -> None:
        """Write the global state (once): arrays of any shape, including 0-d."""
        self._check_open()
        where = f"{self._store.path}: epoch {self.step} globals"
        if self._globals is not None:
            raise StoreError(f"{where}: already written in this epoch")
        if attrs is not None and not isinstance(attrs, Mapping):
            raise StoreError(f"{where}: attrs must be a dict")
        arrs = prepare_arrays(arrays, where, min_ndim=0)
        attrs_json = to_json(dict(attrs or {}), f"{where} attrs")
        self._write(GLOBALS_GROUP, arrs, attrs_json)
        self._globals = {"arrays": array_meta(arrs)}

    def commit(self, durable: bool = False) -> None:
        """Publish the epoch: it becomes current; the old current becomes previous."""
        self._check_open()
        self._store._check_open()
        self._state = "committing"
        try:
            self._store._commit(self, durable)
        except BaseException:
            self._state = "aborted"
            try:
                self._w.abort()
            except Exception:  # noqa: BLE001
                pass
            for part in self._parts.values():
                remove_path(part["tmp"])
            raise
        self._state = "committed"

    def abort(self) -> None:
        """Discard everything written, parts included (idempotent)."""
        if self._state in ("aborted", "committed"):
            return
        self._state = "aborted"
        try:
            self._w.abort()
        except Exception:  # noqa: BLE001
            pass
        for part in self._parts.values():
            remove_path(part["tmp"])


# ============================================================================ reader

def _own_step_problem(place, r, where: str, step: int) -> str | None:
    """The problem of a file of epoch `step` (its main file or a part, open as `r`) whose
    writer recorded another step in it, or none: a file of another epoch put in its place
    (its size and checksum in the manifest recomputed). One attribute, read once per open.
    A memory store has no files to swap."""
    if place.is_memory:
        return None
    try:
        got = r.root_step()
    except Exception as ex:  # noqa: BLE001 - a hostile attribute is a problem to report
        return f"{where}: root attribute 'step' unreadable ({type(ex).__name__}: {ex})"
    if type(got) is int and got == step:
        return None
    return (f"{where}: the file records step {_show(got)}, not the epoch's {step} (a file of "
            f"another epoch)")


class EpochReader:
    """Read access to one committed epoch."""

    def __init__(self, store: Store, entry: dict):
        self._store = store
        self._e = entry
        self.step: int = entry["step"]
        self._where = store._where(entry)
        # the format the epoch was written in (its entry's, else the manifest's)
        self.format_version: int = entry.get("format_version",
                                             store._m.get("format_version", FORMAT_VERSION))
        try:
            self._r = store._place.open_reader(entry)
        except Exception as ex:  # noqa: BLE001
            raise StoreError(f"{self._where}: cannot open epoch {self.step} "
                             f"({type(ex).__name__}: {ex})") from ex
        own = _own_step_problem(store._place, self._r, self._where, self.step)
        if own:
            self._r.close()
            raise StoreError(own)
        self._part_readers: dict[int, object] = {}
        # each group's attrs as read once (JSON text, decoded afresh for every caller): an
        # epoch never changes while it is read, and a sweep asks for every group's x range
        # once per slab (D^2 lookups: 62 500 HDF5 attribute reads took half of a sweep at D = 250)
        self._attrs_json: dict[str, str | None] = {}
        store._readers.add(self)

    def __repr__(self):
        return f"EpochReader({self._where!r}, step={self.step})"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def _dom(self, d) -> dict:
        info = self._e["domains"].get(str(operator.index(d)))
        if info is None:
            raise StoreError(f"{self._where}: epoch {self.step} has no domain {d} "
                             f"(has {self.domains()})")
        return info

    def _check(self):
        if self._r is None:
            raise StoreError(f"{self._where}: reader is closed")

    def _reader(self, d=None):
        """The reader of the file that holds domain d (None: the globals' file)."""
        self._check()
        k = 0 if d is None else self._dom(d).get("part", 0)
        if k == 0:
            return self._r
        r = self._part_readers.get(k)
        if r is None:
            sub = Store._files_of(self._e)[k]
            try:
                r = self._store._place.open_reader(sub)
            except Exception as ex:  # noqa: BLE001
                raise StoreError(f"{self._store._where(sub)}: cannot open part {k} of epoch {self.step} "
                                 f"({type(ex).__name__}: {ex})") from ex
            own = _own_step_problem(self._store._place, r, self._store._where(sub), self.step)
            if own:
                r.close()
                raise StoreError(own)
            self._part_readers[k] = r
        return r

    def domains(self) -> list[int]:
        return sorted(int(k) for k in self._e["domains"])

    def domain_len(self, d: int) -> int:
        return int(self._dom(d)["n"])

    def domain_arrays(self, d: int) -> dict[str, tuple[tuple, np.dtype]]:
        """name -> (shape, dtype) of the arrays of domain d (from the manifest, no I/O)."""
        return {n: (tuple(s), np.dtype(t)) for n, (s, t) in self._dom(d)["arrays"].items()}

    def _attrs(self, g: str, r=None) -> dict:
        self._check()
        r = self._r if r is None else r
        try:
            if g not in self._attrs_json:   # a group's name is unique across the epoch's files
                self._attrs_json[g] = r.attrs_json(g)
            a = self._attrs_json[g]
            return json.loads(a) if a is not None else {}
        except Exception as ex:  # noqa: BLE001
            raise StoreError(f"{self._where}: attrs of /{g} unreadable ({type(ex).__name__}: {ex})") from ex

    def domain_attrs(self, d: int) -> dict:
        return self._attrs(domain_group(operator.index(d)), self._reader(d))

    def _read(self, g: str, arrays: dict, names, rows, r=None) -> dict[str, np.ndarray]:
        self._check()
        reader = self._r if r is None else r
        if names is None:
            names = list(arrays)
        elif isinstance(names, str):
            raise StoreError(f"{self._where}: names must be a list of array names, not a str")
        out = {}
        try:
            for n in names:
                if n not in arrays:
                    raise StoreError(f"{self._where}: epoch {self.step} /{g} has no array {n!r} "
                                     f"(has {list(arrays)})")
                shape, dtype = tuple(arrays[n][0]), np.dtype(arrays[n][1])
                if rows is None:
                    out[n] = reader.read_full(g, n, shape, dtype)
                    continue
                if not shape:
                    raise StoreError(f"{self._where}: /{g}/{n} is 0-d; rows do not apply")
                sel = normalize_rows(rows, shape[0], f"{self._where}: /{g}/{n}")
                if isinstance(sel, tuple):
                    a = np.empty((sel[1] - sel[0],) + shape[1:], dtype=dtype)
                    reader.read_range(g, n, sel[0], sel[1], a)
                else:
                    a = gather_rows(lambda s, e, o: reader.read_range(g, n, s, e, o),
                                    sel, shape, dtype)
                out[n] = a
        except StoreError:
            raise
        except _IO_ERRORS as ex:
            raise StoreError(f"{self._where}: epoch {self.step} /{g}: read failed "
                             f"({type(ex).__name__}: {ex})") from ex
        finally:
            reader.after_read()
        return out

    def read_domain(self, d: int, names: list[str] | None = None,
                    rows: slice | np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Arrays of domain d (all, or `names`); `rows` reads only those rows (first axis)."""
        info = self._dom(d)
        return self._read(domain_group(operator.index(d)), info["arrays"], names, rows, self._reader(d))

    def read_globals(self) -> tuple[dict[str, np.ndarray], dict]:
        g = self._e.get("globals")
        if g is None:
            return {}, {}
        return self._read(GLOBALS_GROUP, g["arrays"], None, None), self._attrs(GLOBALS_GROUP)

    def close(self) -> None:
        r, self._r = self._r, None
        parts, self._part_readers = list(getattr(self, "_part_readers", {}).values()), {}
        for x in ([r] if r is not None else []) + parts:
            try:
                x.close()
            except Exception:  # noqa: BLE001
                pass


def write_part(path, step: int, basename: str, part: int, domains, durable: bool = False) -> dict:
    """Phase 1 of an epoch written by several processes (e.g. MPI ranks): this process
    writes part ``part`` (>= 1) of epoch ``basename`` (``EpochWriter.basename`` of the writer
    the store's owner holds) under a temporary name in the store's epochs/ directory, from
    ``domains`` (an iterable of (d, arrays, attrs)), finished (``durable``: flushed to disk)
    and checksummed. It returns what the owner passes to ``EpochWriter.add_part``; nothing
    of it is visible until the owner commits (phase 2), and an abort removes it.

    The store is opened read-only (its manifest validated, no lock: the owner holds it);
    on any failure the temporary is removed and StoreError says why."""
    store = open_store(path, repair=False)
    try:
        place = store._place
        if place.is_memory:
            raise StoreError(f"{store.path}: a memory store keeps no parts (one process holds it)")
        if not (type(part) is int and 1 <= part <= MAX_PARTS):
            raise StoreError(f"{store.path}: part {_show(part)} is not a part number (1 to {MAX_PARTS})")
        name = part_basename(basename, part)
        _confine.epoch_path(f"{EPOCH_DIR}/{name}", _EXT[store.backend], step, f"{store.path}: epoch {step}",
                            part=part)
        place.resolver.check_epoch_dir()
        tmp = place.tmp_name(name)
        remove_path(tmp)
        try:
            w = place.fmt.Writer(tmp, step, store.compression)
        except (OSError, RuntimeError) as e:
            remove_path(tmp)
            raise write_error(tmp, e) from e
        metas = {}
        try:
            for d, arrays, attrs in domains:
                d = operator.index(d)
                where = f"{store.path}: epoch {step} domain {d}"
                if d < 0 or str(d) in metas:
                    raise StoreError(f"{where}: not a new domain id >= 0")
                arrs = prepare_arrays(arrays, where, min_ndim=1)
                w.write_group(domain_group(d), arrs, to_json(dict(attrs or {}), f"{where} attrs"))
                first = next(iter(arrs.values()), None)
                metas[str(d)] = {"n": 0 if first is None else int(first.shape[0]), "arrays": array_meta(arrs)}
            inner = w.finish(durable)
        except BaseException as e:
            try:
                w.abort()
            except Exception:  # noqa: BLE001
                pass
            remove_path(tmp)
            if isinstance(e, (OSError, RuntimeError)) and not isinstance(e, StoreError):
                raise write_error(tmp, e) from e
            raise
        rel = f"{EPOCH_DIR}/{name}"
        files = file_entries(rel, inner)
        return {"part": part, "path": rel, "tmp": tmp, "files": files, "domains": metas}
    finally:
        store.close()


def store_owns(root, name: str) -> bool:
    """Whether the entry `name` directly inside store directory `root` is the store's own
    (its manifest, a manifest temporary, the epochs directory or the lock file)."""
    return name in (MANIFEST, EPOCH_DIR, LOCK_FILE) or name.startswith(MANIFEST_TMP)
