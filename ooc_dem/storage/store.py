"""Store: a run's committed epochs on top of a place (store directory or memory backing):
queries, the commit of an epoch, verification and reads with fallback, pruning. opening.py's
create_store and open_store make one. See the package docstring for layout and guarantees."""

from __future__ import annotations

import copy
import dataclasses
import json
import operator
import os
import weakref
from collections.abc import Iterable
from typing import Literal

import numpy as np

from . import _lock, _memory
from ._manifest import EXT, MAX_INT64, Place, files_of, now, validate_manifest
from ._util import FORMAT_VERSION, GLOBALS_GROUP, JSONObject, StoreError, domain_group, epoch_basename, write_error
from .epoch import EpochReader, EpochWriter, own_step_problem
from .writeguard import shortfall


class Problem(str):
    """One problem ``Store.verify`` found: the one-line message (the string itself) and
    ``step``, the epoch it belongs to (None for a problem of no one epoch, such as a step
    the manifest does not name). Callers decide by ``step``, never by parsing the text."""

    step: int | None

    def __new__(cls, message: str, step: int | None = None) -> Problem:
        problem = super().__new__(cls, message)
        problem.step = step
        return problem


@dataclasses.dataclass(frozen=True)
class EpochInfo:
    """One committed epoch of a manifest, as `Store.list_epochs` reports it (no data read)."""

    role: str  # "previous" or "current"
    step: int
    path: str  # relative to the store: "epochs/<name>"
    location: str  # where it is (the store path joined with `path`)
    nbytes: int  # total recorded size of its files
    n_domains: int
    problems: tuple[str, ...]  # missing, special or wrong-sized files (sizes only, no checksums)


@dataclasses.dataclass(frozen=True)
class Leftover:
    """What an interrupted write left in a store (`open_store(repair=True)` deletes it)."""

    path: str
    pid: int | None  # the writing process of a ``*.tmp-<pid>`` temporary
    running: bool  # whether that process is running (it may still be writing)


def _pid_running(pid: int) -> bool:
    if pid == os.getpid():  # our own pid on a leftover: an earlier process that had it
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, belongs to someone else
        return True
    except OverflowError:
        return False
    return True


class Store:
    """A run's epochs. See the package docstring for layout and guarantees."""

    def __init__(
        self, place: Place, path: str, manifest: JSONObject, lock: _lock.StoreLock | None = None, writable: bool = True
    ):
        self._place: Place = place
        self.path = path
        self.backend: str = manifest["backend"]
        self._m = manifest
        self.warnings: list[str] = []  # e.g. fallback to the previous epoch
        self.repaired: list[str] = []  # what open_store(repair=True) deleted
        self._verified: set[str] = set()  # epoch paths known good (written or verified here)
        self._writer: EpochWriter | None = None
        self._readers: weakref.WeakSet[EpochReader] = weakref.WeakSet()
        self._closed = False
        self._lock = lock  # the store's write lock (disk stores open for writing)
        self.writable = writable

    def __repr__(self) -> str:
        return f"Store({self.path!r}, backend={self.backend!r}, current={self.current()})"

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> Literal[False]:
        self.close()
        return False

    @property
    def meta(self) -> JSONObject:
        return copy.deepcopy(self._m["meta"])

    def _check_open(self) -> None:
        if self._closed:
            raise StoreError(f"{self.path}: store is closed")

    def _check_writable(self) -> None:
        self._check_open()
        if not self.writable:
            raise StoreError(
                f"{self.path}: store was opened read-only (repair=False); open it with repair=True to write"
            )

    def _entries(self) -> list[JSONObject]:
        """previous, current (those present in the manifest), oldest first."""
        return [e for e in (self._m["previous"], self._m["current"]) if e is not None]

    def _entry(self, step: int) -> JSONObject:
        for e in self._entries():
            if e["step"] == step:
                return e
        raise StoreError(
            f"{self.path}: epoch {step} is not in the manifest (have {[e['step'] for e in self._entries()]})"
        )

    # ------------------------------------------------------------------ queries
    def epochs(self) -> list[int]:
        self._check_open()
        return [e["step"] for e in self._entries() if self._place.exists(e)]

    def current(self) -> int | None:
        cur = self._m["current"]
        return None if cur is None else int(cur["step"])

    def manifest(self, fresh: bool = False) -> JSONObject:
        """A copy of the (validated) manifest; fresh=True reads it again from the store, e.g. to
        see what a run writing the store has committed since this Store was opened."""
        self._check_open()
        if not fresh:
            return copy.deepcopy(self._m)
        backends = ("memory",) if self._place.is_memory else ("hdf5", "zarr")
        place = self._place
        m, _ = validate_manifest(place.read_manifest(), self.path, backends, lambda _b: place)
        return m

    def list_epochs(self) -> list[EpochInfo]:
        """The committed epochs, oldest first, with sizes checked (not their checksums)."""
        self._check_open()
        out = []
        for role, e in (("previous", self._m["previous"]), ("current", self._m["current"])):
            if e is not None:
                subs = files_of(e)
                out.append(
                    EpochInfo(
                        role,
                        e["step"],
                        e["path"],
                        self._where(e),
                        sum(f["size"] for x in subs for f in x["files"]),
                        len(e["domains"]),
                        tuple(p for x in subs for p in self._place.size_problems(x)),
                    )
                )
        return out

    def leftovers(self, manifest: JSONObject | None = None) -> list[Leftover]:
        """Temporaries and unnamed epoch files (what open_store(repair=True) would delete).

        `manifest` (from ``manifest(fresh=True)``) judges "unnamed" by what is committed now
        rather than when this Store was opened (a run may be writing the store)."""
        self._check_open()
        m = self._m if manifest is None else manifest
        return [Leftover(p, pid, pid is not None and _pid_running(pid)) for p, pid in self._place.leftovers(m)]

    def live_writers(self) -> list[int]:
        """Pids of processes writing this store: the holder of its write lock (0 if its pid is
        unknown) and running processes with a temporary epoch in it; [] if none."""
        self._check_open()
        if self._place.is_memory:
            return []
        pids = {x.pid for x in self.leftovers() if x.running and x.pid is not None}
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
        if not 0 <= step <= MAX_INT64:
            raise StoreError(f"{self.path}: epoch step must be in [0, 2**63), got {step}")
        if self._writer is not None and self._writer._state == "open":
            raise StoreError(
                f"{self.path}: epoch {self._writer.step} is still being written (commit or abort it first)"
            )
        prev = self._m["previous"]
        if prev is not None and step <= prev["step"]:
            raise StoreError(
                f"{self.path}: cannot write epoch {step}: not newer than the previous committed epoch {prev['step']}"
            )
        # never reuse the name of an epoch the manifest still names (no in-place modification)
        named = {os.path.basename(e["path"]) for e in self._entries()}
        rev = 0
        while epoch_basename(step, EXT[self.backend], rev) in named:
            rev += 1
        self.check_room(step, expected_bytes)
        self._writer = EpochWriter(self, step, epoch_basename(step, EXT[self.backend], rev))
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
            size = sum(f["size"] for x in files_of(good[-1]) for f in x["files"])
            expected_bytes = size + size // 64 + (4 << 10)
        need = int(expected_bytes)
        where = self._place.tmp_name(epoch_basename(step, EXT[self.backend]))
        try:
            # a directory epoch's files are small each: only a one-file epoch meets the file-size limit
            short = shortfall(self._place.edir, need, 0 if self._place.fmt.IS_DIR else need)
        except OSError as e:
            raise write_error(self._place.edir, e) from e
        if short is not None:
            raise StoreError(
                f"{where}: disk full or file too large (epoch {step} {short[1]}; committed epochs are untouched)"
            )

    def _commit(self, w: "EpochWriter", durable: bool) -> None:
        if sorted(w._parts) != list(range(1, len(w._parts) + 1)):
            raise StoreError(f"{self.path}: epoch {w.step} has parts {sorted(w._parts)}, not 1 to {len(w._parts)}")
        place, writer = self._place, w._w  # the writer place.new_writer made
        if place.is_memory and isinstance(writer, _memory.Writer):
            rel, files = place.publish(writer, w._basename, durable)
        elif not place.is_memory and not isinstance(writer, _memory.Writer):
            rel, files = place.publish(writer, w._basename, durable)
        else:
            raise StoreError(f"{self.path}: epoch {w.step} was begun in another kind of store")
        entry: JSONObject = {
            "step": w.step,
            "path": rel,
            "files": files,
            "domains": w._domains,
            "globals": w._globals,
            "committed_at": now(),
            "format_version": FORMAT_VERSION,
        }
        if w._parts and not self._place.is_memory:  # (add_part refuses parts of a memory store)
            # phase 2 of the parts' commit: every part is complete (its writer finished it and
            # reported its checksums); they take their names, then the manifest names them all
            entry["parts"] = []
            try:
                for k in sorted(w._parts):
                    part = w._parts[k]
                    self._place.publish_part(part["tmp"], part["path"].rpartition("/")[2], durable)
                    entry["parts"].append({"path": part["path"], "files": part["files"]})
            except StoreError:
                for x in files_of(entry):
                    self._place.remove_epoch(x)
                raise
        if self.compression is not None:
            entry["compression"] = self.compression
        old_cur, old_prev = self._m["current"], self._m["previous"]
        # an epoch of an older store keeps the version it was written in (named in its entry)
        # when the manifest moves on to this code's version
        old_v = self._m.get("format_version", FORMAT_VERSION)
        old_cur, old_prev = (
            {**e, "format_version": e.get("format_version", old_v)} if e is not None else None
            for e in (old_cur, old_prev)
        )
        if old_cur is None:
            new_prev = None
        elif w.step > old_cur["step"]:
            new_prev = old_cur
        else:  # rewrite of a step <= current: current is replaced
            new_prev = old_prev
        new_m = dict(self._m, current=entry, previous=new_prev, format_version=FORMAT_VERSION)
        try:
            self._place.write_manifest(new_m, durable)
        except StoreError:
            for x in files_of(entry):
                self._place.remove_epoch(x)
            raise
        self._m = new_m
        self._verified.add(rel)
        keep = {rel} | ({new_prev["path"]} if new_prev else set())
        for e in (old_cur, old_prev):  # only after the new manifest is in place
            if e is not None and e["path"] not in keep:
                self._verified.discard(e["path"])
                try:
                    for x in files_of(e):
                        self._place.remove_epoch(x)
                except (OSError, StoreError) as ex:
                    self.warnings.append(f"{self.path}: could not delete old epoch {e['path']}: {ex}")

    # ------------------------------------------------------------------ reading / checking
    def _problems(self, e: JSONObject, structure_if_damaged: bool = True) -> list[str]:
        """Checksums of every listed file, then groups/arrays named by the manifest.

        With structure_if_damaged=False, files that failed their checksums are not
        opened (a damaged HDF5 file is not handed to the HDF5 library on the read path).
        """
        subs = files_of(e)
        problems = [p for x in subs for p in self._place.check_files(x)]
        if problems and not structure_if_damaged:
            return problems
        for k, x in enumerate(subs):
            groups = [
                (domain_group(int(d)), info["arrays"]) for d, info in e["domains"].items() if info.get("part", 0) == k
            ]
            if k == 0 and e.get("globals") is not None:
                groups.append((GLOBALS_GROUP, e["globals"]["arrays"]))
            problems += self._group_problems(x, groups)
        return problems

    def _group_problems(self, e: JSONObject, groups: Iterable[tuple[str, JSONObject]]) -> list[str]:
        """Groups, arrays (shape, dtype) and attrs of one epoch file as the manifest names them."""
        problems = []
        try:
            r = self._place.open_reader(e)
        except Exception as ex:  # noqa: BLE001 - any failure to open is a problem to report
            return [f"{self._where(e)}: cannot open ({type(ex).__name__}: {ex})"]
        own = own_step_problem(r, self._where(e), e["step"])
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
                            problems.append(
                                f"{self._where(e)}: array /{g}/{name} is {info[0]} "
                                f"{np.dtype(info[1])}, manifest says {tuple(shape)} "
                                f"{np.dtype(dtype)}"
                            )
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

    def _where(self, e: JSONObject) -> str:
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
                    f"using previous epoch {prev['step']}"
                )
                return EpochReader(self, prev)
            raise StoreError(
                f"{self.path}: epoch {cur['step']} is corrupt ({bad[0]}) and previous "
                f"epoch {prev['step']} too ({bad_prev[0]})"
            )
        raise StoreError(f"{self.path}: epoch {cur['step']} is corrupt ({bad[0]}) and there is no previous epoch")

    def _bad(self, e: JSONObject) -> list[str]:
        if e["path"] in self._verified:
            return []
        p = self._problems(e, structure_if_damaged=False)
        if not p:
            self._verified.add(e["path"])
        return p

    def _ensure_ok(self, e: JSONObject) -> None:
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
        self._place.write_manifest(new_m, durable=False)  # first forget it, then delete it
        self._m = new_m
        self._verified.discard(prev["path"])
        for x in files_of(prev):
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
