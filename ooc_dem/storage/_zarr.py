"""zarr v3 epoch format of earlier versions, still read: one LocalStore directory per epoch,
one group per sub-domain, one uncompressed chunk per array (chunks = full shape), no
sharding, no consolidated metadata. Epochs are written as one zip archive each now
(``_zarr_zip``); the directory ``Writer`` stays for tests of stores written before."""

from __future__ import annotations

import json
import os
import sys
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import DTypeLike, NDArray

from ._confine import open_regular, read_regular
from ._util import (
    ATTRS_KEY,
    FORMAT,
    JSONObject,
    StoreError,
    attrs_text,
    bytes_digest,
    drop_page_cache,
    file_digest,
    fsync_tree,
    parse_json,
    pread_into,
    remove_path,
)

if TYPE_CHECKING:
    import zarr
    from zarr.types import AnyArray

EXT = "zarr"
IS_DIR = True
# a zarr metadata document of ours is a few hundred bytes; bigger ones are not read
_MAX_DOC_BYTES = 1 << 20


def walk_files(root: str) -> list[str]:
    """Relative paths ('/'-separated) of every file under root, sorted."""
    out = []
    for d, _dirs, files in os.walk(root):
        for f in files:
            out.append(os.path.relpath(os.path.join(d, f), root).replace(os.sep, "/"))
    return sorted(out)


def _raw_ok(a: np.ndarray) -> bool:
    """Arrays written without the zarr library: 1-D or more, bool/int/uint/float."""
    return a.ndim >= 1 and a.dtype.kind in "biuf" and a.dtype.fields is None


def _array_metadata(a: np.ndarray) -> bytes:
    """The zarr v3 array metadata zarr 3.x writes for an uncompressed one-chunk array."""
    kind = a.dtype.kind
    fill = False if kind == "b" else (0.0 if kind == "f" else 0)
    bytes_codec: JSONObject = {"name": "bytes"}
    if a.dtype.itemsize > 1:
        bytes_codec["configuration"] = {"endian": "little"}
    meta = {
        "shape": list(a.shape),
        "data_type": a.dtype.name,
        "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": [max(1, s) for s in a.shape]}},
        "chunk_key_encoding": {"name": "default", "configuration": {"separator": "/"}},
        "fill_value": fill,
        "codecs": [bytes_codec],
        "attributes": {},
        "zarr_format": 3,
        "node_type": "array",
        "storage_transformers": [],
    }
    return json.dumps(meta, indent=2).encode()


def _write_file(path: str, data: bytes, hashed: dict[str, tuple[int, int, str]], rel: str) -> None:
    """Write a new file; remember (size, mtime, digest) so it is not read back to be hashed."""
    with open(path, "xb") as f:
        f.write(data)
    st = os.stat(path)
    hashed[rel] = (st.st_size, st.st_mtime_ns, bytes_digest(data))
    drop_page_cache(path)


class Writer:
    """Writes one epoch into the directory `path` (a temporary name, renamed by the caller)."""

    def __init__(self, path: str, step: int, compression: str | None = None) -> None:
        if compression is not None:
            raise ValueError("the zarr directory layout is written uncompressed only")
        self.path = path
        self._hashed: dict[str, tuple[int, int, str]] = {}  # rel -> (size, mtime_ns, digest)
        self._zgroups: zarr.Group | None = None  # zarr handles, only for fallbacks
        os.makedirs(path)  # a new directory, as zarr's "w-"
        self._write_group_doc("", {"ooc_dem_format": FORMAT, "step": int(step)})
        self._write_group_doc("domains", {})

    def _write_group_doc(self, group: str, attributes: JSONObject) -> None:
        """A zarr v3 group: its directory and metadata document (what zarr 3.x writes)."""
        gdir = os.path.join(self.path, *group.split("/")) if group else self.path
        if group:
            os.mkdir(gdir)
        doc = json.dumps({"attributes": attributes, "zarr_format": 3, "node_type": "group"}, indent=2)
        rel = f"{group}/zarr.json" if group else "zarr.json"
        _write_file(os.path.join(gdir, "zarr.json"), doc.encode(), self._hashed, rel)

    def _group(self, group: str, attrs_json: str) -> None:
        self._write_group_doc(group, {ATTRS_KEY: attrs_json})

    def _zarr_group(self, group: str) -> zarr.Group:
        import zarr
        from zarr.storage import LocalStore

        if self._zgroups is None:
            self._zgroups = zarr.open_group(store=LocalStore(self.path), mode="r+", zarr_format=3)
        node = self._zgroups[group]
        if not isinstance(node, zarr.Group):
            raise ValueError(f"{self.path}: {group}: not a group")
        return node

    def write_group(self, group: str, arrays: dict[str, NDArray[Any]], attrs_json: str) -> None:
        self._group(group, attrs_json)
        gdir = os.path.join(self.path, *group.split("/"))
        for name, a in arrays.items():
            if _raw_ok(a):
                # the zarr v3 array written directly (metadata document + its one chunk file):
                # byte for byte what zarr writes, without zarr's per-array async round trips,
                # which cost milliseconds per array and dominated out-of-core sweeps
                self._write_raw(gdir, f"{group}/{name}", name, a)
                continue
            arr = self._zarr_group(group).create_array(
                name,
                shape=a.shape,
                dtype=a.dtype,
                chunks=tuple(max(1, s) for s in a.shape),  # one chunk per array
                shards=None,
                filters=None,
                compressors=None,
                fill_value=0,
                config={"write_empty_chunks": True},
            )  # every non-empty array has its chunk file
            if a.size:
                arr[...] = a
        # hash the group's files while they are hot, then drop them from the page cache
        for rel in walk_files(gdir):
            self._hash(f"{group}/{rel}")

    def _write_raw(self, gdir: str, rel: str, name: str, a: NDArray[Any]) -> None:
        adir = os.path.join(gdir, name)
        os.mkdir(adir)
        _write_file(os.path.join(adir, "zarr.json"), _array_metadata(a), self._hashed, f"{rel}/zarr.json")
        if a.size:
            ck = ["c"] + ["0"] * a.ndim
            os.makedirs(os.path.join(adir, *ck[:-1]), exist_ok=True)
            data = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<")).tobytes()
            _write_file(os.path.join(adir, *ck), data, self._hashed, f"{rel}/{'/'.join(ck)}")

    def _hash(self, rel: str) -> str:
        p = os.path.join(self.path, *rel.split("/"))
        st = os.stat(p)
        h = self._hashed.get(rel)
        if h is None or h[0] != st.st_size or h[1] != st.st_mtime_ns:
            size, digest = file_digest(p)
            h = (size, st.st_mtime_ns, digest)
            self._hashed[rel] = h
        return h[2]

    def finish(self, durable: bool) -> list[tuple[str, int, str]]:
        files = []
        for rel in walk_files(self.path):
            digest = self._hash(rel)
            files.append((rel, self._hashed[rel][0], digest))
        if durable:
            fsync_tree(self.path)
        return files

    def abort(self) -> None:
        remove_path(self.path)


class _Member:
    """An array of an epoch group: shape, dtype, and its chunk file when it can be read raw."""

    __slots__ = ("shape", "dtype", "raw", "name")

    def __init__(self, shape: tuple[int, ...], dtype: np.dtype[Any], raw: str | None, name: str) -> None:
        self.shape, self.dtype, self.raw, self.name = shape, dtype, raw, name


def _read_json(path: str) -> JSONObject:
    """A metadata document of an epoch (untrusted): a small regular file holding a JSON object."""
    try:
        doc = parse_json(read_regular(path, _MAX_DOC_BYTES), path)
    except StoreError as e:
        if str(e).endswith(": missing"):
            raise FileNotFoundError(str(e)) from None
        raise ValueError(str(e)) from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: not a JSON object")
    return doc


def check_codecs(meta: JSONObject, where: str, compressors: tuple[str, ...] = ()) -> None:
    """Refuse (ValueError) an array document whose codecs are not the writer's: ``bytes``
    (little or big endian), then at most one of ``compressors``, no storage transformer. Read
    before the zarr library sees the array: an unknown codec could inflate a small chunk
    without bound, and zarr's failures leave its event loop's tasks behind at exit."""
    codecs = meta.get("codecs")
    if not (isinstance(codecs, list) and codecs and all(isinstance(c, dict) for c in codecs)):
        raise ValueError(f"{where}: malformed array metadata (codecs)")
    names = [c.get("name") for c in codecs]
    first = codecs[0].get("configuration") or {}
    bad = [n for i, n in enumerate(names) if not (n == "bytes" if i == 0 else (i == 1 and n in compressors))]
    if bad:
        shown = bad[0] if isinstance(bad[0], str) else json.dumps(bad[0])
        raise ValueError(
            f"{where}: codec {shown[:40]!r} is not one ooc-dem writes "
            f"(bytes{''.join(f', {c}' for c in compressors)}; refused)"
        )
    if not (
        isinstance(first, dict) and set(first) <= {"endian"} and first.get("endian", "little") in ("little", "big")
    ):
        raise ValueError(f"{where}: malformed bytes codec configuration")
    if meta.get("storage_transformers"):
        raise ValueError(f"{where}: storage transformers are not written by ooc-dem (refused)")


def _member(adir: str, meta: JSONObject, name: str) -> _Member:
    """Parse array metadata; `raw` is the chunk path for an uncompressed one-chunk array in
    native byte order (what the writer produces), else None (read through zarr)."""
    shape, dtype = meta.get("shape"), meta.get("data_type")
    if not (isinstance(shape, list) and all(type(v) is int and v >= 0 for v in shape) and isinstance(dtype, str)):
        raise ValueError(f"{adir}: malformed array metadata (shape, data_type)")
    check_codecs(meta, adir)
    shape = tuple(shape)
    dtype = np.dtype(dtype)
    raw: str | None = None
    codecs = meta.get("codecs") or []
    grid = meta.get("chunk_grid") or {}
    cke = meta.get("chunk_key_encoding") or {}
    if (
        len(codecs) == 1
        and codecs[0].get("name") == "bytes"
        and (codecs[0].get("configuration") or {}).get("endian", sys.byteorder) == sys.byteorder
        and dtype.isnative
        and not meta.get("storage_transformers")
        and grid.get("name") == "regular"
        and tuple(grid.get("configuration", {}).get("chunk_shape", ())) == tuple(max(1, v) for v in shape)
        and cke.get("name") == "default"
        and (cke.get("configuration") or {}).get("separator", "/") == "/"
        and len(shape) >= 1
    ):
        raw = os.path.join(adir, "c", *(["0"] * len(shape)))
    return _Member(shape, dtype, raw, name)


def recorded_step(root: JSONObject) -> object:
    """The step a writer recorded in an epoch's root group document (None: none)."""
    attributes = root.get("attributes")
    return attributes.get("step") if isinstance(attributes, dict) else None


class Reader:
    """Reads an epoch's zarr v3 hierarchy from its metadata documents directly (plain JSON
    files), falling back to the zarr library for arrays not in the writer's simple form."""

    def __init__(self, path: str) -> None:
        self.path = path
        if not os.path.isdir(path):
            raise FileNotFoundError(f"{path}: epoch directory missing")
        self._real = os.path.realpath(path)
        meta = _read_json(os.path.join(path, "zarr.json"))
        if meta.get("zarr_format") != 3 or meta.get("node_type") != "group":
            raise ValueError(f"{path}: not a zarr v3 group")
        self._root_step = recorded_step(meta)
        self._zroot: zarr.Group | None = None
        self._groups: dict[str, tuple[JSONObject, dict[str, _Member]] | None] = {}
        self._touched: set[str] = set()

    def _zarr_root(self) -> zarr.Group:
        if self._zroot is None:
            import zarr
            from zarr.storage import LocalStore

            self._zroot = zarr.open_group(
                store=LocalStore(self.path, read_only=True), mode="r", zarr_format=3, use_consolidated=False
            )
        return self._zroot

    def _group_meta(self, group: str) -> tuple[JSONObject, dict[str, _Member]] | None:
        """(group attributes, name -> _Member), read once; None if no such group."""
        if group not in self._groups:
            gdir = os.path.join(self.path, *group.split("/"))
            try:
                meta = _read_json(os.path.join(gdir, "zarr.json"))
            except FileNotFoundError:
                meta = None
            if not isinstance(meta, dict) or meta.get("node_type") != "group":
                self._groups[group] = None
                return None
            if os.path.realpath(gdir) != os.path.join(self._real, *group.split("/")):
                raise ValueError(f"{gdir}: reached through a symbolic link (not allowed)")
            members: dict[str, _Member] = {}
            for name in sorted(os.listdir(gdir)):
                adir = os.path.join(gdir, name)
                mpath = os.path.join(adir, "zarr.json")
                if os.path.islink(adir) or not os.path.isfile(mpath) or os.path.islink(mpath):
                    continue
                am = _read_json(mpath)
                if am.get("node_type") == "array":
                    m = _member(adir, am, f"{group}/{name}")
                    if m.raw is not None and os.path.realpath(m.raw) != os.path.join(
                        self._real, os.path.relpath(m.raw, self.path)
                    ):
                        raise ValueError(f"{m.raw}: reached through a symbolic link (not allowed)")
                    members[name] = m
            attributes = meta.get("attributes") or {}
            if not isinstance(attributes, dict):
                raise ValueError(f"{gdir}: malformed group attributes")
            self._groups[group] = (attributes, members)
        return self._groups[group]

    def _members(self, group: str) -> dict[str, _Member] | None:
        gm = self._group_meta(group)
        return None if gm is None else gm[1]

    def root_step(self) -> object:
        """The step the epoch's writer recorded in its root attributes (None: none)."""
        return self._root_step

    def has_group(self, group: str) -> bool:
        return self._group_meta(group) is not None

    def array_info(self, group: str, name: str) -> tuple[tuple[int, ...], np.dtype[Any]] | None:
        a = (self._members(group) or {}).get(name)
        return None if a is None else (tuple(a.shape), a.dtype)

    def attrs_json(self, group: str) -> str | None:
        gm = self._group_meta(group)
        if gm is None:
            raise KeyError(f"group {group} missing")
        return attrs_text(gm[0].get(ATTRS_KEY))

    def _array(self, group: str, name: str) -> tuple[_Member, str | None]:
        """(member, chunk file path or None if the raw fast path does not apply)."""
        a = (self._members(group) or {}).get(name)
        if a is None:
            raise KeyError(f"array {group}/{name} missing")
        return a, a.raw

    def _via_zarr(self, a: _Member) -> AnyArray:
        import zarr

        node = self._zarr_root()[a.name]
        if not isinstance(node, zarr.Array):
            raise ValueError(f"{self.path}: {a.name}: not an array")
        return node

    def _pread(self, raw: str, what: str, out: NDArray[Any], offset: int) -> None:
        try:
            fd = open_regular(raw)  # a regular file (no link, no FIFO): reads are bounded
        except StoreError as e:
            if str(e).endswith(": missing"):
                raise StoreError(f"{raw}: chunk file missing ({what})") from None
            raise
        try:
            pread_into(fd, out, offset, raw)
        finally:
            os.close(fd)
        self._touched.add(raw)

    def read_full(self, group: str, name: str, shape: tuple[int, ...], dtype: DTypeLike) -> NDArray[Any]:
        a, raw = self._array(group, name)
        if tuple(a.shape) != tuple(shape):
            raise ValueError(f"array {group}/{name} has shape {a.shape}, manifest says {tuple(shape)}")
        out = np.empty(shape, dtype=dtype)
        if out.size == 0:
            return out
        if raw is not None:
            self._pread(raw, f"{group}/{name}", out, 0)
        else:
            out[...] = self._via_zarr(a)[...]
        return out

    def read_range(self, group: str, name: str, start: int, stop: int, out: NDArray[Any]) -> None:
        if stop <= start or out.size == 0:
            return
        a, raw = self._array(group, name)
        if raw is not None:
            row_bytes = out.dtype.itemsize * int(np.prod(a.shape[1:], dtype=np.int64))
            self._pread(raw, f"{group}/{name}", out, start * row_bytes)  # only the asked rows
        else:
            out[...] = self._via_zarr(a)[start:stop]

    def after_read(self) -> None:
        for p in self._touched:
            drop_page_cache(p)
        self._touched.clear()

    def close(self) -> None:
        self._groups.clear()
        self._zroot = None
