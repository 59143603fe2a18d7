"""A Store from a path: ``create_store`` (a new, empty store, replacing an ooc-dem store
there), ``open_store`` (an existing one, for writing with repair, or read-only), memory
stores' registry (``drop_memory_store``) and what in a store directory is the store's own
(``store_owns``). See the package docstring for layout and guarantees."""

from __future__ import annotations

import os
from collections.abc import Mapping

from . import _disk, _lock, _memory
from ._manifest import BACKENDS, COMPRESSIONS, now, store_key, validate_manifest
from ._util import (
    EPOCH_DIR,
    FORMAT,
    FORMAT_VERSION,
    LOCK_FILE,
    MANIFEST,
    MANIFEST_TMP,
    MAX_JSON_DEPTH,
    StoreError,
    StrPath,
    json_depth,
    json_roundtrip,
    write_error,
)
from .store import Store


def create_store(path: StrPath, backend: str, meta: Mapping[str, object], compression: str | None = None) -> Store:
    """Create a new, empty store at `path` and hold its write lock until closed.

    An existing ooc-dem store at `path` is replaced (its manifest and epochs are
    deleted; other files in the directory are left alone) unless another process is
    writing it. An existing non-empty path that is not an ooc-dem store is refused.
    `compression` (None, or one of ``COMPRESSIONS[backend]``) applies to every epoch the
    store is written with, also after it is opened again.
    """
    key = store_key(path)
    if backend not in BACKENDS:
        raise StoreError(f"{key}: unknown backend {backend!r} (expected one of {', '.join(BACKENDS)})")
    if not isinstance(meta, Mapping):
        raise StoreError(f"{key}: meta must be a dict")
    if compression is not None and compression not in COMPRESSIONS[backend]:
        have = ", ".join(COMPRESSIONS[backend]) or "none"
        raise StoreError(f"{key}: compression {compression!r} is not one of the {backend} backend's ({have})")
    manifest = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "backend": backend,
        "meta": json_roundtrip(dict(meta), f"{key}: meta"),
        "created_at": now(),
        "current": None,
        "previous": None,
    }
    if compression is not None:
        manifest["compression"] = compression
    if json_depth(manifest) > MAX_JSON_DEPTH:  # it could not be opened again
        raise StoreError(f"{key}: meta nested deeper than {MAX_JSON_DEPTH - 1} levels")
    if backend == "memory":
        backing = _memory.Backing()
        mem = _memory.Place(key, backing)
        mem.write_manifest(manifest)
        _memory._REGISTRY[key] = backing
        return Store(mem, key, manifest)
    kind, why = _disk.classify(key)
    if kind == "foreign":
        raise StoreError(f"{key}: refusing to create a store here: path exists and is not an ooc-dem store ({why})")
    try:
        os.makedirs(key, exist_ok=True)
    except OSError as e:
        raise write_error(key, e) from e
    lock = _lock.StoreLock(key)  # before anything is deleted: not under a running writer
    try:
        kind, why = _disk.classify(key)
        if kind == "foreign":
            raise StoreError(f"{key}: refusing to create a store here: path exists and is not an ooc-dem store ({why})")
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


def open_store(path: StrPath, repair: bool = True) -> Store:
    """Open an existing store.

    repair=True opens it for writing: takes the store's write lock (StoreError if another
    process holds it) and deletes temporaries and unnamed epoch files. repair=False opens
    it read-only: no lock, nothing deleted, writing refused; it works while a run writes.
    """
    key = store_key(path)
    backing = _memory._REGISTRY.get(key)
    if backing is not None:
        mem = _memory.Place(key, backing)
        m, _ = validate_manifest(mem.read_manifest(), key, ("memory",), lambda _b: mem)
        store = Store(mem, key, m, writable=repair)
        if repair:
            store.repaired = mem.repair(m)
        return store
    if key.startswith("mem://"):
        raise StoreError(f"{key}: no such memory store in this process")
    m, place = validate_manifest(_classify_existing(key), key, ("hdf5", "zarr"), lambda b: _disk.Place(key, b))
    if not repair:
        return Store(place, key, m, writable=False)
    lock = _lock.StoreLock(key)  # only now: a store refused above is left exactly as it was
    try:
        info = _classify_existing(key)  # again: a writer may have committed meanwhile
        m, place = validate_manifest(info, key, ("hdf5", "zarr"), lambda b: _disk.Place(key, b))
        store = Store(place, key, m, lock)
        try:
            store.repaired = place.repair(m)
        except OSError as e:
            raise StoreError(f"{key}: repair failed ({e})") from e
    except BaseException:
        lock.release()
        raise
    return store


def _classify_existing(key: str) -> object:
    """The manifest of the store at `key` (for validate_manifest to check), or StoreError."""
    kind, info = _disk.classify(key)
    if kind == "absent":
        raise StoreError(f"{key}: no such store (path does not exist)")
    if kind in ("empty", "foreign"):
        raise StoreError(f"{key}: not an ooc-dem store ({info or 'empty directory'})")
    if kind == "damaged":
        raise StoreError(f"{key}: MANIFEST.json missing or unreadable ({info})")
    return info


def drop_memory_store(path: StrPath) -> bool:
    """Forget a memory store (frees its arrays). Returns whether it existed."""
    return _memory._REGISTRY.pop(store_key(path), None) is not None


def store_owns(root: StrPath, name: str) -> bool:
    """Whether the entry `name` directly inside store directory `root` is the store's own
    (its manifest, a manifest temporary, the epochs directory or the lock file)."""
    return name in (MANIFEST, EPOCH_DIR, LOCK_FILE) or name.startswith(MANIFEST_TMP)
