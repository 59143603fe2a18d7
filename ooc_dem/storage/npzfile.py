"""Members of an ``.npz`` archive read as untrusted input: every member's size is read from
its zip entry and ``.npy`` header and compared with what is expected before anything is
allocated or inflated (a 4 MB archive may declare 4 GB of deflated zeros); never unpickled.
It imports nothing of the package, so that every layer may read its npz files with it."""

from __future__ import annotations

import os
import zipfile
import zlib
from collections.abc import Mapping
from typing import IO, Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

# a row shape: one entry per dimension after the rows, a size or a range of allowed sizes
RowShape: TypeAlias = "tuple[int | range, ...]"


def _npy_header(f: IO[bytes], where: str, error: type[Exception]) -> tuple[tuple[int, ...], np.dtype[Any], int]:
    """(shape, dtype, header bytes) of the .npy stream f, from its header only."""
    fmt = np.lib.format
    version = fmt.read_magic(f)
    if version == (1, 0):
        shape, fortran, dtype = fmt.read_array_header_1_0(f)
    elif version == (2, 0):
        shape, fortran, dtype = fmt.read_array_header_2_0(f)
    else:
        raise error(f"{where}: .npy format version {version} (not what ooc-dem writes)")
    if dtype.hasobject or dtype.fields is not None or fortran:
        raise error(
            f"{where}: dtype {dtype.str} (an object, structured or Fortran-order array "
            f"is not what ooc-dem writes; refused)"
        )
    return tuple(shape), dtype, f.tell()


def _row_fits(shape: tuple[int, ...], tail: RowShape) -> bool:
    return len(shape) == 1 + len(tail) and all(
        s in t if isinstance(t, range) else s == t for s, t in zip(shape[1:], tail)
    )


def _dim(t: int | range) -> str:
    return f"{t.start}..{t.stop - 1}" if isinstance(t, range) else str(t)


def read_npz_members(
    path: str | os.PathLike[str],
    want: Mapping[str, tuple[RowShape | None, str]],
    n: int | None,
    error: type[Exception],
    n_from: str = "",
) -> dict[str, NDArray[Any]]:
    """The members ``want`` names of the npz archive ``path``: name -> (row shape, a tuple, for
    an array of n rows, where a ``range`` admits any size in it; None for one number; the
    allowed dtype kinds, e.g. "iuf"). Each member's declared shape must be that (``n``: the
    rows expected, None when unknown; ``n_from`` says where that number comes from) and
    its bytes those of its zip entry (stored, within the archive, when ``n`` is unknown), and
    all of them must fit in a quarter of this machine's memory, before any is read. Anything
    else raises ``error`` (one line)."""
    import psutil

    found: dict[str, NDArray[Any]] = {}
    budget: int = psutil.virtual_memory().total // 4
    size = os.stat(path).st_size
    try:
        with zipfile.ZipFile(path) as zf:
            for k, (tail, kinds) in want.items():
                where = f"{path}: {k!r}"
                try:
                    zi = zf.getinfo(f"{k}.npy")
                except KeyError:
                    raise error(f"{path}: no array {k!r}") from None
                if zi.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                    raise error(f"{where}: zip compression {zi.compress_type} (refused)")
                if n is None and (
                    zi.compress_type != zipfile.ZIP_STORED
                    or zi.compress_size != zi.file_size
                    or zi.header_offset + zi.compress_size > size
                ):
                    # no expected length: only the archive's own bytes bound the member's
                    raise error(f"{where}: a compressed or truncated member of unknown length (refused)")
                with zf.open(zi) as f:
                    shape, dtype, head = _npy_header(f, where, error)
                ok = shape == () if tail is None else _row_fits(shape, tail)
                if not ok or dtype.kind not in kinds or dtype.itemsize > 8:
                    raise error(
                        f"{where}: shape {shape} dtype {dtype.str}: expected "
                        + ("a number" if tail is None else f"(rows{''.join(f', {_dim(t)}' for t in tail)})")
                        + f" of kind {kinds!r}"
                    )
                if tail is not None and n is not None and shape[0] != n:
                    raise error(f"{where}: {shape[0]} rows, expected {n}" + (f" ({n_from})" if n_from else ""))
                nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
                if zi.file_size != head + nbytes:
                    raise error(f"{where}: declares {nbytes} bytes of data, its zip entry holds {zi.file_size - head}")
                budget -= nbytes
                if budget < 0:
                    raise error(f"{where}: {nbytes} bytes, beyond this machine's memory")
                with zf.open(zi) as f:
                    found[k] = np.lib.format.read_array(f, allow_pickle=False)
    except error:
        raise
    except _UNREADABLE as e:
        raise _unreadable(path, e, error) from None
    return found


_UNREADABLE = (ValueError, OSError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, NotImplementedError)


def _unreadable(path: str | os.PathLike[str], e: Exception, error: type[Exception]) -> Exception:
    return error(f"{path}: not a readable npz archive ({' '.join(str(e).split())[:160]})")


def npz_member_names(path: str | os.PathLike[str], error: type[Exception]) -> list[str]:
    """The array names of the npz archive ``path`` (from its zip directory; nothing inflated)."""
    try:
        with zipfile.ZipFile(path) as zf:
            return [m[:-4] for m in zf.namelist() if m.endswith(".npy")]
    except _UNREADABLE as e:
        raise _unreadable(path, e, error) from None
