"""zarr v3 epoch format, one file per epoch: the epoch's zarr hierarchy in a zip archive.

``zarr.open_group(zarr.storage.ZipStore("epochs/e000000001234.zip", mode="r"), mode="r")``
reads it: the archive holds exactly the keys a zarr v3 LocalStore directory would hold
(``zarr.json``, ``domains/d0000/zarr.json``, ``domains/d0000/pos/zarr.json``,
``domains/d0000/pos/c/0/0`` ...), every entry stored (zip compression "stored"), so an
uncompressed chunk's bytes sit at a fixed offset of the file and a row range is one pread.

Why one file: on the machines this runs on, creating and above all deleting a file or a
directory costs about 2 ms each (journal), and the directory layout (``_zarr``) made
~240 objects per epoch of 6 groups and deleted as many: ~1 s per sweep at K = 1. An epoch
file is now created, renamed and deleted like an HDF5 epoch.

Compression (optional, per store): the zarr codecs ``zstd`` or ``blosc`` (lz4, byte
shuffle) after the ``bytes`` codec, chunks of about ``CHUNK_BYTES`` of rows, so a row range
decodes only the chunks it touches. The archive is written as a stream (zip data
descriptors, no seeking back), so its checksum is computed as it is written.
"""

from __future__ import annotations

import io
import json
import os
import struct
import sys
import zipfile
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import DTypeLike, NDArray

from ._confine import open_regular
from ._util import ATTRS_KEY, FORMAT, JSONObject, attrs_text, drop_page_cache, new_digest, pread_into, remove_path
from ._zarr import check_codecs, recorded_step

if TYPE_CHECKING:
    import zarr
    from _typeshed import ReadableBuffer
    from zarr.types import AnyArray

EXT = "zip"
IS_DIR = False
# compressed arrays are cut into chunks of about this many bytes of rows (a strip read
# decodes only the chunks it needs; the codecs work well on blocks of this size)
CHUNK_BYTES = 1 << 20
# a zarr metadata document of ours is a few hundred bytes; bigger ones are not read
_MAX_DOC_BYTES = 1 << 20
# a group whose entries span at most this many bytes is read in one pread when first used
# (its documents, zip headers and chunks then cost one read, not ~50 small ones: reads after
# the page cache was dropped are latency-bound); at most _SPAN_CACHE bytes are kept
_SPAN_BYTES = 1 << 20
_SPAN_CACHE = 8 << 20
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # fixed: the same state gives the same bytes
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
_LOCAL_HEADER = struct.Struct("<4s2B4HL2L2H")  # zip local file header, 30 bytes


class _Codec(Protocol):
    """A numcodecs codec (what this module calls of one)."""

    def encode(self, buf: NDArray[Any], /) -> bytes: ...

    def decode(self, buf: bytes, /, out: NDArray[Any]) -> object: ...


def _numcodecs() -> Any:  # numcodecs: no type information
    import numcodecs

    return numcodecs


def _zstd_doc(itemsize: int) -> JSONObject:
    return {"name": "zstd", "configuration": {"level": 3, "checksum": False}}


def _blosc_doc(itemsize: int) -> JSONObject:
    return {
        "name": "blosc",
        "configuration": {"typesize": int(itemsize), "cname": "lz4", "clevel": 5, "shuffle": "shuffle", "blocksize": 0},
    }


# name -> (zarr v3 codec document after "bytes", for an itemsize; numcodecs codec factory)
CODECS: dict[str, tuple[Callable[[int], JSONObject], Callable[[], _Codec]]] = {
    "zstd": (_zstd_doc, lambda: _numcodecs().Zstd(level=3)),
    "blosc": (_blosc_doc, lambda: _numcodecs().Blosc(cname="lz4", clevel=5, shuffle=_numcodecs().Blosc.SHUFFLE)),
}


def _fill(dtype: np.dtype[Any]) -> bool | int | float | list[float]:
    if dtype.kind == "b":
        return False
    if dtype.kind == "c":
        return [0.0, 0.0]
    return 0.0 if dtype.kind == "f" else 0


def _chunk_key(prefix: str, index: int, ndim: int) -> str:
    return f"{prefix}/c" if ndim == 0 else f"{prefix}/c/" + "/".join([str(index)] + ["0"] * (ndim - 1))


def _chunk_rows(a: NDArray[Any], compressed: bool) -> int:
    """Rows per chunk: all of them uncompressed (one chunk: row ranges by offset), else
    about CHUNK_BYTES' worth."""
    if a.ndim == 0:
        return 1
    n: int = max(1, a.shape[0])
    if not compressed:
        return n
    row = max(1, a.dtype.itemsize * int(np.prod(a.shape[1:], dtype=np.int64)))
    return int(min(n, max(1, CHUNK_BYTES // row)))


def _array_doc(a: NDArray[Any], rows: int, codec: str | None) -> bytes:
    """The zarr v3 array metadata zarr 3.x writes for this array, chunking and codecs."""
    bytes_codec: JSONObject = {"name": "bytes"}
    if a.dtype.itemsize > 1:
        bytes_codec["configuration"] = {"endian": "little"}
    codecs = [bytes_codec]
    if codec is not None:
        codecs.append(CODECS[codec][0](a.dtype.itemsize))
    chunk_shape = [] if a.ndim == 0 else [rows] + [max(1, s) for s in a.shape[1:]]
    meta = {
        "shape": list(a.shape),
        "data_type": a.dtype.name,
        "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": chunk_shape}},
        "chunk_key_encoding": {"name": "default", "configuration": {"separator": "/"}},
        "fill_value": _fill(a.dtype),
        "codecs": codecs,
        "attributes": {},
        "zarr_format": 3,
        "node_type": "array",
        "storage_transformers": [],
    }
    return json.dumps(meta, indent=2).encode()


def _group_doc(attributes: JSONObject) -> bytes:
    return json.dumps({"attributes": attributes, "zarr_format": 3, "node_type": "group"}, indent=2).encode()


class _HashingStream:
    """The epoch file as zipfile sees it: write-only, never seeked (so zipfile writes data
    descriptors instead of patching headers), hashed as written."""

    def __init__(self, f: io.BufferedWriter) -> None:
        self._f = f
        self.digest = new_digest()
        self.pos = 0

    def write(self, b: ReadableBuffer) -> int:
        n = self._f.write(b)
        self.digest.update(b)
        self.pos += len(b) if isinstance(b, (bytes, bytearray)) else memoryview(b).nbytes
        return n

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        self._f.flush()

    def close(self) -> None:
        """Nothing: the epoch file is the Writer's to close (zipfile never closes a stream it
        was given; its type asks for the method)."""


class Writer:
    """Writes one epoch into the file `path` (a temporary name, renamed by the caller)."""

    def __init__(self, path: str, step: int, compression: str | None = None) -> None:
        if compression is not None and compression not in CODECS:
            raise ValueError(f"unknown zarr compression {compression!r}")
        self.path = path
        self.codec = compression
        self._encoder = None if compression is None else CODECS[compression][1]()
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o644)
        self._f = open(fd, "wb")
        try:
            self._stream = _HashingStream(self._f)
            self._zip: zipfile.ZipFile | None = zipfile.ZipFile(self._stream, "w", zipfile.ZIP_STORED, allowZip64=True)
            self._put("zarr.json", _group_doc({"ooc_dem_format": FORMAT, "step": int(step)}))
            self._put("domains/zarr.json", _group_doc({}))
        except BaseException:
            self._f.close()
            raise

    def _zipfile(self) -> zipfile.ZipFile:
        if self._zip is None:
            raise ValueError(f"{self.path}: the epoch archive is closed")
        return self._zip

    def _put(self, key: str, data: bytes | NDArray[Any]) -> None:
        zi = zipfile.ZipInfo(key, date_time=_ZIP_TIME)
        zi.compress_type = zipfile.ZIP_STORED
        zi.external_attr = 0o644 << 16
        mv = data.data.cast("B") if not isinstance(data, bytes) else data
        # the size is known up front: zipfile then chooses zip64 headers only when needed
        zi.file_size = len(mv)
        with self._zipfile().open(zi, "w", force_zip64=len(mv) > 0x7FFFFFFF) as dest:
            dest.write(mv)

    def write_group(self, group: str, arrays: dict[str, NDArray[Any]], attrs_json: str) -> None:
        self._put(f"{group}/zarr.json", _group_doc({ATTRS_KEY: attrs_json}))
        for name, a in arrays.items():
            self._write_array(f"{group}/{name}", a)
        self._f.flush()
        drop_page_cache(self.path)  # starts write-back, drops clean pages

    def _write_array(self, prefix: str, a: NDArray[Any]) -> None:
        encoder = self._encoder
        rows = _chunk_rows(a, encoder is not None)
        self._put(f"{prefix}/zarr.json", _array_doc(a, rows, self.codec))
        if a.size == 0:
            return  # zarr: an absent chunk is the fill value, nothing to store
        data = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))
        if a.ndim == 0:
            data = data.reshape(1)
        if encoder is None:
            self._put(_chunk_key(prefix, 0, a.ndim), data)
            return
        n = data.shape[0]
        for i, lo in enumerate(range(0, n, rows)):
            part = data[lo : lo + rows]
            if len(part) < rows and a.ndim:  # zarr stores edge chunks whole, padded with fill
                pad = np.zeros((rows,) + data.shape[1:], data.dtype)
                pad[: len(part)] = part
                part = pad
            self._put(_chunk_key(prefix, i, a.ndim), encoder.encode(part))

    def finish(self, durable: bool) -> list[tuple[str, int, str]]:
        """Close the archive and return [("", size, digest)] (the epoch is this one file)."""
        zf, self._zip = self._zipfile(), None
        zf.close()
        self._f.flush()
        if durable:
            os.fsync(self._f.fileno())
        self._f.close()
        drop_page_cache(self.path)
        return [("", self._stream.pos, self._stream.digest.hexdigest())]

    def abort(self) -> None:
        zf, self._zip = getattr(self, "_zip", None), None
        try:
            if zf is not None:
                zf.fp = None  # do not write a central directory into a discarded file
            self._f.close()
        except Exception:  # noqa: BLE001 - the file is being thrown away
            pass
        remove_path(self.path)


# ============================================================================ reading


def _zstd_content_size(buf: bytes) -> int | None:
    """The decompressed size a zstd frame header declares (None: not declared or no frame)."""
    if len(buf) < 6 or buf[:4] != b"\x28\xb5\x2f\xfd":
        return None
    fhd = buf[4]
    fcs_flag, single, did_flag = fhd >> 6, (fhd >> 5) & 1, fhd & 3
    pos = 5 + (0 if single else 1) + (0, 1, 2, 4)[did_flag]
    size = (1 if single else 0, 2, 4, 8)[fcs_flag]
    if size == 0 or len(buf) < pos + size:
        return None
    v = int.from_bytes(buf[pos : pos + size], "little")
    return v + 256 if size == 2 else v


def _blosc_size(buf: bytes) -> int | None:
    return int.from_bytes(buf[4:8], "little") if len(buf) >= 16 else None


class _Member:
    """An array of an epoch group: shape, dtype, and how its chunks are read directly:
    ``codec`` None (one uncompressed chunk at a file offset) or "zstd"/"blosc" (chunks of
    ``rows`` rows); ``direct`` False: read through the zarr library."""

    __slots__ = ("shape", "dtype", "direct", "codec", "rows", "key")

    def __init__(
        self, shape: tuple[int, ...], dtype: np.dtype[Any], direct: bool, codec: str | None, rows: int, key: str
    ) -> None:
        self.shape, self.dtype, self.direct, self.codec, self.rows, self.key = shape, dtype, direct, codec, rows, key


def _member(key: str, meta: JSONObject) -> _Member:
    shape, data_type = meta.get("shape"), meta.get("data_type")
    if not (isinstance(shape, list) and all(type(v) is int and v >= 0 for v in shape) and isinstance(data_type, str)):
        raise ValueError(f"{key}: malformed array metadata (shape, data_type)")
    shape = tuple(shape)
    try:
        dtype = np.dtype(data_type)
    except TypeError:
        raise ValueError(f"{key}: unknown data_type {data_type[:40]!r}") from None
    check_codecs(meta, key, tuple(CODECS))
    codecs = meta["codecs"]
    grid = meta.get("chunk_grid") or {}
    cke = meta.get("chunk_key_encoding") or {}
    chunk_shape = (
        grid.get("configuration", {}).get("chunk_shape", None) if isinstance(grid.get("configuration"), dict) else None
    )
    simple = (
        isinstance(codecs, list)
        and codecs
        and isinstance(codecs[0], dict)
        and codecs[0].get("name") == "bytes"
        and (
            (codecs[0].get("configuration") or {}).get("endian", sys.byteorder) == sys.byteorder or dtype.itemsize == 1
        )
        and dtype.isnative
        and not meta.get("storage_transformers")
        and grid.get("name") == "regular"
        and isinstance(chunk_shape, list)
        and all(type(v) is int and v >= 1 for v in chunk_shape)
        and len(chunk_shape) == len(shape)
        and tuple(chunk_shape[1:]) == tuple(max(1, v) for v in shape[1:])
        and cke.get("name") == "default"
        and (cke.get("configuration") or {}).get("separator", "/") == "/"
    )
    if len(codecs) == 2 and not simple:
        # compressed chunks are decoded here only, where a chunk's declared size is checked
        # before it is inflated; zarr would inflate any size
        raise ValueError(f"{key}: compressed array not in the writer's chunking (refused)")
    if not simple or not isinstance(chunk_shape, list):
        return _Member(shape, dtype, False, None, 0, key)
    rows = chunk_shape[0] if shape else 1
    if len(codecs) == 1 and (not shape or rows == max(1, shape[0])):
        return _Member(shape, dtype, True, None, rows, key)
    if len(codecs) == 2:
        return _Member(shape, dtype, True, codecs[1]["name"], rows, key)
    return _Member(shape, dtype, False, None, 0, key)


class Reader:
    """Reads an epoch archive: its central directory and metadata documents directly, chunk
    bytes by pread at their offsets; arrays not in the writer's forms through zarr."""

    def __init__(self, path: str) -> None:
        self.path = path
        self._fd = open_regular(path)  # a regular file (not a link, FIFO...): reads are bounded
        try:
            self._size = os.fstat(self._fd).st_size
            try:
                with zipfile.ZipFile(os.fdopen(os.dup(self._fd), "rb")) as zf:
                    infos = zf.infolist()
                    central = int(zf.start_dir)
            except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError) as e:
                raise ValueError(f"{path}: not a readable zip archive ({e})") from None
            self._entries: dict[str, zipfile.ZipInfo] = {}
            for zi in infos:
                if zi.filename in self._entries:
                    raise ValueError(f"{path}: key {zi.filename[:80]!r} stored twice")
                self._entries[zi.filename] = zi
            self._offsets: dict[str, int] = {}
            # where each entry ends (the next entry's header, or the central directory)
            starts = sorted({zi.header_offset for zi in infos} | {central})
            nxt = {a: b for a, b in zip(starts, starts[1:])}
            self._ends = {zi.filename: nxt.get(zi.header_offset, central) for zi in infos}
            self._spans: dict[str, tuple[int, NDArray[np.uint8]]] = {}
            # group -> names of its members (keys "<group>/<name>/zarr.json"), built once
            self._children: dict[str, list[str]] = {}
            for key in self._entries:
                if key.endswith("/zarr.json"):
                    group, _, name = key[: -len("/zarr.json")].rpartition("/")
                    if name:
                        self._children.setdefault(group, []).append(name)
            meta = self._doc("zarr.json")
            if meta is None or meta.get("zarr_format") != 3 or meta.get("node_type") != "group":
                raise ValueError(f"{path}: not a zarr v3 group")
            self._root_step = recorded_step(meta)
        except BaseException:
            os.close(self._fd)
            raise
        self._zroot: zarr.Group | None = None
        self._groups: dict[str, tuple[JSONObject, dict[str, _Member]] | None] = {}
        self._decoders: dict[str, _Codec] = {}

    # ------------------------------------------------------------------ entries
    def _data_offset(self, key: str) -> tuple[int, int]:
        """(offset, size) of a stored entry's bytes in the file, checked against its header."""
        zi = self._entries.get(key)
        if zi is None:
            raise KeyError(key)
        off = self._offsets.get(key)
        if off is None:
            if zi.compress_type != zipfile.ZIP_STORED:
                raise ValueError(
                    f"{self.path}: {key}: zip entry is compressed by the archive (not what ooc-dem or zarr write)"
                )
            head = bytearray(_LOCAL_HEADER.size)
            self._pread(np.frombuffer(head, np.uint8), zi.header_offset, self.path)
            fields = _LOCAL_HEADER.unpack(bytes(head))
            if fields[0] != b"PK\x03\x04":
                raise ValueError(f"{self.path}: {key}: bad local header")
            off = zi.header_offset + _LOCAL_HEADER.size + fields[-2] + fields[-1]
            if zi.file_size != zi.compress_size or off + zi.file_size > self._size:
                raise ValueError(f"{self.path}: {key}: entry runs past the end of the file")
            self._offsets[key] = off
        return off, zi.file_size

    def _bytes(self, key: str, limit: int) -> bytes:
        off, size = self._data_offset(key)
        if size > limit:
            raise ValueError(f"{self.path}: {key}: {size} bytes, more than the {limit} allowed")
        buf = np.empty(size, np.uint8)
        self._pread(buf, off, f"{self.path}: {key}")
        return buf.tobytes()

    def _pread(self, out: NDArray[Any], offset: int, what: str) -> None:
        """Bytes at `offset` into `out`: from a group span read before if it holds them."""
        n = out.nbytes
        for lo, buf in self._spans.values():
            if lo <= offset and offset + n <= lo + len(buf):
                out.reshape(-1).view(np.uint8)[:] = buf[offset - lo : offset - lo + n]
                return
        pread_into(self._fd, out, offset, what)

    def _load_span(self, group: str) -> None:
        """Read a small group's entries (documents, headers, chunks) in one pread."""
        prefix = f"{group}/"
        keys = [k for k in self._entries if k.startswith(prefix)]
        if not keys or group in self._spans:
            return
        lo = min(self._entries[k].header_offset for k in keys)
        hi = min(max(self._ends[k] for k in keys), self._size)
        if not 0 < hi - lo <= _SPAN_BYTES:
            return
        while self._spans and sum(len(b) for _, b in self._spans.values()) + (hi - lo) > _SPAN_CACHE:
            self._spans.pop(next(iter(self._spans)))
        buf = np.empty(hi - lo, np.uint8)
        pread_into(self._fd, buf, lo, f"{self.path}: {group}")
        self._spans[group] = (lo, buf)

    def _doc(self, key: str) -> JSONObject | None:
        if key not in self._entries:
            return None
        try:
            doc = json.loads(self._bytes(key, _MAX_DOC_BYTES))
        except (ValueError, RecursionError) as e:
            raise ValueError(f"{self.path}: {key}: not valid JSON ({str(e)[:100]})") from None
        if not isinstance(doc, dict):
            raise ValueError(f"{self.path}: {key}: not a JSON object")
        return doc

    # ------------------------------------------------------------------ hierarchy
    def _group_meta(self, group: str) -> tuple[JSONObject, dict[str, _Member]] | None:
        """(group attributes, name -> _Member), read once; None if no such group."""
        if group not in self._groups:
            if f"{group}/zarr.json" in self._entries:
                self._load_span(group)
            meta = self._doc(f"{group}/zarr.json")
            if meta is None or meta.get("node_type") != "group":
                self._groups[group] = None
                return None
            members: dict[str, _Member] = {}
            for name in sorted(self._children.get(group, ())):
                am = self._doc(f"{group}/{name}/zarr.json")
                if am is not None and am.get("node_type") == "array":
                    members[name] = _member(f"{group}/{name}", am)
            attributes = meta.get("attributes") or {}
            if not isinstance(attributes, dict):
                raise ValueError(f"{self.path}: {group}: malformed group attributes")
            self._groups[group] = (attributes, members)
        return self._groups[group]

    def root_step(self) -> object:
        """The step the epoch's writer recorded in its root attributes (None: none)."""
        return self._root_step

    def has_group(self, group: str) -> bool:
        return self._group_meta(group) is not None

    def array_info(self, group: str, name: str) -> tuple[tuple[int, ...], np.dtype[Any]] | None:
        gm = self._group_meta(group)
        a = None if gm is None else gm[1].get(name)
        return None if a is None else (tuple(a.shape), a.dtype)

    def attrs_json(self, group: str) -> str | None:
        gm = self._group_meta(group)
        if gm is None:
            raise KeyError(f"group {group} missing")
        return attrs_text(gm[0].get(ATTRS_KEY))

    def _array(self, group: str, name: str) -> _Member:
        gm = self._group_meta(group)
        a = None if gm is None else gm[1].get(name)
        if a is None:
            raise KeyError(f"array {group}/{name} missing")
        return a

    def _via_zarr(self, a: _Member) -> AnyArray:
        if a.codec is not None:  # bounded decoding only (_read_rows)
            raise ValueError(f"{self.path}: {a.key}: compressed array of dtype {a.dtype.str}, not the one expected")
        if self._zroot is None:
            import zarr
            from zarr.storage import ZipStore

            self._zroot = zarr.open_group(
                store=ZipStore(self.path, mode="r"), mode="r", zarr_format=3, use_consolidated=False
            )
        node = self._zroot[a.key]
        if not isinstance(node, zarr.Array):
            raise ValueError(f"{self.path}: {a.key}: not an array")
        return node

    # ------------------------------------------------------------------ data
    def _read_rows(self, a: _Member, start: int, stop: int, out: NDArray[Any]) -> None:
        """Rows [start, stop) of a directly readable array into `out` (C-contiguous)."""
        ndim = len(a.shape)
        if a.codec is None:
            key = _chunk_key(a.key, 0, ndim)
            try:
                off, size = self._data_offset(key)
            except KeyError:
                raise ValueError(f"{self.path}: {key}: chunk missing") from None
            full = int(np.prod(a.shape, dtype=np.int64)) * a.dtype.itemsize
            if size != full:
                raise ValueError(f"{self.path}: {key}: {size} bytes, expected {full}")
            row = full // max(1, a.shape[0]) if ndim else full
            self._pread(out, off + start * row, f"{self.path}: {key}")
            return
        dec = self._decoders.get(a.codec)
        if dec is None:
            dec = self._decoders[a.codec] = CODECS[a.codec][1]()
        rows = a.rows
        tail = tuple(a.shape[1:])
        buf = np.empty((rows,) + tail if ndim else (1,), a.dtype)
        flat_out = out.reshape((-1,) + tail) if ndim else out.reshape(1)
        for i in range(start // rows, (stop - 1) // rows + 1):
            key = _chunk_key(a.key, i, ndim)
            try:
                _off, size = self._data_offset(key)
            except KeyError:
                raise ValueError(f"{self.path}: {key}: chunk missing") from None
            enc = self._bytes(key, buf.nbytes + (1 << 16))  # never more than a chunk's worth
            declared = _zstd_content_size(enc) if a.codec == "zstd" else _blosc_size(enc)
            if declared != buf.nbytes:
                raise ValueError(f"{self.path}: {key}: chunk decodes to {declared} bytes, expected {buf.nbytes}")
            try:
                dec.decode(enc, out=buf)
            except (RuntimeError, ValueError) as e:
                raise ValueError(f"{self.path}: {key}: cannot decode ({e})") from None
            lo, hi = max(start, i * rows), min(stop, (i + 1) * rows)
            flat_out[lo - start : hi - start] = buf[lo - i * rows : hi - i * rows]

    def read_full(self, group: str, name: str, shape: tuple[int, ...], dtype: DTypeLike) -> NDArray[Any]:
        a = self._array(group, name)
        if tuple(a.shape) != tuple(shape):
            raise ValueError(f"array {group}/{name} has shape {a.shape}, manifest says {tuple(shape)}")
        out = np.empty(shape, dtype=dtype)
        if out.size == 0:
            return out
        if a.direct and a.dtype == out.dtype:
            self._read_rows(a, 0, shape[0] if shape else 1, out)
        else:
            out[...] = self._via_zarr(a)[...]
        return out

    def read_range(self, group: str, name: str, start: int, stop: int, out: NDArray[Any]) -> None:
        if stop <= start or out.size == 0:
            return
        a = self._array(group, name)
        if a.direct and a.dtype == out.dtype:
            self._read_rows(a, start, stop, out)  # only the asked rows (or their chunks)
        else:
            out[...] = self._via_zarr(a)[start:stop]

    def after_read(self) -> None:
        if hasattr(os, "posix_fadvise"):
            try:
                os.posix_fadvise(self._fd, 0, 0, os.POSIX_FADV_DONTNEED)
            except OSError:
                pass

    def close(self) -> None:
        self._groups.clear()
        self._spans.clear()
        self._zroot = None
        fd, self._fd = self._fd, -1
        if fd >= 0:
            os.close(fd)
