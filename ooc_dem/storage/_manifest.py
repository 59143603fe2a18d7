"""A store's manifest: the backends and their epoch names, and the validation of a manifest
read from a store (untrusted input: see the package docstring) so that later code can trust
its entries."""

from __future__ import annotations

import datetime as _dt
import os
import re
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, TypeAlias

import numpy as np

from . import _confine
from ._util import (
    EPOCH_DIR,
    FORMAT,
    MANIFEST,
    MAX_PARTS,
    SUPPORTED_VERSIONS,
    JSONObject,
    StoreError,
    StrPath,
    check_array_name,
    file_checksum,
    part_basename,
)
from ._util import show as _show

if TYPE_CHECKING:
    from . import _disk, _memory

# where a store's manifest and epochs are: a store directory or a memory store's backing
Place: TypeAlias = "_disk.Place | _memory.Place"

BACKENDS = ("hdf5", "zarr", "memory")
# the extension of the epochs a backend writes, and of those it reads (zarr: one zip archive
# per epoch; directories, written before, are still read)
EXT = {"hdf5": "h5", "zarr": "zip", "memory": "mem"}
READ_EXTS = {"hdf5": ("h5",), "zarr": ("zip", "zarr"), "memory": ("mem",)}
# optional compression of a store's arrays, per backend: zarr codecs (zstd; blosc = lz4 with
# byte shuffle) or HDF5 filters (gzip = deflate level 4 with shuffle; lzf with shuffle);
# measured by tools/iobench.py (off by default: see the README's "Disk economy")
COMPRESSIONS = {"hdf5": ("gzip", "lzf"), "zarr": ("zstd", "blosc"), "memory": ()}
# a compressed epoch's arrays may hold at most this many times the bytes of its files (a
# bound on what a manifest can make a reader allocate; real states compress ~1.1-2x)
_MAX_RATIO = 64

# the limits of what a manifest may say (beyond them it is not ours): steps, sizes and array
# dimensions are stored as int64; numpy arrays have at most 64 dimensions, ours far fewer
MAX_INT64 = 2**63 - 1
_MAX_NDIM = 32
_MAX_DOMAIN_ID = 10**9 - 1
_MAX_NAME_CHARS = 200  # ARRAY_NAME_RE's limit, checked first to keep messages short
_DOMAIN_KEY_RE = re.compile(r"^(0|[1-9][0-9]{0,8})$")  # str(d) of a domain id d >= 0


def now() -> str:
    """The time as a manifest records it (UTC, ISO 8601, seconds)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def store_key(path: StrPath) -> str:
    """The store's path as a str (also a memory store's name)."""
    try:
        return os.fspath(path)
    except TypeError:
        raise StoreError(f"{path!r}: store path must be a str or os.PathLike") from None


def _int(v: object, what: str, lo: int = 0, hi: int = MAX_INT64) -> int:
    if type(v) is not int or not lo <= v <= hi:  # (bool is an int subclass: refused)
        raise StoreError(f"{what}: must be an integer in [{lo}, {hi}], got {_show(v)}")
    return v


def _dict(v: object, what: str) -> JSONObject:
    if not isinstance(v, dict):
        raise StoreError(f"{what}: malformed (must be a JSON object, got {_show(v)})")
    return v


def _check_arrays(arrays: object, what: str, min_ndim: int) -> int:
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
            raise StoreError(
                f"{where}: malformed shape {_show(shape)} (a list of {min_ndim} to {_MAX_NDIM} non-negative integers)"
            )
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
            raise StoreError(
                f"{where}: dtype {_show(dtype)} is not a numeric numpy dtype string (such as '<f8', '<i8', '|b1')"
            )
        nbytes += count * dt.itemsize
        if nbytes > MAX_INT64:
            raise StoreError(f"{where}: arrays larger than 2**63 bytes")
    return nbytes


def _check_entry(entry: object, role: str, where: str, place: Place, ext: Sequence[str]) -> None:
    """Check one epoch entry of a manifest, confining its paths (see _confine)."""
    what = f"{where}/{MANIFEST}: {role} epoch"
    e = _dict(entry, what)
    step = _int(e.get("step"), f"{what} step")
    if "format_version" in e:
        v = e["format_version"]
        if type(v) is not int or v not in SUPPORTED_VERSIONS:
            raise StoreError(
                f"{what}: unsupported format_version {_show(v)} (this code reads "
                f"{', '.join(map(str, SUPPORTED_VERSIONS))})"
            )
    epoch = _confine.epoch_path(e.get("path"), ext, step, what)
    files = e.get("files")
    if not isinstance(files, list):
        raise StoreError(f'{what}: malformed "files" (must be a list of file entries)')
    comp = e.get("compression")
    if comp is not None and (not isinstance(comp, str) or comp not in COMPRESSIONS[place.backend]):
        raise StoreError(f"{what}: unknown compression {_show(comp)}")
    seen: set[str] = set()
    stored = 0

    def check_files(epoch: str, files: list[object], what: str) -> None:
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
        raise StoreError(f'{what}: malformed "parts" (must be a list of at most {MAX_PARTS} part entries, on disk)')
    for k, part in enumerate(parts, start=1):
        pw = f"{what} part {k}"
        part = _dict(part, pw)
        ppath = _confine.epoch_path(part.get("path"), ext, step, pw, part=k)
        if ppath != f"{EPOCH_DIR}/{part_basename(epoch.rpartition('/')[2], k)}":
            raise StoreError(f"{pw}: path {_show(ppath)} is not part {k} of epoch {epoch}")
        pfiles = part.get("files")
        if not isinstance(pfiles, list):
            raise StoreError(f'{pw}: malformed "files" (must be a list of file entries)')
        check_files(ppath, pfiles, pw)
        if not place.is_memory:
            place.resolver.path(ppath, pw)
    domains = _dict(e.get("domains"), f"{what} domains")
    needed = 0
    for d, info in domains.items():
        if not (isinstance(d, str) and _DOMAIN_KEY_RE.match(d)):
            raise StoreError(
                f"{what}: domain key {_show(d)} is not a domain id "
                f"(0 to {_MAX_DOMAIN_ID}, written without sign or leading zeros)"
            )
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
        raise StoreError(
            f"{what}: arrays need {needed} bytes but its files hold only {stored}"
            + ("" if comp is None else f" ({comp}, at most {_MAX_RATIO}x)")
        )
    if not isinstance(e.get("committed_at", ""), str):
        raise StoreError(f"{what}: malformed committed_at {_show(e.get('committed_at'))}")
    if not place.is_memory:
        # the epoch itself must resolve inside epochs/; its files are strictly below it (checked
        # above), so only links inside the epoch could lead elsewhere: those are verification
        # problems of that epoch (Place.check_files), not reasons to refuse the whole store
        place.resolver.path(epoch, what)


def validate_manifest(
    m: object, where: str, backends: Sequence[str], place_for: Callable[[str], Place]
) -> tuple[JSONObject, Place]:
    """Check everything later code relies on, so that it can trust the manifest's entries.

    `place_for(backend)` gives the place whose paths the entries must resolve in.
    Returns (manifest, place)."""
    if not isinstance(m, dict) or m.get("format") != FORMAT:
        raise StoreError(f'{where}: not an ooc-dem store (MANIFEST.json has no "format": "{FORMAT}")')
    v = m.get("format_version")
    if type(v) is not int or v not in SUPPORTED_VERSIONS:
        raise StoreError(
            f"{where}: unsupported format_version {_show(v)} (this code reads "
            f"{', '.join(map(str, SUPPORTED_VERSIONS))})"
        )
    backend = m.get("backend")
    if not isinstance(backend, str) or backend not in backends:
        raise StoreError(
            f"{where}: MANIFEST.json names backend {_show(backend)}, expected one of {', '.join(backends)}"
        )
    place = place_for(backend)
    if not place.is_memory:
        place.resolver.check_epoch_dir()
    if not isinstance(m.get("meta", {}), dict):
        raise StoreError(f"{where}: MANIFEST.json missing or unreadable (malformed: meta is not an object)")
    if not isinstance(m.get("created_at", ""), str):
        raise StoreError(f"{where}: MANIFEST.json missing or unreadable (malformed: created_at)")
    comp = m.get("compression")
    if comp is not None and (not isinstance(comp, str) or comp not in COMPRESSIONS[backend]):
        raise StoreError(
            f"{where}: MANIFEST.json names compression {_show(comp)}, expected one "
            f"of the {backend} backend's ({', '.join(COMPRESSIONS[backend]) or 'none'})"
        )
    cur, prev = m.get("current"), m.get("previous")
    ext = READ_EXTS[backend]
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
            raise StoreError(f"{what}: previous epoch step {prev['step']} is not older than the current {cur['step']}")
    m.setdefault("meta", {})
    m.setdefault("previous", None)
    m.setdefault("current", None)
    return m, place


def files_of(e: JSONObject) -> list[JSONObject]:
    """The epoch's main file(s) and every part's, each as an entry of its own (the Place's
    checks, sizes and deletion work on one path with its files)."""
    return [e] + [{"step": e["step"], "path": p["path"], "files": p["files"]} for p in e.get("parts", ())]
