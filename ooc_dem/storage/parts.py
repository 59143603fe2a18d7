"""An epoch written by several processes (e.g. MPI ranks): each writes its part with
``write_part`` (phase 1); the store's owner adds the parts to its epoch
(``EpochWriter.add_part``) and publishes them with it (``EpochWriter.commit``, phase 2)."""

from __future__ import annotations

import operator
from collections.abc import Iterable, Mapping

from ._manifest import EXT
from ._util import (
    EPOCH_DIR,
    MAX_PARTS,
    JSONObject,
    StoreError,
    StrPath,
    array_meta,
    domain_group,
    file_entries,
    part_basename,
    prepare_arrays,
    remove_path,
    to_json,
    write_error,
)
from ._util import show as _show
from . import _confine
from .opening import open_store


def write_part(
    path: StrPath,
    step: int,
    basename: str,
    part: int,
    domains: Iterable[tuple[int, Mapping[str, object], Mapping[str, object] | None]],
    durable: bool = False,
) -> JSONObject:
    """Phase 1 of an epoch written by several processes (e.g. MPI ranks): this process
    writes part ``part`` (>= 1) of epoch ``basename`` (``EpochWriter.basename`` of the writer
    the store's owner holds) under a temporary name in the store's epochs/ directory, from
    ``domains`` (an iterable of (d, arrays, attrs)), finished (``durable``: flushed to disk)
    and checksummed. It returns what the owner passes to ``EpochWriter.add_part``; nothing
    of it is visible until the owner commits (phase 2), and an abort removes it.

    The store is opened read-only (its manifest validated, no lock: the owner holds it);
    on any failure the temporary is removed and StoreError says why."""
    store = open_store(path, repair=False)
    try:
        place = store._place
        if place.is_memory:
            raise StoreError(f"{store.path}: a memory store keeps no parts (one process holds it)")
        if not (type(part) is int and 1 <= part <= MAX_PARTS):
            raise StoreError(f"{store.path}: part {_show(part)} is not a part number (1 to {MAX_PARTS})")
        name = part_basename(basename, part)
        _confine.epoch_path(f"{EPOCH_DIR}/{name}", EXT[store.backend], step, f"{store.path}: epoch {step}", part=part)
        place.resolver.check_epoch_dir()
        tmp = place.tmp_name(name)
        remove_path(tmp)
        try:
            w = place.fmt.Writer(tmp, step, store.compression)
        except (OSError, RuntimeError) as e:
            remove_path(tmp)
            raise write_error(tmp, e) from e
        metas: dict[str, JSONObject] = {}
        try:
            for d, arrays, attrs in domains:
                d = operator.index(d)
                where = f"{store.path}: epoch {step} domain {d}"
                if d < 0 or str(d) in metas:
                    raise StoreError(f"{where}: not a new domain id >= 0")
                arrs = prepare_arrays(arrays, where, min_ndim=1)
                w.write_group(domain_group(d), arrs, to_json(dict(attrs or {}), f"{where} attrs"))
                first = next(iter(arrs.values()), None)
                metas[str(d)] = {"n": 0 if first is None else int(first.shape[0]), "arrays": array_meta(arrs)}
            inner = w.finish(durable)
        except BaseException as e:
            try:
                w.abort()
            except Exception:  # noqa: BLE001
                pass
            remove_path(tmp)
            if isinstance(e, (OSError, RuntimeError)) and not isinstance(e, StoreError):
                raise write_error(tmp, e) from e
            raise
        rel = f"{EPOCH_DIR}/{name}"
        files = file_entries(rel, inner)
        return {"part": part, "path": rel, "tmp": tmp, "files": files, "domains": metas}
    finally:
        store.close()
