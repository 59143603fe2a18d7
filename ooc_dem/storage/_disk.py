"""Manifest and epoch files of a store directory (HDF5 or zarr).

Every path taken from a manifest goes through ``_confine`` (see there); every file read
is a regular file opened without following symbolic links, read no further than allowed.
"""

from __future__ import annotations

import os
import stat
from typing import Literal

from . import _hdf5, _zarr, _zarr_zip
from ._confine import Resolver, digest_regular, read_regular
from ._util import (
    EPOCH_DIR,
    EPOCH_NAME_RE,
    FORMAT,
    LOCK_FILE,
    MANIFEST,
    MANIFEST_TMP,
    MAX_MANIFEST_BYTES,
    TMP_NAME_RE,
    EpochFormat,
    FormatReader,
    FormatWriter,
    JSONObject,
    StoreError,
    drop_page_cache,
    file_checksum,
    file_entries,
    fsync_path,
    parse_json,
    remove_path,
    to_json,
    write_error,
)

# what each backend writes, and every epoch format it reads (by the epoch name's extension):
# zarr epochs were directories before (``_zarr``, ~20 files and directories per group),
# one zip archive per epoch since (``_zarr_zip``); both are read
FORMATS: dict[str, EpochFormat] = {"hdf5": _hdf5, "zarr": _zarr_zip}
READ_FORMATS: dict[str, dict[str, EpochFormat]] = {
    "hdf5": {_hdf5.EXT: _hdf5},
    "zarr": {_zarr_zip.EXT: _zarr_zip, _zarr.EXT: _zarr},
}
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)


class ManifestUnreadable(StoreError):
    """MANIFEST.json is missing, not a regular file, too big or not valid JSON."""

    def __init__(self, mpath: str, reason: str) -> None:
        self.reason = reason
        super().__init__(f"{mpath}: MANIFEST.json missing or unreadable ({reason})")


def read_manifest_file(mpath: str) -> object:
    """The parsed JSON of a MANIFEST.json: a regular file of at most MAX_MANIFEST_BYTES."""
    try:
        return parse_json(read_regular(mpath, MAX_MANIFEST_BYTES), mpath)
    except StoreError as e:  # messages are "<mpath>: <reason>"
        raise ManifestUnreadable(mpath, str(e)[len(mpath) + 2 :]) from None


def _is_real_dir(path: str) -> bool:
    try:
        return stat.S_ISDIR(os.lstat(path).st_mode)
    except OSError:
        return False


def classify(root: str) -> tuple[str, object]:
    """Look at a path: ("absent"|"empty"|"foreign"|"damaged"|"store", manifest-or-reason).

    The lock file alone does not make a directory non-empty (it is ours, and kept)."""
    if not os.path.lexists(root):
        return "absent", None
    if not os.path.isdir(root):
        return "foreign", "it is not a directory"
    entries = [n for n in os.listdir(root) if n != LOCK_FILE]
    if not entries:
        return "empty", None
    mpath = os.path.join(root, MANIFEST)
    edir = os.path.join(root, EPOCH_DIR)
    looks_ours = _is_real_dir(edir) and all(EPOCH_NAME_RE.match(n) or TMP_NAME_RE.match(n) for n in os.listdir(edir))
    if os.path.lexists(mpath):
        try:
            m = read_manifest_file(mpath)
        except ManifestUnreadable as e:
            if looks_ours:
                return "damaged", e.reason
            return "foreign", "MANIFEST.json is not an ooc-dem manifest"
        if isinstance(m, dict) and m.get("format") == FORMAT:
            return "store", m
        if looks_ours and not isinstance(m, dict):
            return "damaged", "manifest is not a JSON object"
        return "foreign", "MANIFEST.json is not an ooc-dem manifest"
    if looks_ours or (_is_real_dir(edir) and os.path.lexists(os.path.join(root, MANIFEST_TMP))):
        return "damaged", "MANIFEST.json missing"
    return "foreign", "no MANIFEST.json"


def wipe(root: str) -> None:
    """Remove a store's own files (manifest, its temporary, epochs) - nothing else.

    The lock file stays: the caller holds it (see _lock)."""
    for n in (MANIFEST, MANIFEST_TMP):
        remove_path(os.path.join(root, n))
    remove_path(os.path.join(root, EPOCH_DIR))  # a symbolic link is unlinked, not followed


def _walk_epoch(base: str) -> tuple[dict[str, str], list[str]]:
    """Regular files under an epoch directory (rel "/"-path -> path) and problems (symbolic
    links, other special files), without following any symbolic link."""
    files: dict[str, str] = {}
    problems: list[str] = []
    stack = [("", base)]
    while stack:
        rel, d = stack.pop()
        try:
            with os.scandir(d) as it:
                items = sorted(it, key=lambda x: x.name)
        except OSError as e:
            problems.append(f"{d}: unreadable directory ({e.strerror or e})")
            continue
        for x in items:
            r = f"{rel}/{x.name}" if rel else x.name
            if x.is_symlink():
                problems.append(f"{x.path}: symbolic link inside the epoch (not allowed)")
            elif x.is_dir(follow_symlinks=False):
                stack.append((r, x.path))
            elif x.is_file(follow_symlinks=False):
                files[r] = x.path
            else:
                problems.append(f"{x.path}: not a regular file")
    return files, problems


class Place:
    is_memory: Literal[False] = False

    def __init__(self, root: str, backend: str) -> None:
        self.root = root
        self.backend = backend
        self.fmt = FORMATS[backend]
        self._read_fmts = READ_FORMATS[backend]
        self.edir = os.path.join(root, EPOCH_DIR)
        self.mpath = os.path.join(root, MANIFEST)
        self.resolver = Resolver(root)

    # ------------------------------------------------------------------ manifest
    def read_manifest(self) -> object:
        return read_manifest_file(self.mpath)

    def write_manifest(self, m: JSONObject, durable: bool = False) -> None:
        data = to_json(m, f"{self.mpath}: manifest", indent=1).encode()
        tmp = os.path.join(self.root, MANIFEST_TMP)
        try:
            remove_path(tmp)  # exclusive create below: never written through a planted link
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o644)
            with open(fd, "wb") as f:
                f.write(data)
                f.flush()
                if durable:
                    os.fsync(f.fileno())
            os.replace(tmp, self.mpath)  # the commit point
            if durable:
                fsync_path(self.root)
        except OSError as e:
            remove_path(tmp)
            raise write_error(self.mpath, e) from e
        drop_page_cache(self.mpath)

    # ------------------------------------------------------------------ epochs
    def tmp_name(self, basename: str) -> str:
        return os.path.join(self.edir, f"{basename}.tmp-{os.getpid()}")

    def fmt_of(self, path: str) -> EpochFormat:
        """The format module of an epoch (by its name's extension; the writer's if unknown)."""
        return self._read_fmts.get(path.rpartition(".")[2], self.fmt)

    def new_writer(self, step: int, basename: str, compression: str | None = None) -> FormatWriter:
        tmp = self.tmp_name(basename)
        remove_path(tmp)  # leftover of an earlier process with our pid
        os.makedirs(self.edir, exist_ok=True)
        return self.fmt.Writer(tmp, step, compression)

    def publish(self, writer: FormatWriter, basename: str, durable: bool) -> tuple[str, list[JSONObject]]:
        """Finish the temporary epoch, rename it into place; return (rel path, file list)."""
        tmp = self.tmp_name(basename)
        try:
            inner = writer.finish(durable)
        except (OSError, RuntimeError) as e:
            writer.abort()
            raise write_error(tmp, e) from e
        final = os.path.join(self.edir, basename)
        try:
            remove_path(final)  # never an epoch named by the manifest (see Store)
            os.rename(tmp, final)
            if durable:
                fsync_path(self.edir)
        except OSError as e:
            remove_path(tmp)
            remove_path(final)
            raise write_error(final, e) from e
        rel = f"{EPOCH_DIR}/{basename}"
        return rel, file_entries(rel, inner)

    def publish_part(self, tmp: str, basename: str, durable: bool) -> None:
        """Rename a part another process finished (``store.write_part``) into place."""
        final = os.path.join(self.edir, basename)
        try:
            self.resolver.check_epoch_dir()
            remove_path(final)
            os.rename(tmp, final)
            if durable:
                fsync_path(self.edir)
        except OSError as e:
            remove_path(tmp)
            raise write_error(final, e) from e

    def _epoch(self, entry: JSONObject) -> str:
        return self.resolver.path(entry["path"], f"{self.root}: epoch {entry['step']}")

    def exists(self, entry: JSONObject) -> bool:
        return os.path.lexists(self._epoch(entry))

    def remove_epoch(self, entry: JSONObject) -> None:
        """Delete an epoch the manifest named: a direct child of the real epochs/ directory
        (checked again here, just before deleting; a symbolic link is unlinked, not followed)."""
        self.resolver.check_epoch_dir()
        remove_path(self._epoch(entry))

    def _check_epoch_kind(self, base: str) -> str | None:
        """Problem if the epoch is not what its backend writes (a real file or directory)."""
        try:
            st = os.lstat(base)
        except FileNotFoundError:
            return f"{base}: missing"
        except OSError as e:
            return f"{base}: unreadable ({e.strerror or e})"
        if stat.S_ISLNK(st.st_mode):
            return f"{base}: is a symbolic link (not allowed)"
        want_dir = self.fmt_of(base).IS_DIR
        if want_dir and not stat.S_ISDIR(st.st_mode):
            return f"{base}: not a directory"
        if not want_dir and not stat.S_ISREG(st.st_mode):
            return f"{base}: not a regular file"
        return None

    def open_reader(self, entry: JSONObject) -> FormatReader:
        base = self._epoch(entry)
        bad = self._check_epoch_kind(base)
        if bad:
            raise StoreError(bad)
        return self.fmt_of(base).Reader(base)

    def size_problems(self, entry: JSONObject) -> list[str]:
        """Missing, special or wrong-sized files of an epoch (metadata only, no data read)."""
        base = self._epoch(entry)
        bad = self._check_epoch_kind(base)
        if bad:
            return [bad]
        problems = []
        for f in entry["files"]:
            try:
                p = self.resolver.path(f["path"], base)
            except StoreError as e:
                problems.append(str(e))
                continue
            try:
                st = os.lstat(p)
            except OSError:
                problems.append(f"{p}: missing")
                continue
            if not stat.S_ISREG(st.st_mode):
                problems.append(f"{p}: not a regular file")
            elif st.st_size != f["size"]:
                problems.append(f"{p}: size {st.st_size} != recorded {f['size']}")
        return problems

    def check_files(self, entry: JSONObject) -> list[str]:
        """Sizes and checksums of every listed file, which must be all the epoch's files."""
        base = self._epoch(entry)
        bad = self._check_epoch_kind(base)
        if bad:
            return [bad]
        problems = []
        for f in entry["files"]:
            try:
                p = self.resolver.path(f["path"], base)
                if not self.resolver.has_no_links(p):
                    raise StoreError(f"{p}: reached through a symbolic link (not allowed)")
                digest, want = file_checksum(f, p)
                got = digest_regular(p, f["size"], digest)
            except StoreError as e:
                problems.append(str(e))
                continue
            if got != want:
                problems.append(f"{p}: {digest} mismatch (content changed)")
        if self.fmt_of(base).IS_DIR:
            found, odd = _walk_epoch(base)
            problems += odd
            listed = {f["path"][len(entry["path"]) + 1 :] for f in entry["files"]}
            problems += [f"{found[r]}: unexpected file (not in manifest)" for r in sorted(found) if r not in listed]
        return problems

    # ------------------------------------------------------------------ leftovers
    def leftovers(self, m: JSONObject) -> list[tuple[str, int | None]]:
        """(path, writer pid or None) of what an interrupted write leaves: MANIFEST.json.tmp,
        ``*.tmp-<pid>`` epochs and epoch files the manifest does not name. Only direct
        children of the real epochs/ directory with names of ours are considered."""
        out: list[tuple[str, int | None]] = []
        tmp = os.path.join(self.root, MANIFEST_TMP)
        if os.path.lexists(tmp):
            out.append((tmp, None))
        if not _is_real_dir(self.edir):
            return out
        named = {
            x["path"].rpartition("/")[2]
            for e in (m.get("current"), m.get("previous"))
            if e
            for x in [e, *e.get("parts", ())]
        }
        for n in sorted(os.listdir(self.edir)):
            t = TMP_NAME_RE.match(n)
            if t:
                out.append((os.path.join(self.edir, n), int(t.group(2))))
            elif EPOCH_NAME_RE.match(n) and n not in named:
                out.append((os.path.join(self.edir, n), None))
        return out

    def repair(self, m: JSONObject) -> list[str]:
        """Delete the leftovers (the caller holds the store's write lock); return what went."""
        self.resolver.check_epoch_dir()
        removed = []
        for p, _pid in self.leftovers(m):
            remove_path(p)  # a symbolic link is unlinked, never followed
            removed.append(p)
        if not os.path.lexists(self.edir):
            os.makedirs(self.edir, exist_ok=True)
        return removed
