"""HDF5 epoch format: one file per epoch, one group per sub-domain, contiguous datasets."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import DTypeLike, NDArray

from . import writeguard
from ._util import ATTRS_KEY, FORMAT, attrs_text, drop_page_cache, file_digest, fsync_path, remove_path, start_writeback

if TYPE_CHECKING:
    import h5py

EXT = "h5"
IS_DIR = False
_RDCC_NBYTES = 1 << 20
# compressed datasets are chunked in about this many bytes of rows (a row range decompresses
# only the chunks it touches; the chunk cache above holds one)
CHUNK_BYTES = 1 << 20
# name -> h5py create_dataset keywords (built-in filters only: every h5py reads them)
FILTERS: dict[str, dict[str, Any]] = {
    "gzip": {"compression": "gzip", "compression_opts": 4, "shuffle": True},
    "lzf": {"compression": "lzf", "shuffle": True},
}


def _h5py() -> Any:  # h5py: no type information
    import h5py

    return h5py


# HDF5's metadata cache (object headers, group B-trees) grows with the objects touched in a
# file, up to 32 MB by default: ~22 MB once an epoch holds ~300 groups, for the writer and
# again for the reader (measured), so an out-of-core run's RSS rose with D. Groups are written
# and read one after another, so a small cache loses nothing.
_MDC_BYTES = 1 << 20


# Files are opened with no file locking (stores live on network/scratch filesystems), a small
# chunk cache and no SWMR.


def _small_metadata_cache(f: h5py.File) -> h5py.File:
    cfg = f.id.get_mdc_config()
    cfg.set_initial_size = True
    cfg.initial_size = cfg.max_size = _MDC_BYTES
    cfg.min_size = min(cfg.min_size, _MDC_BYTES)
    f.id.set_mdc_config(cfg)
    return f


def _open_read(path: str) -> h5py.File:
    return _small_metadata_cache(_h5py().File(path, "r", locking=False, rdcc_nbytes=_RDCC_NBYTES))


def _create(path: str) -> tuple[h5py.File, writeguard.GuardedFile]:
    """Create `path` ("w-") through a write guard (see writeguard: a failed write must never
    reach HDF5, which crashes the process after one)."""
    f, guard = writeguard.create_h5(path, locking=False, rdcc_nbytes=_RDCC_NBYTES)
    return _small_metadata_cache(f), guard


class Writer:
    """Writes one epoch into the file `path` (a temporary name, renamed by the caller)."""

    def __init__(self, path: str, step: int, compression: str | None = None) -> None:
        if compression is not None and compression not in FILTERS:
            raise ValueError(f"unknown HDF5 compression {compression!r}")
        self.path = path
        self.filters = None if compression is None else FILTERS[compression]
        self.f: h5py.File | None = None
        self.f, self._guard = _create(path)
        self.f.attrs["ooc_dem_format"] = FORMAT
        self.f.attrs["step"] = np.int64(step)
        self.f.create_group("domains")

    def _file(self) -> h5py.File:
        if self.f is None:
            raise ValueError(f"{self.path}: the epoch file is closed")
        return self.f

    def _check_room(self, nbytes: int) -> None:
        """Refuse a group that cannot fit before writing it (an OSError, which the store
        turns into a one-line StoreError); a failure during the write is the guard's."""
        import os

        need = int(nbytes) + 8192  # datasets plus headroom for HDF5 object headers
        writeguard.check_room(self.path, need, os.path.getsize(self.path) + need)

    def write_group(self, group: str, arrays: dict[str, NDArray[Any]], attrs_json: str) -> None:
        f = self._file()
        f.flush()
        self._check_room(sum(np.asarray(a).nbytes for a in arrays.values()) + len(attrs_json))
        g = f.create_group(group)
        g.attrs[ATTRS_KEY] = attrs_json
        for name, a in arrays.items():
            if self.filters is None or a.ndim == 0 or a.size == 0:
                g.create_dataset(name, data=a)  # contiguous layout: row ranges are read in place
                continue
            row = a.dtype.itemsize * int(np.prod(a.shape[1:], dtype=np.int64))
            rows = int(min(a.shape[0], max(1, CHUNK_BYTES // max(1, row))))
            g.create_dataset(name, data=a, chunks=(rows,) + a.shape[1:], **self.filters)
        f.flush()
        self._guard.check()
        # written back now, dropped once the commit has read the file's checksum (finish)
        start_writeback(self.path)

    def finish(self, durable: bool) -> list[tuple[str, int, str]]:
        """Close the file and return [(relpath within epoch, size, digest)] ("" = the file itself)."""
        f, self.f = self.f, None
        writeguard.close_h5(f, self._guard)
        if durable:
            fsync_path(self.path)
        size, digest = file_digest(self.path)
        return [("", size, digest)]

    def abort(self) -> None:
        f, self.f = self.f, None
        if f is not None:
            try:
                writeguard.close_h5(f, self._guard)
            except Exception:  # noqa: BLE001 - the file is being thrown away
                pass
        remove_path(self.path)


class Reader:
    def __init__(self, path: str) -> None:
        self.path = path
        self._objs: dict[str, Any] = {}  # path -> object of one group, checked once (see _get)
        self._objs_group: str | None = None
        self.f: h5py.File | None = _open_read(path)

    def _get(self, path: str) -> Any:
        """The object at `path`, following hard links only: a soft or external link, or a
        dataset whose data lives in other files (external storage, virtual datasets), would
        make a hostile epoch file read outside the store."""
        if path in self._objs:
            return self._objs[path]
        # objects of one group at a time: an open dataset holds ~40 kB of HDF5 buffers once
        # read (measured), so keeping every group's open grew with D, not with the slab
        group = "/".join(path.split("/")[:2])
        if group != self._objs_group:
            self._objs.clear()
            self._objs_group = group
        h5py = _h5py()
        obj = self.f
        for part in path.split("/"):
            if not isinstance(obj, h5py.Group):
                return None
            link = obj.get(part, getlink=True)
            if link is None:
                return None
            if not isinstance(link, h5py.HardLink):
                raise ValueError(f"/{path}: is a {type(link).__name__} (only hard links are read)")
            obj = obj[part]
        if isinstance(obj, h5py.Dataset) and (obj.external or obj.is_virtual):
            raise ValueError(f"/{path}: data stored outside the epoch file (not read)")
        self._objs[path] = obj
        return obj

    def root_step(self) -> object:
        """The step the file's writer recorded in its root attributes (None: none)."""
        if self.f is None:
            raise ValueError(f"{self.path}: the epoch file is closed")
        v = self.f.attrs.get("step")
        return v.item() if isinstance(v, np.generic) else v

    def has_group(self, group: str) -> bool:
        return isinstance(self._get(group), _h5py().Group)

    def array_info(self, group: str, name: str) -> tuple[tuple[int, ...], np.dtype[Any]] | None:
        obj = self._get(f"{group}/{name}")
        if not isinstance(obj, _h5py().Dataset):
            return None
        return tuple(obj.shape), obj.dtype

    def attrs_json(self, group: str) -> str | None:
        g = self._get(group)
        if g is None:
            raise KeyError(f"group /{group} missing")
        return attrs_text(g.attrs.get(ATTRS_KEY))

    def _ds(self, group: str, name: str) -> Any:
        obj = self._get(f"{group}/{name}")
        if not isinstance(obj, _h5py().Dataset):
            raise KeyError(f"dataset /{group}/{name} missing")
        return obj

    def read_full(self, group: str, name: str, shape: tuple[int, ...], dtype: DTypeLike) -> NDArray[Any]:
        ds = self._ds(group, name)
        if tuple(ds.shape) != tuple(shape):
            raise ValueError(f"dataset /{group}/{name} has shape {ds.shape}, manifest says {tuple(shape)}")
        out = np.empty(shape, dtype=dtype)
        if out.ndim == 0:
            out[()] = ds[()]
        elif out.size:
            ds.read_direct(out)
        return out

    def read_range(self, group: str, name: str, start: int, stop: int, out: NDArray[Any]) -> None:
        if stop > start:
            self._ds(group, name).read_direct(out, np.s_[start:stop], np.s_[0 : stop - start])

    def after_read(self) -> None:
        drop_page_cache(self.path)

    def close(self) -> None:
        self._objs.clear()
        f, self.f = self.f, None
        if f is not None:
            f.close()
