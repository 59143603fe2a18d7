"""Run directories seen from outside: the committed step, and edits of their files."""

import hashlib
import json
import os
import pathlib
import zipfile


def committed_step(store) -> int:
    """The step of a store's committed epoch, read from its manifest (not by opening the
    store, so it can be polled while a run writes); -1 before the first commit."""
    try:
        m = json.loads((pathlib.Path(store) / "MANIFEST.json").read_text())
    except (OSError, ValueError):
        return -1
    cur = m.get("current") if isinstance(m, dict) else None
    return cur["step"] if isinstance(cur, dict) and isinstance(cur.get("step"), int) else -1


def zarr_epochs_as_directories(store) -> None:
    """Turn every zarr epoch of a store (one zip archive each) into the directory layout of
    earlier versions, manifest included (a store written before; still read): the archive's
    keys become files under `epochs/<name>.zarr/`, exactly a zarr LocalStore."""
    store = pathlib.Path(store)
    m = json.loads((store / "MANIFEST.json").read_text())
    for role in ("current", "previous"):
        e = m.get(role)
        if not e or not e["path"].endswith(".zip"):
            continue
        src = store / e["path"]
        rel = e["path"][: -len(".zip")] + ".zarr"
        with zipfile.ZipFile(src) as zf:
            zf.extractall(store / rel)
        src.unlink()
        files = sorted(p for p in (store / rel).rglob("*") if p.is_file())
        e["path"] = rel
        e["files"] = [
            {
                "path": p.relative_to(store).as_posix(),
                "size": p.stat().st_size,
                "sha256": hashlib.sha256(p.read_bytes()).hexdigest(),
            }
            for p in files
        ]
    (store / "MANIFEST.json").write_text(json.dumps(m, indent=1))


def zip_without(path, prefix: str) -> None:
    """Rewrite the zip archive `path` without the entries whose names start with `prefix`
    (a zarr epoch with a group or array deleted)."""
    tmp = str(path) + ".rewrite"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as dst:
        for zi in src.infolist():
            if not zi.filename.startswith(prefix):
                dst.writestr(zi, src.read(zi))
    os.replace(tmp, path)
