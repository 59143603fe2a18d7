"""Manifest and epoch files of a store directory (HDF5 or zarr)."""

from __future__ import annotations

import json
import os

from . import _hdf5, _zarr
from ._util import (EPOCH_DIR, EPOCH_NAME_RE, FORMAT, MANIFEST, MANIFEST_TMP, StoreError,
                    drop_page_cache, fsync_path, remove_path, sha256_file, to_json, write_error)

FORMATS = {"hdf5": _hdf5, "zarr": _zarr}


def classify(root: str) -> tuple[str, object]:
    """Look at a path: ("absent"|"empty"|"foreign"|"damaged"|"store", manifest-or-reason)."""
    if not os.path.lexists(root):
        return "absent", None
    if not os.path.isdir(root):
        return "foreign", "it is not a directory"
    entries = os.listdir(root)
    if not entries:
        return "empty", None
    mpath = os.path.join(root, MANIFEST)
    edir = os.path.join(root, EPOCH_DIR)
    looks_ours = os.path.isdir(edir) and all(
        EPOCH_NAME_RE.match(n.split(".tmp-")[0]) for n in os.listdir(edir))
    if os.path.isfile(mpath):
        try:
            with open(mpath, "rb") as f:
                m = json.loads(f.read())
        except (OSError, ValueError) as e:
            if looks_ours:
                return "damaged", f"{type(e).__name__}: {e}"
            return "foreign", "MANIFEST.json is not an ooc-dem manifest"
        if isinstance(m, dict) and m.get("format") == FORMAT:
            return "store", m
        if looks_ours and not isinstance(m, dict):
            return "damaged", "manifest is not a JSON object"
        return "foreign", "MANIFEST.json is not an ooc-dem manifest"
    if looks_ours or (os.path.isdir(edir) and os.path.exists(os.path.join(root, MANIFEST_TMP))):
        return "damaged", "MANIFEST.json missing"
    return "foreign", "no MANIFEST.json"


def wipe(root: str) -> None:
    """Remove a store's own files (manifest, temporaries, epochs) - nothing else."""
    for n in os.listdir(root):
        if n == MANIFEST or n.startswith(MANIFEST_TMP):
            remove_path(os.path.join(root, n))
    remove_path(os.path.join(root, EPOCH_DIR))


class Place:
    is_memory = False

    def __init__(self, root: str, backend: str):
        self.root = root
        self.fmt = FORMATS[backend]
        self.edir = os.path.join(root, EPOCH_DIR)
        self.mpath = os.path.join(root, MANIFEST)

    # ------------------------------------------------------------------ manifest
    def read_manifest(self) -> dict:
        try:
            with open(self.mpath, "rb") as f:
                m = json.loads(f.read())
        except (OSError, ValueError) as e:
            raise StoreError(f"{self.mpath}: MANIFEST.json missing or unreadable ({e})") from None
        return m

    def write_manifest(self, m: dict, durable: bool = False) -> None:
        data = to_json(m, f"{self.mpath}: manifest", indent=1).encode()
        tmp = os.path.join(self.root, MANIFEST_TMP)
        try:
            with open(tmp, "wb") as f:
                f.write(data)
                f.flush()
                if durable:
                    os.fsync(f.fileno())
            os.replace(tmp, self.mpath)          # the commit point
            if durable:
                fsync_path(self.root)
        except OSError as e:
            remove_path(tmp)
            raise write_error(self.mpath, e) from e
        drop_page_cache(self.mpath)

    # ------------------------------------------------------------------ epochs
    def used_on_disk(self, basename: str) -> bool:
        return os.path.lexists(os.path.join(self.edir, basename))

    def tmp_name(self, basename: str) -> str:
        return os.path.join(self.edir, f"{basename}.tmp-{os.getpid()}")

    def new_writer(self, step: int, basename: str):
        tmp = self.tmp_name(basename)
        remove_path(tmp)                         # leftover of an earlier process with our pid
        os.makedirs(self.edir, exist_ok=True)
        return self.fmt.Writer(tmp, step)

    def publish(self, writer, basename: str, durable: bool) -> tuple[str, list[dict]]:
        """Finish the temporary epoch, rename it into place; return (rel path, file list)."""
        tmp = self.tmp_name(basename)
        try:
            inner = writer.finish(durable)
        except (OSError, RuntimeError) as e:
            writer.abort()
            raise write_error(tmp, e) from e
        final = os.path.join(self.edir, basename)
        try:
            remove_path(final)                  # never an epoch named by the manifest (see Store)
            os.rename(tmp, final)
            if durable:
                fsync_path(self.edir)
        except OSError as e:
            remove_path(tmp)
            remove_path(final)
            raise write_error(final, e) from e
        rel = f"{EPOCH_DIR}/{basename}"
        files = [{"path": rel if r == "" else f"{rel}/{r}", "size": size, "sha256": sha}
                 for r, size, sha in inner]
        return rel, files

    def exists(self, entry) -> bool:
        return os.path.exists(os.path.join(self.root, entry["path"]))

    def remove_epoch(self, entry) -> None:
        remove_path(os.path.join(self.root, entry["path"]))

    def open_reader(self, entry):
        return self.fmt.Reader(os.path.join(self.root, entry["path"]))

    def check_files(self, entry) -> list[str]:
        problems = []
        base = os.path.join(self.root, entry["path"])
        if not os.path.exists(base):
            return [f"{base}: missing"]
        listed = set()
        for f in entry["files"]:
            p = os.path.join(self.root, *f["path"].split("/"))
            listed.add(os.path.normpath(p))
            try:
                size = os.stat(p).st_size
            except OSError:
                problems.append(f"{p}: missing")
                continue
            if size != f["size"]:
                problems.append(f"{p}: size {size} != recorded {f['size']} (truncated?)")
                continue
            try:
                _, sha = sha256_file(p)
            except OSError as e:
                problems.append(f"{p}: unreadable ({e})")
                continue
            if sha != f["sha256"]:
                problems.append(f"{p}: sha256 mismatch (content changed)")
        if os.path.isdir(base):
            for rel in _zarr.walk_files(base):
                p = os.path.normpath(os.path.join(base, *rel.split("/")))
                if p not in listed:
                    problems.append(f"{p}: unexpected file (not in manifest)")
        return problems

    def repair(self, m: dict) -> list[str]:
        """Delete temporaries and epoch files the manifest does not name; return what went."""
        removed = []
        for n in os.listdir(self.root):
            if n.startswith(MANIFEST_TMP):
                remove_path(os.path.join(self.root, n))
                removed.append(os.path.join(self.root, n))
        if not os.path.isdir(self.edir):
            os.makedirs(self.edir, exist_ok=True)
            return removed
        named = {os.path.basename(e["path"]) for e in (m.get("current"), m.get("previous")) if e}
        for n in sorted(os.listdir(self.edir)):
            if ".tmp-" in n or (EPOCH_NAME_RE.match(n) and n not in named):
                remove_path(os.path.join(self.edir, n))
                removed.append(os.path.join(self.edir, n))
        return removed
