"""zarr v3 epoch format: one LocalStore directory per epoch, one group per sub-domain,
one uncompressed chunk per array (chunks = full shape), no sharding, no consolidated metadata."""

from __future__ import annotations

import os
import sys

import numpy as np

from ._util import (ATTRS_KEY, FORMAT, StoreError, drop_page_cache, fsync_tree, pread_into,
                    remove_path, sha256_file)

EXT = "zarr"
IS_DIR = True


def _zarr():
    import zarr
    from zarr.storage import LocalStore
    return zarr, LocalStore


def walk_files(root: str) -> list[str]:
    """Relative paths ('/'-separated) of every file under root, sorted."""
    out = []
    for d, _dirs, files in os.walk(root):
        for f in files:
            out.append(os.path.relpath(os.path.join(d, f), root).replace(os.sep, "/"))
    return sorted(out)


class Writer:
    """Writes one epoch into the directory `path` (a temporary name, renamed by the caller)."""

    def __init__(self, path: str, step: int):
        zarr, LocalStore = _zarr()
        self.path = path
        self._hashed: dict[str, tuple[int, int, str]] = {}   # rel -> (size, mtime_ns, sha)
        self.root = zarr.open_group(store=LocalStore(path), mode="w-", zarr_format=3,
                                    attributes={"ooc_dem_format": FORMAT, "step": int(step)})
        self._groups = {"": self.root, "domains": self.root.create_group("domains")}

    def _group(self, group: str, attrs_json: str):
        parent, _, leaf = group.rpartition("/")
        return self._groups[parent].create_group(leaf, attributes={ATTRS_KEY: attrs_json})

    def write_group(self, group: str, arrays: dict[str, np.ndarray], attrs_json: str) -> None:
        g = self._group(group, attrs_json)
        for name, a in arrays.items():
            arr = g.create_array(
                name, shape=a.shape, dtype=a.dtype,
                chunks=tuple(max(1, s) for s in a.shape),  # one chunk per array
                shards=None, filters=None, compressors=None, fill_value=0,
                config={"write_empty_chunks": True})         # every non-empty array has its chunk file
            if a.size:
                arr[...] = a
        # hash the group's files while they are hot, then drop them from the page cache
        gdir = os.path.join(self.path, *group.split("/"))
        for rel in walk_files(gdir):
            self._hash(f"{group}/{rel}")

    def _hash(self, rel: str) -> str:
        p = os.path.join(self.path, *rel.split("/"))
        st = os.stat(p)
        h = self._hashed.get(rel)
        if h is None or h[0] != st.st_size or h[1] != st.st_mtime_ns:
            size, sha = sha256_file(p)
            h = (size, st.st_mtime_ns, sha)
            self._hashed[rel] = h
        return h[2]

    def finish(self, durable: bool) -> list[tuple[str, int, str]]:
        files = []
        for rel in walk_files(self.path):
            sha = self._hash(rel)
            files.append((rel, self._hashed[rel][0], sha))
        if durable:
            fsync_tree(self.path)
        return files

    def abort(self) -> None:
        remove_path(self.path)


class Reader:
    def __init__(self, path: str):
        zarr, LocalStore = _zarr()
        self.path = path
        if not os.path.isdir(path):
            raise FileNotFoundError(f"{path}: epoch directory missing")
        self.root = zarr.open_group(store=LocalStore(path, read_only=True), mode="r",
                                    zarr_format=3, use_consolidated=False)
        self._arrays: dict[tuple[str, str], tuple] = {}
        self._groups: dict[str, dict | None] = {}
        self._touched: set[str] = set()

    def _members(self, group: str):
        """name -> zarr.Array of a group (fetched concurrently, once), or None if no such group."""
        if group not in self._groups:
            zarr, _ = _zarr()
            try:
                g = self.root[group]
            except (KeyError, FileNotFoundError):
                g = None
            self._groups[group] = dict(g.arrays()) if isinstance(g, zarr.Group) else None
        return self._groups[group]

    def has_group(self, group: str) -> bool:
        return self._members(group) is not None

    def array_info(self, group: str, name: str):
        a = (self._members(group) or {}).get(name)
        return None if a is None else (tuple(a.shape), a.dtype)

    def attrs_json(self, group: str):
        return self.root[group].attrs.get(ATTRS_KEY)

    def _array(self, group, name):
        """(zarr array, chunk file path or None if the raw fast path does not apply)."""
        key = (group, name)
        hit = self._arrays.get(key)
        if hit is None:
            from zarr.codecs import BytesCodec
            a = (self._members(group) or {}).get(name)
            if a is None:
                raise KeyError(f"array {group}/{name} missing")
            md = a.metadata
            raw = None
            codecs = tuple(md.codecs)
            endian = getattr(codecs[0], "endian", None) if len(codecs) == 1 else None
            endian = getattr(endian, "value", endian)
            if (len(codecs) == 1 and isinstance(codecs[0], BytesCodec)
                    and endian in (None, sys.byteorder) and a.dtype.isnative
                    and tuple(md.chunk_grid.chunk_shape) == tuple(max(1, s) for s in a.shape)):
                ck = md.chunk_key_encoding.encode_chunk_key((0,) * a.ndim)
                raw = os.path.join(self.path, *group.split("/"), name, *ck.split("/"))
            hit = (a, raw)
            self._arrays[key] = hit
        return hit

    def _pread(self, raw, what, out, offset):
        try:
            fd = os.open(raw, os.O_RDONLY)
        except FileNotFoundError:
            raise StoreError(f"{raw}: chunk file missing ({what})") from None
        try:
            pread_into(fd, out, offset, raw)
        finally:
            os.close(fd)
        self._touched.add(raw)

    def read_full(self, group, name, shape, dtype) -> np.ndarray:
        a, raw = self._array(group, name)
        if tuple(a.shape) != tuple(shape):
            raise ValueError(f"array {group}/{name} has shape {a.shape}, manifest says {tuple(shape)}")
        out = np.empty(shape, dtype=dtype)
        if out.size == 0:
            return out
        if raw is not None:
            self._pread(raw, f"{group}/{name}", out, 0)
        else:
            out[...] = a[...]
        return out

    def read_range(self, group, name, start, stop, out) -> None:
        if stop <= start or out.size == 0:
            return
        a, raw = self._array(group, name)
        if raw is not None:
            row_bytes = out.dtype.itemsize * int(np.prod(a.shape[1:], dtype=np.int64))
            self._pread(raw, f"{group}/{name}", out, start * row_bytes)   # only the asked rows
        else:
            out[...] = a[start:stop]

    def after_read(self) -> None:
        for p in self._touched:
            drop_page_cache(p)
        self._touched.clear()

    def close(self) -> None:
        self._arrays.clear()
        self._groups.clear()
        self.root = None
