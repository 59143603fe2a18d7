"""ooc-dem epoch store: named numpy arrays + JSON attributes per sub-domain, per epoch.

This package knows nothing of physics. A *store* holds committed *epochs* (a step
number each); an epoch holds one group per sub-domain (``write_domain``) plus one
``globals`` group. Backends: ``"hdf5"`` (h5py), ``"zarr"`` (zarr v3) and
``"memory"`` (dicts, same semantics); all pass tests/test_store_conformance.py.

On-disk layout
--------------
::

    STORE/
      MANIFEST.json      {"format": "ooc-dem-store", "format_version": 1, "backend": "hdf5"|"zarr",
                          "meta": {...}, "created_at": iso time,
                          "current": EPOCH|null, "previous": EPOCH|null}
                          EPOCH = {"step": int,
                                   "path": "epochs/e000000001234.h5",
                                   "files": [{"path": rel, "size": int, "sha256": hex}, ...],
                                   "domains": {"0": {"n": rows, "arrays": {name: [shape, dtype]}}, ...},
                                   "globals": {"arrays": {name: [shape, dtype]}} | null,
                                   "committed_at": iso time}
      epochs/
        e000000001234.h5        HDF5: one file per epoch, written as e000000001234.h5.tmp-<pid>
                                and renamed when complete; groups /domains/d0000, /domains/d0001 ...
                                (one per sub-domain, arrays as contiguous datasets, attrs as the JSON
                                string attribute "ooc_dem_attrs"), /globals (same form).
        e000000001234.zarr/     zarr v3 LocalStore: groups domains/d0000 ..., globals (attrs as the
                                JSON string attribute "ooc_dem_attrs"); written as a .tmp-<pid>
                                directory renamed when complete; one uncompressed chunk per array
                                (chunks = full shape), no sharding, no consolidated metadata.

* Paths in the manifest are relative to STORE and use "/". "files" lists the HDF5
  file, or every file under the zarr directory individually; "sha256" is over the
  file's bytes. The memory backend lists one pseudo-file per array (checksum over
  the array bytes) and per group's attrs.
* "n" is the row count of the domain's first array (0 if none); arrays of one
  domain may have different lengths (e.g. CSR pointers and entries).
* dtype is numpy's ``dtype.str`` (e.g. "<f8"); arrays are stored in native byte
  order (non-native input is converted), any numeric kind (bool, int, uint, float,
  complex), domain arrays have >= 1 dimension, any length including 0.
* Array names: letters, digits and ``_ . + -``, not starting with ``.`` or ``-``.
* Attrs and meta are JSON (numpy scalars/arrays are converted); they come back as
  ``json.loads(json.dumps(x))`` (tuples become lists, keys become strings).
* A step rewritten while the manifest still names an epoch of that step (resuming
  after a fallback) gets the name ``e<step>.r1.h5`` (``.r2`` ...): a committed epoch
  is never modified in place.

Commit protocol
---------------
``begin_epoch(step)`` writes everything under temporary names (``*.tmp-<pid>``);
``commit()`` closes and checksums the epoch, renames it into place, then writes
``MANIFEST.json.tmp`` and ``os.replace``s it over ``MANIFEST.json`` - the only
commit point. The new manifest names the new epoch as current and the old current
as previous; epochs older than that are deleted only after the new manifest is in
place. ``commit(durable=True)`` also fsyncs the data files, the manifest and the
directories. Without it a power loss may lose recent commits (a crashed *process*
loses nothing that was committed).

A step must be newer than the previous epoch; a step <= current (resuming after a
fallback) replaces the current epoch and keeps the previous one.

Recovery
--------
``open_store(path, repair=True)`` deletes ``MANIFEST.json.tmp``, ``*.tmp-*`` and
epoch files the manifest does not name (listed in ``store.repaired``); it assumes a
single writer per store. A missing or unparsable manifest is a StoreError (nothing
is deleted). ``read_epoch()`` verifies the current epoch's sizes and sha256 (once per
Store object; epochs this object committed count as verified) and falls back to the
previous epoch if they fail, recording a message in ``store.warnings``; if both
fail it raises StoreError naming the file and the problem. Wrong data is never
returned silently.

Errors
------
Every failure is a ``StoreError`` with a one-line message naming the path and the
problem. Running out of space / file-size limit while writing (ENOSPC, EFBIG,
EDQUOT, also as reported by HDF5) gives "...: disk full or file too large (...)";
the partial epoch is removed and the committed epochs are untouched. (The caller
should ignore SIGXFSZ so that a file-size limit is an error, not a kill.)

Page cache
----------
Written files are dropped from the page cache after writing (``drop_page_cache``:
``posix_fadvise(POSIX_FADV_DONTNEED)``, which starts write-back of dirty pages and
drops clean ones), and files are dropped after each ``read_domain`` /
``read_globals``, so memory measurements are not inflated by cached store data.

Partial reads
-------------
``read_domain(d, rows=...)`` reads only the requested rows: HDF5 datasets are
contiguous (hyperslab reads); zarr chunks are uncompressed, so rows are read with
``pread`` at their offset in the chunk file. Index arrays are read in windows of
nearby rows (at most 1 MiB wide), never the whole array.
"""

from ._util import StoreError, drop_page_cache
from .store import (BACKENDS, EpochInfo, EpochReader, EpochWriter, Leftover, Store, create_store,
                    drop_memory_store, open_store)

__all__ = [
    "BACKENDS",
    "EpochInfo",
    "EpochReader",
    "EpochWriter",
    "Leftover",
    "Store",
    "StoreError",
    "create_store",
    "drop_memory_store",
    "drop_page_cache",
    "open_store",
]
