"""Store / EpochWriter / EpochReader on top of a place (store directory or memory backing)."""

from __future__ import annotations

import copy
import datetime as _dt
import json
import operator
import os
import weakref
from collections.abc import Mapping

import numpy as np

from . import _disk, _memory
from ._util import (FORMAT, FORMAT_VERSION, GLOBALS_GROUP, StoreError, array_meta, domain_group,
                    epoch_basename, gather_rows, json_roundtrip, normalize_rows, prepare_arrays,
                    remove_path, to_json, write_error)

BACKENDS = ("hdf5", "zarr", "memory")
_EXT = {"hdf5": "h5", "zarr": "zarr", "memory": "mem"}
_IO_ERRORS = (OSError, RuntimeError, KeyError, ValueError, TypeError)


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _key(path) -> str:
    try:
        return os.fspath(path)
    except TypeError:
        raise StoreError(f"{path!r}: store path must be a str or os.PathLike") from None


# ============================================================================ open / create

def create_store(path, backend: str, meta: dict) -> "Store":
    """Create a new, empty store at `path`.

    An existing ooc-dem store at `path` is replaced (its manifest and epochs are
    deleted; other files in the directory are left alone). An existing non-empty
    path that is not an ooc-dem store is refused.
    """
    key = _key(path)
    if backend not in BACKENDS:
        raise StoreError(f"{key}: unknown backend {backend!r} (expected one of {', '.join(BACKENDS)})")
    if not isinstance(meta, Mapping):
        raise StoreError(f"{key}: meta must be a dict")
    manifest = {"format": FORMAT, "format_version": FORMAT_VERSION, "backend": backend,
                "meta": json_roundtrip(dict(meta), f"{key}: meta"),
                "created_at": _now(), "current": None, "previous": None}
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
        if kind in ("store", "damaged"):
            _disk.wipe(key)
        os.makedirs(os.path.join(key, "epochs"), exist_ok=True)
    except OSError as e:
        raise write_error(key, e) from e
    _memory._REGISTRY.pop(key, None)
    place = _disk.Place(key, backend)
    place.write_manifest(manifest, durable=True)
    return Store(place, key, manifest)


def _check_entry(e, what):
    if e is None:
        return
    if not isinstance(e, dict) or not isinstance(e.get("step"), int) \
            or not isinstance(e.get("path"), str) or not isinstance(e.get("files"), list) \
            or not isinstance(e.get("domains"), dict):
        raise ValueError(f"bad {what} epoch entry")
    for f in e["files"]:
        if not (isinstance(f, dict) and isinstance(f.get("path"), str)
                and isinstance(f.get("size"), int) and isinstance(f.get("sha256"), str)):
            raise ValueError(f"bad file entry in {what} epoch")


def _validate_manifest(m, where: str, backends) -> dict:
    if not isinstance(m, dict) or m.get("format") != FORMAT:
        raise StoreError(f"{where}: not an ooc-dem store (MANIFEST.json has no "
                         f"\"format\": \"{FORMAT}\")")
    v = m.get("format_version")
    if v != FORMAT_VERSION:
        raise StoreError(f"{where}: unsupported format_version {v!r} (this code reads {FORMAT_VERSION})")
    if m.get("backend") not in backends:
        raise StoreError(f"{where}: MANIFEST.json names backend {m.get('backend')!r}, "
                         f"expected one of {', '.join(backends)}")
    try:
        _check_entry(m.get("current"), "current")
        _check_entry(m.get("previous"), "previous")
        if not isinstance(m.get("meta", {}), dict):
            raise ValueError("meta is not an object")
    except ValueError as e:
        raise StoreError(f"{where}: MANIFEST.json missing or unreadable (malformed: {e})") from None
    m.setdefault("meta", {})
    m.setdefault("previous", None)
    m.setdefault("current", None)
    return m


def open_store(path, repair: bool = True) -> "Store":
    """Open an existing store; with repair, delete temporaries and unnamed epoch files."""
    key = _key(path)
    backing = _memory._REGISTRY.get(key)
    if backing is not None:
        place = _memory.Place(key, backing)
        m = _validate_manifest(place.read_manifest(), key, ("memory",))
        store = Store(place, key, m)
        if repair:
            store.repaired = place.repair(m)
        return store
    if key.startswith("mem://"):
        raise StoreError(f"{key}: no such memory store in this process")
    kind, info = _disk.classify(key)
    if kind == "absent":
        raise StoreError(f"{key}: no such store (path does not exist)")
    if kind in ("empty", "foreign"):
        raise StoreError(f"{key}: not an ooc-dem store ({info or 'empty directory'})")
    if kind == "damaged":
        raise StoreError(f"{key}: MANIFEST.json missing or unreadable ({info})")
    m = _validate_manifest(info, key, ("hdf5", "zarr"))
    place = _disk.Place(key, m["backend"])
    store = Store(place, key, m)
    if repair:
        try:
            store.repaired = place.repair(m)
        except OSError as e:
            raise StoreError(f"{key}: repair failed ({e})") from e
    return store


def drop_memory_store(path) -> bool:
    """Forget a memory store (frees its arrays). Returns whether it existed."""
    return _memory._REGISTRY.pop(_key(path), None) is not None


# ============================================================================ Store

class Store:
    """A run's epochs. See the package docstring for layout and guarantees."""

    def __init__(self, place, path: str, manifest: dict):
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

    def _entries(self) -> list[dict]:
        """previous, current (those present in the manifest), oldest first."""
        return [e for e in (self._m["previous"], self._m["current"]) if e is not None]

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

    # ------------------------------------------------------------------ writing
    def begin_epoch(self, step: int) -> "EpochWriter":
        """Start writing epoch `step`. Nothing is visible until commit().

        `step` must be newer than the previous epoch. Normally it is newer than the
        current one too; a step <= current (e.g. resuming after a fallback to the
        previous epoch) replaces the current epoch when committed.
        """
        self._check_open()
        try:
            step = operator.index(step)
        except TypeError:
            raise StoreError(f"{self.path}: epoch step must be an int, got {step!r}") from None
        if step < 0:
            raise StoreError(f"{self.path}: epoch step must be >= 0, got {step}")
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
        self._writer = EpochWriter(self, step, epoch_basename(step, _EXT[self.backend], rev))
        return self._writer

    def _commit(self, w: "EpochWriter", durable: bool) -> None:
        rel, files = self._place.publish(w._w, w._basename, durable)
        entry = {"step": w.step, "path": rel, "files": files, "domains": w._domains,
                 "globals": w._globals, "committed_at": _now()}
        old_cur, old_prev = self._m["current"], self._m["previous"]
        if old_cur is None:
            new_prev = None
        elif w.step > old_cur["step"]:
            new_prev = old_cur
        else:                       # rewrite of a step <= current: current is replaced
            new_prev = old_prev
        new_m = dict(self._m, current=entry, previous=new_prev)
        try:
            self._place.write_manifest(new_m, durable)
        except StoreError:
            self._place.remove_epoch(entry)
            raise
        self._m = new_m
        self._verified.add(rel)
        keep = {rel} | ({new_prev["path"]} if new_prev else set())
        for e in (old_cur, old_prev):                  # only after the new manifest is in place
            if e is not None and e["path"] not in keep:
                self._verified.discard(e["path"])
                try:
                    self._place.remove_epoch(e)
                except OSError as ex:
                    self.warnings.append(f"{self.path}: could not delete old epoch {e['path']}: {ex}")

    # ------------------------------------------------------------------ reading / checking
    def _problems(self, e: dict, structure_if_damaged: bool = True) -> list[str]:
        """Checksums of every listed file, then groups/arrays named by the manifest.

        With structure_if_damaged=False, files that failed their checksums are not
        opened (a damaged HDF5 file is not handed to the HDF5 library on the read path).
        """
        problems = self._place.check_files(e)
        if problems and not structure_if_damaged:
            return problems
        try:
            r = self._place.open_reader(e)
        except Exception as ex:  # noqa: BLE001 - any failure to open is a problem to report
            return problems + [f"{self._where(e)}: cannot open ({type(ex).__name__}: {ex})"]
        try:
            groups = [(domain_group(int(d)), info["arrays"]) for d, info in e["domains"].items()]
            if e.get("globals") is not None:
                groups.append((GLOBALS_GROUP, e["globals"]["arrays"]))
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

    def verify(self, step: int | None = None) -> list[str]:
        """Problems found (empty list = OK) in epoch `step`, or in every epoch of the manifest."""
        self._check_open()
        if step is None:
            entries = self._entries()
        else:
            try:
                entries = [self._entry(operator.index(step))]
            except StoreError as ex:
                return [str(ex)]
        out = []
        for e in entries:
            p = self._problems(e)
            out += [f"epoch {e['step']}: {x}" for x in p]
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
        """Delete committed epochs beyond the newest `keep` (the current one is always kept)."""
        self._check_open()
        keep = max(1, operator.index(keep))
        entries = self._entries()
        drop = entries[:-keep] if len(entries) > keep else []
        drop = [e for e in drop if e is not self._m["current"]]
        if not drop:
            return []
        paths = {e["path"] for e in drop}
        new_m = dict(self._m, previous=None if self._m["previous"] and
                     self._m["previous"]["path"] in paths else self._m["previous"])
        self._place.write_manifest(new_m, durable=False)
        self._m = new_m
        for e in drop:
            self._verified.discard(e["path"])
            self._place.remove_epoch(e)
        return [e["step"] for e in drop]

    def close(self) -> None:
        if self._closed:
            return
        if self._writer is not None and self._writer._state == "open":
            self._writer.abort()
        for r in list(self._readers):
            r.close()
        self._closed = True


# ============================================================================ writer

class EpochWriter:
    """Writes one epoch under temporary names; commit() publishes it atomically."""

    def __init__(self, store: Store, step: int, basename: str):
        self._store = store
        self.step = step
        self._basename = basename
        self._domains: dict[str, dict] = {}
        self._globals: dict | None = None
        self._state = "open"
        self._tmp = store._place.tmp_name(basename)
        try:
            self._w = store._place.new_writer(step, basename)
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
            raise
        self._state = "committed"

    def abort(self) -> None:
        """Discard everything written (idempotent)."""
        if self._state in ("aborted", "committed"):
            return
        self._state = "aborted"
        try:
            self._w.abort()
        except Exception:  # noqa: BLE001
            pass


# ============================================================================ reader

class EpochReader:
    """Read access to one committed epoch."""

    def __init__(self, store: Store, entry: dict):
        self._store = store
        self._e = entry
        self.step: int = entry["step"]
        self._where = store._where(entry)
        try:
            self._r = store._place.open_reader(entry)
        except Exception as ex:  # noqa: BLE001
            raise StoreError(f"{self._where}: cannot open epoch {self.step} "
                             f"({type(ex).__name__}: {ex})") from ex
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

    def domains(self) -> list[int]:
        return sorted(int(k) for k in self._e["domains"])

    def domain_len(self, d: int) -> int:
        return int(self._dom(d)["n"])

    def domain_arrays(self, d: int) -> dict[str, tuple[tuple, np.dtype]]:
        """name -> (shape, dtype) of the arrays of domain d (from the manifest, no I/O)."""
        return {n: (tuple(s), np.dtype(t)) for n, (s, t) in self._dom(d)["arrays"].items()}

    def _attrs(self, g: str) -> dict:
        self._check()
        try:
            a = self._r.attrs_json(g)
            return json.loads(a) if a is not None else {}
        except Exception as ex:  # noqa: BLE001
            raise StoreError(f"{self._where}: attrs of /{g} unreadable ({type(ex).__name__}: {ex})") from ex

    def domain_attrs(self, d: int) -> dict:
        self._dom(d)
        return self._attrs(domain_group(operator.index(d)))

    def _read(self, g: str, arrays: dict, names, rows) -> dict[str, np.ndarray]:
        self._check()
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
                    out[n] = self._r.read_full(g, n, shape, dtype)
                    continue
                if not shape:
                    raise StoreError(f"{self._where}: /{g}/{n} is 0-d; rows do not apply")
                sel = normalize_rows(rows, shape[0], f"{self._where}: /{g}/{n}")
                if isinstance(sel, tuple):
                    a = np.empty((sel[1] - sel[0],) + shape[1:], dtype=dtype)
                    self._r.read_range(g, n, sel[0], sel[1], a)
                else:
                    a = gather_rows(lambda s, e, o: self._r.read_range(g, n, s, e, o),
                                    sel, shape, dtype)
                out[n] = a
        except StoreError:
            raise
        except _IO_ERRORS as ex:
            raise StoreError(f"{self._where}: epoch {self.step} /{g}: read failed "
                             f"({type(ex).__name__}: {ex})") from ex
        finally:
            self._r.after_read()
        return out

    def read_domain(self, d: int, names: list[str] | None = None,
                    rows: slice | np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Arrays of domain d (all, or `names`); `rows` reads only those rows (first axis)."""
        info = self._dom(d)
        return self._read(domain_group(operator.index(d)), info["arrays"], names, rows)

    def read_globals(self) -> tuple[dict[str, np.ndarray], dict]:
        g = self._e.get("globals")
        if g is None:
            return {}, {}
        return self._read(GLOBALS_GROUP, g["arrays"], None, None), self._attrs(GLOBALS_GROUP)

    def close(self) -> None:
        r, self._r = self._r, None
        if r is not None:
            try:
                r.close()
            except Exception:  # noqa: BLE001
                pass


def store_owns(root, name: str) -> bool:
    """Whether the entry `name` directly inside store directory `root` is the store's own
    (its manifest, a manifest temporary, the epochs directory or the lock file)."""
    from ._util import EPOCH_DIR, MANIFEST, MANIFEST_TMP
    return name in (MANIFEST, EPOCH_DIR, ".ooc-dem.lock") or name.startswith(MANIFEST_TMP)
