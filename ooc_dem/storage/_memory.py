"""Memory backend: the same store semantics held in dicts (for tests and serial DDM runs).

Every memory store lives in a module-level registry keyed by its path string, so
open_store("mem://name") reopens it for as long as the process lives (or until
drop_memory_store). Arrays are copied on write and on read, and the "files" of an
epoch are its arrays and attrs, checksummed over their bytes.
"""

from __future__ import annotations

from typing import Any, Literal, TypedDict

import numpy as np
from numpy.typing import DTypeLike, NDArray

from ._util import DIGEST, EPOCH_DIR, JSONObject, StoreError, bytes_digest, file_checksum, parse_json, to_json

_REGISTRY: dict[str, "Backing"] = {}


class Group(TypedDict):
    """A group of an epoch in memory."""

    arrays: dict[str, NDArray[Any]]
    attrs: str  # JSON


class Backing:
    def __init__(self) -> None:
        self.manifest_json: str | None = None
        # epoch path ("epochs/<name>", as on disk) -> group name -> group
        self.epochs: dict[str, dict[str, Group]] = {}


def _file_entries(base: str, groups: dict[str, Group]) -> list[JSONObject]:
    files = []
    for g, content in groups.items():
        for name, a in content["arrays"].items():
            files.append({"path": f"{base}/{g}/{name}", "size": int(a.nbytes), DIGEST: bytes_digest(a.tobytes())})
        raw = content["attrs"].encode()
        files.append({"path": f"{base}/{g}/.attrs", "size": len(raw), DIGEST: bytes_digest(raw)})
    return files


class Writer:
    def __init__(self) -> None:
        self.groups: dict[str, Group] = {}

    def write_group(self, group: str, arrays: dict[str, NDArray[Any]], attrs_json: str) -> None:
        self.groups[group] = {"arrays": {n: np.array(a, copy=True) for n, a in arrays.items()}, "attrs": attrs_json}

    def abort(self) -> None:
        self.groups = {}


class Reader:
    def __init__(self, groups: dict[str, Group], path: str):
        self.groups = groups
        self.path = path

    def has_group(self, group: str) -> bool:
        return group in self.groups

    def array_info(self, group: str, name: str) -> tuple[tuple[int, ...], np.dtype[Any]] | None:
        a = self._find(group, name)
        return None if a is None else (tuple(a.shape), a.dtype)

    def attrs_json(self, group: str) -> str:
        return self.groups[group]["attrs"]

    def _find(self, group: str, name: str) -> NDArray[Any] | None:
        g = self.groups.get(group)
        return None if g is None else g["arrays"].get(name)

    def _a(self, group: str, name: str) -> NDArray[Any]:
        a = self._find(group, name)
        if a is None:
            raise KeyError(f"array {group}/{name} missing")
        return a

    def read_full(self, group: str, name: str, shape: tuple[int, ...], dtype: DTypeLike) -> NDArray[Any]:
        a = self._a(group, name)
        if tuple(a.shape) != tuple(shape):
            raise ValueError(f"array {group}/{name} has shape {a.shape}, manifest says {tuple(shape)}")
        return np.array(a, dtype=dtype, copy=True)

    def read_range(self, group: str, name: str, start: int, stop: int, out: NDArray[Any]) -> None:
        out[...] = self._a(group, name)[start:stop]

    def after_read(self) -> None:
        pass

    def close(self) -> None:
        self.groups = {}


class Place:
    """Manifest + epochs of one memory store."""

    is_memory: Literal[True] = True
    backend = "memory"

    def __init__(self, key: str, backing: Backing) -> None:
        self.key = key
        self.b = backing

    def read_manifest(self) -> object:
        if self.b.manifest_json is None:
            raise StoreError(f"{self.key}: MANIFEST.json missing or unreadable")
        return parse_json(self.b.manifest_json.encode(), f"{self.key}: MANIFEST.json")

    def write_manifest(self, m: JSONObject, durable: bool = False) -> None:
        self.b.manifest_json = to_json(m, f"{self.key}: manifest")

    def new_writer(self, step: int, basename: str, compression: str | None = None) -> Writer:
        return Writer()

    def tmp_name(self, basename: str) -> str:
        return f"{self.key}/{basename} (uncommitted)"

    def publish(self, writer: Writer, basename: str, durable: bool) -> tuple[str, list[JSONObject]]:
        rel = f"{EPOCH_DIR}/{basename}"
        self.b.epochs[rel] = writer.groups
        return rel, _file_entries(rel, writer.groups)

    def exists(self, entry: JSONObject) -> bool:
        return entry["path"] in self.b.epochs

    def remove_epoch(self, entry: JSONObject) -> None:
        self.b.epochs.pop(entry["path"], None)

    def open_reader(self, entry: JSONObject) -> Reader:
        groups = self.b.epochs.get(entry["path"])
        if groups is None:
            raise FileNotFoundError(f"{self.key}/{entry['path']}: epoch missing")
        return Reader(groups, f"{self.key}/{entry['path']}")

    def size_problems(self, entry: JSONObject) -> list[str]:
        if entry["path"] not in self.b.epochs:
            return [f"{self.key}/{entry['path']}: epoch missing"]
        return []

    def leftovers(self, m: JSONObject) -> list[tuple[str, int | None]]:
        return []  # nothing is written under a temporary name

    def check_files(self, entry: JSONObject) -> list[str]:
        problems: list[str] = []
        groups = self.b.epochs.get(entry["path"])
        if groups is None:
            return [f"{self.key}/{entry['path']}: epoch missing"]
        actual = {f["path"] for f in _file_entries(entry["path"], groups)}
        listed = {f["path"] for f in entry["files"]}
        problems += [f"{self.key}/{p}: unexpected (not in manifest)" for p in sorted(actual - listed)]
        for f in entry["files"]:
            rest = f["path"][len(entry["path"]) + 1 :]
            g, _, name = rest.rpartition("/")
            grp = groups.get(g)
            where = f"{self.key}/{f['path']}"
            if grp is None or (name != ".attrs" and name not in grp["arrays"]):
                problems.append(f"{where}: missing")
                continue
            raw = grp["attrs"].encode() if name == ".attrs" else grp["arrays"][name].tobytes()
            if len(raw) != f["size"]:
                problems.append(f"{where}: size {len(raw)} != recorded {f['size']} (truncated?)")
            else:
                digest, want = file_checksum(f, where)
                if bytes_digest(raw, digest) != want:
                    problems.append(f"{where}: {digest} mismatch (content changed)")
        return problems

    def repair(self, m: JSONObject) -> list[str]:
        named = {e["path"] for e in (m.get("current"), m.get("previous")) if e}
        removed = [p for p in self.b.epochs if p not in named]
        for p in removed:
            del self.b.epochs[p]
        return [f"{self.key}/{p}" for p in removed]

    def wipe(self) -> None:
        self.b.manifest_json = None
        self.b.epochs.clear()
