"""EpochWriter and EpochReader: one epoch of a store, written under temporary names and
published by ``EpochWriter.commit``, or read back once committed (``Store.begin_epoch`` and
``Store.read_epoch`` make them)."""

from __future__ import annotations

import json
import operator
import os
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any, Literal, Protocol, TypeAlias

import numpy as np
from numpy.typing import NDArray

from . import _memory
from ._manifest import files_of
from ._util import (
    EPOCH_DIR,
    FORMAT_VERSION,
    GLOBALS_GROUP,
    MAX_PARTS,
    FormatReader,
    FormatWriter,
    JSONObject,
    StoreError,
    array_meta,
    domain_group,
    gather_rows,
    normalize_rows,
    part_basename,
    prepare_arrays,
    remove_path,
    to_json,
    write_error,
)
from ._util import TMP_NAME_RE as _TMP_RE
from ._util import show as _show

if TYPE_CHECKING:
    import weakref

    from ._manifest import Place


class OwningStore(Protocol):
    """What an epoch's writer and reader use of the Store that made them (store.py's Store;
    a protocol here: the store imports this module)."""

    path: str
    _place: Place
    _m: JSONObject
    _readers: weakref.WeakSet[EpochReader]

    @property
    def compression(self) -> str | None: ...

    def _check_open(self) -> None: ...

    def _commit(self, w: EpochWriter, durable: bool) -> None: ...

    def _where(self, e: JSONObject) -> str: ...


_IO_ERRORS = (OSError, RuntimeError, KeyError, ValueError, TypeError)

# an open epoch file of a disk store, or a memory store's epoch
EpochFile: TypeAlias = "FormatReader | _memory.Reader"


# ============================================================================ writer


class EpochWriter:
    """Writes one epoch of ``store`` (the Store that began it) under temporary names;
    commit() publishes it atomically."""

    def __init__(self, store: OwningStore, step: int, basename: str):
        self._store = store
        self.step = step
        self._basename = basename
        self._domains: dict[str, JSONObject] = {}
        self._globals: JSONObject | None = None
        self._parts: dict[int, JSONObject] = {}
        self._state = "open"
        self._tmp = store._place.tmp_name(basename)
        try:
            self._w: FormatWriter | _memory.Writer = store._place.new_writer(step, basename, store.compression)
        except (OSError, RuntimeError) as e:
            self._state = "aborted"
            if not store._place.is_memory:
                remove_path(self._tmp)
            raise write_error(self._tmp, e) from e

    def __repr__(self) -> str:
        return f"EpochWriter({self._store.path!r}, step={self.step}, state={self._state})"

    def __enter__(self) -> EpochWriter:
        return self

    def __exit__(self, *exc: object) -> Literal[False]:
        if self._state == "open":  # exception, or left without commit(): discard the epoch
            self.abort()
        return False

    def _check_open(self) -> None:
        if self._state != "open":
            raise StoreError(f"{self._store.path}: epoch {self.step} writer is {self._state}")

    def _write(self, group: str, arrays: dict[str, NDArray[Any]], attrs_json: str) -> None:
        try:
            self._w.write_group(group, arrays, attrs_json)
        except (OSError, RuntimeError) as e:
            self.abort()
            raise write_error(self._tmp, e) from e
        except BaseException:
            self.abort()
            raise

    def write_domain(self, d: int, arrays: Mapping[str, object], attrs: Mapping[str, object] | None = None) -> None:
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
        self._domains[str(d)] = {"n": 0 if first is None else int(first.shape[0]), "arrays": array_meta(arrs)}

    @property
    def basename(self) -> str:
        """The epoch's file name: the processes that write its parts name them after it
        (``write_part(..., writer.basename, k, ...)``)."""
        return self._basename

    def add_part(self, part: JSONObject) -> None:
        """Phase 1 of a parts' commit: part ``part["part"]`` (what ``write_part`` returned in
        another process, complete on disk under its temporary name) is in this epoch. It is
        published with the epoch by commit(), and removed if the epoch is aborted."""
        self._check_open()
        where = f"{self._store.path}: epoch {self.step}"
        place = self._store._place
        if place.is_memory:
            raise StoreError(f"{where}: a memory store keeps no parts (one process holds it)")
        k = part.get("part")
        if type(k) is not int or not 1 <= k <= MAX_PARTS or k in self._parts:
            raise StoreError(f"{where}: part {_show(k)} is not a new part number (1 to {MAX_PARTS})")
        name = part_basename(self._basename, k)
        tmp = part.get("tmp", "")
        m = _TMP_RE.match(os.path.basename(tmp)) if isinstance(tmp, str) else None
        if (
            part.get("path") != f"{EPOCH_DIR}/{name}"
            or m is None
            or m.group(1) != name
            or os.path.dirname(tmp) != place.edir
        ):
            raise StoreError(f"{where}: part {k} was not written as part {k} of this epoch ({name})")
        self._parts[k] = part  # its tmp is ours to remove from now on (abort)
        for d, info in part["domains"].items():
            if d in self._domains:
                self.abort()
                raise StoreError(f"{where} domain {d}: written twice (part {k} and another)")
            self._domains[d] = {**info, "part": k}

    def write_globals(self, arrays: Mapping[str, object], attrs: Mapping[str, object] | None = None) -> None:
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


def own_step_problem(r: EpochFile, where: str, step: int) -> str | None:
    """The problem of a file of epoch `step` (its main file or a part, open as `r`) whose
    writer recorded another step in it, or none: a file of another epoch put in its place
    (its size and checksum in the manifest recomputed). One attribute, read once per open.
    A memory store has no files to swap."""
    if isinstance(r, _memory.Reader):
        return None
    try:
        got = r.root_step()
    except Exception as ex:  # noqa: BLE001 - a hostile attribute is a problem to report
        return f"{where}: root attribute 'step' unreadable ({type(ex).__name__}: {ex})"
    if type(got) is int and got == step:
        return None
    return f"{where}: the file records step {_show(got)}, not the epoch's {step} (a file of another epoch)"


class EpochReader:
    """Read access to one committed epoch (its manifest ``entry``) of ``store``."""

    def __init__(self, store: OwningStore, entry: JSONObject):
        self._store = store
        self._e = entry
        self.step: int = entry["step"]
        self._where = store._where(entry)
        self._r: EpochFile | None
        # the format the epoch was written in (its entry's, else the manifest's)
        store_version: int = store._m.get("format_version", FORMAT_VERSION)
        self.format_version: int = entry.get("format_version", store_version)
        try:
            self._r = store._place.open_reader(entry)
        except Exception as ex:  # noqa: BLE001
            raise StoreError(f"{self._where}: cannot open epoch {self.step} ({type(ex).__name__}: {ex})") from ex
        own = own_step_problem(self._r, self._where, self.step)
        if own:
            self._r.close()
            raise StoreError(own)
        self._part_readers: dict[int, EpochFile] = {}
        # each group's attrs as read once (JSON text, decoded afresh for every caller): an
        # epoch never changes while it is read, and a sweep asks for every group's x range
        # once per slab (D^2 lookups: 62 500 HDF5 attribute reads took half of a sweep at D = 250)
        self._attrs_json: dict[str, str | None] = {}
        store._readers.add(self)

    def __repr__(self) -> str:
        return f"EpochReader({self._where!r}, step={self.step})"

    def __enter__(self) -> EpochReader:
        return self

    def __exit__(self, *exc: object) -> Literal[False]:
        self.close()
        return False

    def _dom(self, d: int) -> JSONObject:
        info: JSONObject | None = self._e["domains"].get(str(operator.index(d)))
        if info is None:
            raise StoreError(f"{self._where}: epoch {self.step} has no domain {d} (has {self.domains()})")
        return info

    def _check(self) -> EpochFile:
        if self._r is None:
            raise StoreError(f"{self._where}: reader is closed")
        return self._r

    def _reader(self, d: int | None = None) -> EpochFile:
        """The reader of the file that holds domain d (None: the globals' file)."""
        main = self._check()
        k = 0 if d is None else self._dom(d).get("part", 0)
        if k == 0:
            return main
        r = self._part_readers.get(k)
        if r is None:
            sub = files_of(self._e)[k]
            try:
                r = self._store._place.open_reader(sub)
            except Exception as ex:  # noqa: BLE001
                raise StoreError(
                    f"{self._store._where(sub)}: cannot open part {k} of epoch {self.step} ({type(ex).__name__}: {ex})"
                ) from ex
            own = own_step_problem(r, self._store._where(sub), self.step)
            if own:
                r.close()
                raise StoreError(own)
            self._part_readers[k] = r
        return r

    def domains(self) -> list[int]:
        return sorted(int(k) for k in self._e["domains"])

    def domain_len(self, d: int) -> int:
        return int(self._dom(d)["n"])

    def domain_arrays(self, d: int) -> dict[str, tuple[tuple[int, ...], np.dtype[Any]]]:
        """name -> (shape, dtype) of the arrays of domain d (from the manifest, no I/O)."""
        return {n: (tuple(s), np.dtype(t)) for n, (s, t) in self._dom(d)["arrays"].items()}

    def _attrs(self, g: str, r: EpochFile | None = None) -> JSONObject:
        main = self._check()
        r = main if r is None else r
        try:
            if g not in self._attrs_json:  # a group's name is unique across the epoch's files
                self._attrs_json[g] = r.attrs_json(g)
            a = self._attrs_json[g]
            return json.loads(a) if a is not None else {}
        except Exception as ex:  # noqa: BLE001
            raise StoreError(f"{self._where}: attrs of /{g} unreadable ({type(ex).__name__}: {ex})") from ex

    def domain_attrs(self, d: int) -> JSONObject:
        return self._attrs(domain_group(operator.index(d)), self._reader(d))

    def _read(
        self, g: str, arrays: JSONObject, names: Iterable[str] | None, rows: object, r: EpochFile | None = None
    ) -> dict[str, NDArray[Any]]:
        main = self._check()
        reader = main if r is None else r
        if names is None:
            names = list(arrays)
        elif isinstance(names, str):
            raise StoreError(f"{self._where}: names must be a list of array names, not a str")
        out: dict[str, NDArray[Any]] = {}
        try:
            for n in names:
                if n not in arrays:
                    raise StoreError(f"{self._where}: epoch {self.step} /{g} has no array {n!r} (has {list(arrays)})")
                shape, dtype = tuple(arrays[n][0]), np.dtype(arrays[n][1])
                if rows is None:
                    out[n] = reader.read_full(g, n, shape, dtype)
                    continue
                if not shape:
                    raise StoreError(f"{self._where}: /{g}/{n} is 0-d; rows do not apply")
                sel = normalize_rows(rows, shape[0], f"{self._where}: /{g}/{n}")
                if sel is None or isinstance(sel, tuple):  # (None: every row)
                    start, stop = (0, shape[0]) if sel is None else sel
                    a = np.empty((stop - start,) + shape[1:], dtype=dtype)
                    reader.read_range(g, n, start, stop, a)
                else:
                    a = gather_rows(lambda s, e, o: reader.read_range(g, n, s, e, o), sel, shape, dtype)
                out[n] = a
        except StoreError:
            raise
        except _IO_ERRORS as ex:
            raise StoreError(f"{self._where}: epoch {self.step} /{g}: read failed ({type(ex).__name__}: {ex})") from ex
        finally:
            reader.after_read()
        return out

    def read_domain(
        self, d: int, names: list[str] | None = None, rows: slice | NDArray[Any] | None = None
    ) -> dict[str, NDArray[Any]]:
        """Arrays of domain d (all, or `names`); `rows` reads only those rows (first axis)."""
        info = self._dom(d)
        return self._read(domain_group(operator.index(d)), info["arrays"], names, rows, self._reader(d))

    def read_globals(self) -> tuple[dict[str, NDArray[Any]], JSONObject]:
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
