"""ooc-dem epoch store: named numpy arrays + JSON attributes per sub-domain, per epoch.

This package knows nothing of physics. A *store* holds committed *epochs* (a step
number each); an epoch holds one group per sub-domain (``write_domain``) plus one
``globals`` group. Backends: ``"hdf5"`` (h5py), ``"zarr"`` (zarr v3) and
``"memory"`` (dicts, same semantics); all pass tests/test_store_conformance.py.

On-disk layout
--------------
::

    STORE/
      .ooc-dem.lock      the write lock: flock(LOCK_EX) by the one process writing the store,
                         which writes its pid into it (for messages); never deleted (see Writers)
      MANIFEST.json      {"format": "ooc-dem-store", "format_version": 2, "backend": "hdf5"|"zarr",
                          "meta": {...}, "created_at": iso time,
                          "current": EPOCH|null, "previous": EPOCH|null}
                          EPOCH = {"step": int,
                                   "path": "epochs/e000000001234.h5",
                                   "files": [{"path": rel, "size": int, "xxh3_128": hex}, ...],
                                   "domains": {"0": {"n": rows, "arrays": {name: [shape, dtype]}}, ...},
                                   "globals": {"arrays": {name: [shape, dtype]}} | null,
                                   "committed_at": iso time,
                                   "format_version": int}   (the version the epoch was written
                                                            in; absent: the manifest's)
      epochs/
        e000000001234.h5        HDF5: one file per epoch, written as e000000001234.h5.tmp-<pid>
                                and renamed when complete; groups /domains/d0000, /domains/d0001 ...
                                (one per sub-domain, arrays as contiguous datasets, attrs as the JSON
                                string attribute "ooc_dem_attrs"), /globals (same form).
        e000000001234.zip       zarr v3: the epoch's hierarchy (the keys of a LocalStore:
                                zarr.json, domains/d0000/zarr.json, domains/d0000/pos/zarr.json,
                                domains/d0000/pos/c/0/0 ...) in one zip archive (zarr's ZipStore),
                                every entry stored; written as a .tmp-<pid> file renamed when
                                complete; one uncompressed chunk per array, or with compression
                                (zstd / blosc codecs) chunks of ~1 MiB of rows. Attrs as the JSON
                                string attribute "ooc_dem_attrs". One file, not ~20 files and
                                directories per group: creating and deleting them dominated sweeps.
        e000000001234.zarr/     the zarr layout of earlier versions (a LocalStore directory, one
                                uncompressed chunk per array): still read, no longer written.

* ``compression`` (manifest key, absent = none): ``COMPRESSIONS[backend]``, chosen at
  create_store and used for every epoch written; each epoch entry names its own. The
  bytes-fit-in-files check allows a compressed epoch at most 64x its files' bytes.
* ``format_version``: this code writes 2 and reads 1 and 2. The package never interprets
  array names; the version (``EpochReader.format_version``: the epoch entry's, else the
  manifest's) tells the application how to read them (ooc_dem.model.checkpoint.open_epoch reads
  a version-1 epoch's 2D component arrays as version 2). A commit into a version-1 store
  moves the manifest to version 2 and stamps the older entries with their version.
* Paths in the manifest are relative to STORE and use "/". "files" lists the HDF5
  file, or every file under the zarr directory individually; the checksum is over the
  file's bytes: "xxh3_128" (XXH3, 128 bits, 32 hex digits) as written now, or "sha256"
  (64 hex digits) as older stores recorded it, which is still checked. It detects torn,
  truncated or altered files; it is no authenticity check (the manifest that holds it
  lives in the same store), so the fast non-cryptographic hash serves. The memory backend lists one pseudo-file per array (checksum over
  the array bytes) and per group's attrs, under the same "epochs/<name>.mem" paths.
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

A store is untrusted input
-------------------------
A store may come from someone else; nothing in it may make this package read, write or
delete outside it (``_confine`` is the one place that resolves its paths). open_store
validates the whole manifest first and refuses, with a one-line StoreError, anything
that is not exactly what this package writes:

* types and ranges everywhere: steps, sizes, shapes are non-negative ints below 2**63
  (not bools, floats or strings), a file has exactly one checksum, in its lowercase hex length, domain keys are
  canonical ids ("0", "17"; not "01", "-1", " 1"), dtypes are numeric numpy ``dtype.str``
  strings, array names as above, the arrays' bytes fit in the epoch's recorded files;
* paths: a str, relative, "/"-separated, no "."/".."/empty part, no NUL, only the
  characters our names use; an epoch path is exactly ``epochs/<name>`` with <name> an
  epoch name of the store's backend *for that step*; file entries are the epoch file
  itself (HDF5: exactly that one) or strictly below it (zarr: at least one, and the
  regular files found under the epoch directory must be exactly the listed ones);
  an epoch resolves (symbolic links followed) inside the real ``epochs/``, which must be
  a real directory, not a symbolic link;
* current and previous have different paths and previous.step < current.step;
* MANIFEST.json is a regular file (not followed if a link) of at most 64 MiB, valid
  JSON nested at most 100 levels (checked with fstat before it is read).

Reading and checking: only regular files are read (O_NOFOLLOW | O_NONBLOCK, fstat), their
size is compared with the manifest before reading and no more than that is ever read (a
FIFO or /dev/zero cannot hang a read); a symbolic link or special file inside an epoch,
or a file reached through one, is a verification problem of that epoch; HDF5 soft and
external links and external or virtual datasets are not followed. Deleting: prune
deletes only the previous epoch the manifest names (never the current one, the manifest,
``epochs/`` or the store); repair deletes only direct children of the real ``epochs/``
whose names are ours (``e<step>[.rN].<ext>.tmp-<pid>`` and epoch names the manifest does
not name) and ``MANIFEST.json.tmp``, unlinking symbolic links rather than following them.

Writers
-------
One process writes a store at a time. ``create_store`` and ``open_store(repair=True)``
take an exclusive ``flock`` on ``STORE/.ooc-dem.lock`` (refused with "another process is
writing this store (pid N)"; a second writer in the same process is refused too) and
hold it until ``Store.close()`` or the process's death (the kernel drops it: a SIGKILLed
run leaves no stale lock). ``open_store(repair=False)`` opens read-only: no lock,
nothing deleted, begin_epoch/prune refused; it works while a run writes (verify, list,
hash, inspect, export). The lock file is never deleted: another process may hold it
open, and a new file under the same name would exclude nobody. Memory stores live in
one process and take no lock.

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
``open_store(path, repair=True)`` takes the write lock, then deletes
``MANIFEST.json.tmp``, ``*.tmp-<pid>`` and epoch files the manifest does not name
(listed in ``store.repaired``; ``Store.leftovers()`` lists them without deleting). A
missing, unparsable or invalid manifest is a StoreError (nothing is deleted or written). ``read_epoch()`` verifies the current epoch's sizes and checksums (once per
Store object; epochs this object committed count as verified) and falls back to the
previous epoch if they fail, recording a message in ``store.warnings``; if both
fail it raises StoreError naming the file and the problem. Wrong data is never
returned silently.

Queries for tools
-----------------
``Store.list_epochs()`` (EpochInfo: role, step, path, size, domains, size problems; no
data read), ``Store.verify(step=None)`` (a list of Problem: the one-line message as a str,
``.step`` the epoch it is in), ``Store.leftovers()`` (Leftover: path, writer pid, whether it runs),
``Store.live_writers()`` (pids of the lock holder and of running temporaries' writers)
and ``Store.manifest(fresh=False)`` (a copy of the validated manifest; fresh=True reads
the store's current one again) are what ``ooc-dem checkpoint`` uses; nothing outside
this package reads MANIFEST.json itself.

Errors
------
Every failure is a ``StoreError`` with a one-line message naming the path and the
problem. Running out of space / file-size limit while writing (ENOSPC, EFBIG,
EDQUOT, also as reported by HDF5) gives "...: disk full or file too large (...)";
the partial epoch is removed and the committed epochs are untouched. (The caller
should ignore SIGXFSZ so that a file-size limit is an error, not a kill.)

Page cache
----------
Written files are dropped from the page cache once committed (``drop_page_cache``:
``posix_fadvise(POSIX_FADV_DONTNEED)``, which starts write-back of dirty pages and
drops clean ones); an HDF5 epoch's groups are written back as they are written
(``start_writeback``: sync_file_range, so dirty pages never pile up) and dropped after
the commit has read the file's checksum from the cache. Files are dropped after each
``read_domain`` / ``read_globals``, so memory measurements are not inflated by cached
store data.

Partial reads
-------------
``read_domain(d, rows=...)`` reads only the requested rows: HDF5 datasets are
contiguous (hyperslab reads; compressed: the chunks touched); uncompressed zarr chunks are
read with ``pread`` at the rows' offset in the archive, compressed ones chunk by chunk (a
group spanning at most 1 MiB is read in one pread when first used).

Disk space
----------
``begin_epoch`` first calls ``Store.check_room``: the free space of the store's file
system, and the file-size limit for a one-file epoch, must hold about the current
epoch's size (+1/64 + 4 KiB), else "disk full or file too large" before anything is
written (and before a sweep is computed). Index arrays are read in windows of
nearby rows (at most 1 MiB wide), never the whole array.
"""

from ._manifest import BACKENDS, COMPRESSIONS
from ._util import StoreError, drop_page_cache
from .epoch import EpochReader, EpochWriter
from .parts import write_part
from .opening import create_store, drop_memory_store, open_store, store_owns
from .store import EpochInfo, Leftover, Problem, Store

__all__ = [
    "BACKENDS",
    "COMPRESSIONS",
    "EpochInfo",
    "EpochReader",
    "EpochWriter",
    "Leftover",
    "Problem",
    "Store",
    "StoreError",
    "create_store",
    "drop_memory_store",
    "drop_page_cache",
    "open_store",
    "store_owns",
    "write_part",
]
