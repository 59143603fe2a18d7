"""Edits of a world applied before the command: manifest JSON, run files, paths and links; the
array-file edits are file_edits'."""

from __future__ import annotations

import copy
import json
import os
import re
import shutil
from pathlib import Path

from .common import _dumps, _sha
from .file_edits import (
    _decode_value,
    _edit_array,
    _edit_attrs,
    _edit_bomb_npz,
    _edit_npz_array,
    _edit_npz_member,
    _edit_traj,
    _edit_zarr_codec,
    _epoch_entry,
    _write_npz,
)
from .world import World


RAW_HUGE_INT = "1" + "0" * 5000


def _get(tree, path):
    for k in path:
        tree = tree[k]
    return tree


def _set(tree, path, value):
    if not path:
        return value
    parent = tree
    for k in path[:-1]:
        if isinstance(parent, dict) and isinstance(k, str):
            parent = parent.get(k)
        elif isinstance(parent, list) and isinstance(k, int) and -len(parent) <= k < len(parent):
            parent = parent[k]
        else:
            return tree
    k = path[-1]
    if isinstance(parent, dict) and isinstance(k, str):
        parent[k] = value
    elif isinstance(parent, list) and isinstance(k, int) and -len(parent) <= k < len(parent):
        parent[k] = value
    return tree


def _delete(tree, path):
    try:
        parent = _get(tree, path[:-1])
        if isinstance(parent, dict):
            parent.pop(path[-1], None)
        elif isinstance(parent, list) and isinstance(path[-1], int) and path[-1] < len(parent):
            del parent[path[-1]]
    except (KeyError, IndexError, TypeError):
        pass
    return tree


def _epoch_file_paths(world: World, which: str) -> list[Path]:
    """Regular files (relative to the store) of the named epoch."""
    m = world.manifest()
    e = _epoch_entry(m, which)
    if not e:
        return []
    return [world.run / f["path"] for f in e["files"]]


def _fix_checksums(world: World, rels: list[str]):
    m = world.manifest()
    for role in ("current", "previous"):
        e = _epoch_entry(m, role)
        for f in (e or {}).get("files", []):
            if f["path"] in rels:
                p = world.run / f["path"]
                f["size"] = p.stat().st_size
                f.pop("xxh3_128", None)  # an older store's checksum, still accepted
                f["sha256"] = _sha(p)
    world.write_manifest(m)


def apply_edit(world: World, ed: dict) -> None:
    op = ed["op"]
    run = world.run
    if op not in ("manifest_raw", "runfile", "runfile_link", "scenario_file", "epochs_symlink"):
        try:
            world.manifest()
        except (ValueError, UnicodeDecodeError, RecursionError, OSError):
            return  # an earlier edit made the manifest unreadable
    if op == "manifest_set":
        m = world.manifest()
        value = json.loads(json.dumps(ed["value"]).replace("$ABS", str(world.w)))
        world.write_manifest(_set(m, ed["path"], _decode_value(value)))
    elif op == "manifest_delete":
        world.write_manifest(_delete(world.manifest(), ed["path"]))
    elif op == "manifest_swap":
        m = world.manifest()
        m["current"], m["previous"] = m.get("previous"), m.get("current")
        world.write_manifest(m)
    elif op == "manifest_prev_is_cur":
        m = world.manifest()
        m["previous"] = copy.deepcopy(m.get("current"))
        world.write_manifest(m)
    elif op == "manifest_raw":
        text = (run / "MANIFEST.json").read_text()
        if ed["what"] == "huge_int":
            text = re.sub(r'"step": \d+', '"step": ' + RAW_HUGE_INT, text, count=1)
        elif ed["what"] == "deep":
            text = text.replace('"meta": {', '"deep": ' + "[" * ed["n"] + "]" * ed["n"] + ', "meta": {', 1)
        elif ed["what"] == "truncate":
            text = text[: int(len(text) * ed["frac"])]
        elif ed["what"] == "nan_step":
            text = re.sub(r'"step": \d+', '"step": NaN', text, count=1)
        elif ed["what"] == "bytes":
            (run / "MANIFEST.json").write_bytes(bytes(ed["data"]))
            return
        (run / "MANIFEST.json").write_text(text)
    elif op == "epochs_symlink":
        if (run / "epochs").is_symlink() or not (run / "epochs").is_dir():
            return
        shutil.copytree(run / "epochs", world.w / "victim_epochs", symlinks=True)
        shutil.rmtree(run / "epochs")
        os.symlink("../victim_epochs", run / "epochs")
    elif op == "flip":
        files = [p for p in _epoch_file_paths(world, ed["which"]) if p.is_file()]
        if not files:
            return
        p = files[ed["file"] % len(files)]
        data = bytearray(p.read_bytes())
        if not data:
            return
        for frac, x in zip(ed["offsets"], ed["xors"]):
            i = min(int(frac * len(data)), len(data) - 1)
            data[i] ^= (x % 255) + 1
        p.write_bytes(bytes(data))
        if ed.get("recompute"):
            _fix_checksums(world, [p.relative_to(run).as_posix()])
    elif op == "truncate":
        files = [p for p in _epoch_file_paths(world, ed["which"]) if p.is_file()]
        if not files:
            return
        p = files[ed["file"] % len(files)]
        data = p.read_bytes()
        p.write_bytes(data[: int(len(data) * ed["frac"])] + bytes(ed.get("extra", [])))
        if ed.get("recompute"):
            _fix_checksums(world, [p.relative_to(run).as_posix()])
    elif op == "array":
        _edit_array(world, ed)
    elif op == "attrs":
        _edit_attrs(world, ed)
    elif op == "npz_array":
        _edit_npz_array(world, ed)
    elif op == "npz_member":
        (_edit_bomb_npz if ed["what"] == "bomb" else _edit_npz_member)(world, ed)
    elif op == "traj":
        _edit_traj(world, ed)
    elif op == "zarr_codec":
        _edit_zarr_codec(world, ed)
    elif op == "runfile":
        p = run / ed["name"]
        if not ed.get("delete") and "summary_set" not in ed:
            if p.is_symlink():
                p.unlink()
            elif p.is_dir():
                shutil.rmtree(p)
        if "text" in ed:
            p.write_text(ed["text"], encoding="utf-8", errors="surrogatepass")
        elif "json" in ed:
            p.write_text(_dumps(_decode_value(ed["json"])))
        elif "bytes" in ed:
            p.write_bytes(bytes(ed["bytes"]))
        elif "npz" in ed:
            _write_npz(p, ed["npz"])
        elif ed.get("delete"):
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()
        elif "summary_set" in ed:
            if p.is_symlink() or not p.is_file():
                return  # an earlier edit made it a link (to /dev/zero, say): never read it here
            s = json.loads(p.read_text())
            p.write_text(_dumps(_set(s, ed["summary_set"], _decode_value(ed["value"]))))
    elif op == "runfile_link":
        p = run / ed["name"]
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif os.path.lexists(p):
            p.unlink()
        os.symlink(ed["target"], p)
    elif op == "scenario_file":
        p = world.w / "out" / ed["name"]
        if "bytes" in ed:
            p.write_bytes(bytes(ed["bytes"]))
        else:
            p.write_text(ed["text"], encoding="utf-8", errors="surrogatepass")
    else:
        raise ValueError(f"unknown edit {op!r}")
