"""Base material (finished runs, a bed, a cache: built once) and the world of a case (a fresh copy
of them, victims and links around), snapshots of a world."""

from __future__ import annotations

import json
import os
import shutil
import stat
from pathlib import Path

from .common import _dumps, _sha
from .handle import Worker


_RUN20 = ["--steps", "20", "--checkpoint-every", "10", "--no-progress", "--no-figures"]
BASE_RUNS = {
    "h5": ["run", "quick", *_RUN20, "--set", "output.series_interval=0.00005"],
    "zarr": [
        "run",
        "quick",
        *_RUN20,
        "--mode",
        "ooc",
        "--domains",
        "3",
        "--block",
        "10",
        "--backend",
        "zarr",
        "--set",
        "output.series_interval=0.00005",
    ],
    # 3D stores: monolithic HDF5 and out-of-core zarr (the same epoch edits as 2D)
    "h5_3d": ["run", "quick-3d", *_RUN20, "--set", "output.series_interval=0.00005"],
    "zarr_3d": [
        "run",
        "quick-3d",
        *_RUN20,
        "--mode",
        "ooc",
        "--domains",
        "2",
        "--block",
        "10",
        "--backend",
        "zarr",
        "--set",
        "output.series_interval=0.00005",
    ],
    # a frame every 10 steps (frames 0, 10, 20) for the trajectory and film cases
    "traj": [
        "run",
        "quick",
        *_RUN20,
        "--set",
        "output.series_interval=0.00005",
        "--set",
        "output.snapshot_interval=0.0001",
    ],
    # serial DDM (sub-domains in one process, HDF5)
    "ddm": ["run", "quick", *_RUN20, "--mode", "ddm", "--domains", "3", "--set", "output.series_interval=0.00005"],
    # a zarr store whose arrays carry a compression codec (zstd)
    "zarr_zstd": [
        "run",
        "quick",
        *_RUN20,
        "--backend",
        "zarr",
        "--compression",
        "zstd",
        "--set",
        "output.series_interval=0.00005",
    ],
    # a prepared bed (`--bed` cases) made with a fresh bed cache (the bed-cache cases)
    "bed": ["prepare", "quick", "--no-progress"],
}
# the second store of a world (`compare`, run2)
OTHER_BASE = {
    "h5": "zarr",
    "zarr": "h5",
    "ddm": "h5",
    "h5_3d": "zarr_3d",
    "zarr_3d": "h5_3d",
    "traj": "h5",
    "zarr_zstd": "h5",
}

TINY_SCENARIO = """\
[scenario]
name = "tiny"
description = "fuzz base scenario"

[soil]
n = 300

[bin]
length = 0.1
height = 0.1

[wheel]
enabled = false

[output]
run_steps = 10
"""


def make_bases(where: Path, names=None) -> dict:
    """The finished base runs, made once with the real CLI's ``main`` in one worker process
    (imports and JIT paid once, not per base). ``where/cache`` is the bed cache the "bed" base
    was prepared with (its entry is the bed-cache cases' material)."""
    where.mkdir(parents=True, exist_ok=True)
    out, todo = {}, []
    for name in BASE_RUNS if names is None else names:
        d = where / name
        if not (d / ("bed.npz" if name == "bed" else "summary.json")).is_file():
            shutil.rmtree(d, ignore_errors=True)
            todo.append(name)
        out[name] = d
    if todo:
        builder = Worker(use_rlimit=False).start()
        try:
            for name in todo:
                env = {"OOC_DEM_CACHE": str(where / "cache")} if name == "bed" else None
                res = builder.call([*BASE_RUNS[name], "--out", name], where, timeout=1800, env=env)
                if res.get("rc") != 0:
                    raise RuntimeError(
                        f"base {name} failed ({res.get('rc')}): {(res.get('stderr') or res.get('error') or '')[-2000:]}"
                    )
        finally:
            builder.close()
    if "bed" in out:
        out["cache"] = where / "cache"
    return out


class World:
    """The directory tree of one case."""

    def __init__(self, root: Path, base: Path, other: Path):
        self.root = root
        self.w = root / "w"
        self.run = self.w / "run"
        (root / "dev").mkdir(parents=True)
        os.symlink("/dev/zero", root / "dev" / "zero")
        self.w.mkdir()
        shutil.copytree(base, self.run, symlinks=True)
        self.base = base
        self.other = other
        (self.w / "out").mkdir()
        v = self.w / "victim"
        (v / "sub").mkdir(parents=True)
        (v / "a.txt").write_text("precious a\n")
        (v / "sub" / "b.txt").write_text("precious b\n")
        (self.w / "victim_file").write_text("precious file\n")
        for name, target in (
            ("link_victim", "victim"),
            ("link_file", "victim_file"),
            ("link_zero", "/dev/zero"),
            ("dev_null", "/dev/null"),
            ("dev_full", "/dev/full"),
        ):
            os.symlink(target, self.w / name)
        (self.w / "scenario.toml").write_text(TINY_SCENARIO)

    def add_material(self, what: str, bases: dict):
        """The prepared bed (w/out/bed) or a copy of the bed cache (w/cache)."""
        if what == "bed":
            shutil.copytree(bases["bed"], self.w / "out" / "bed", symlinks=True)
        elif what == "cache":
            shutil.copytree(bases["cache"], self.w / "cache", symlinks=True)

    def add_run2(self):
        shutil.copytree(self.other, self.w / "run2", symlinks=True)

    def epoch_bytes_changed(self) -> bool:
        """Whether any file of the base store's epochs differs now (edits may cancel out: the
        same byte flipped twice is the original byte)."""
        base_m = json.loads((self.base / "MANIFEST.json").read_text())
        for e in (base_m["current"], base_m["previous"]):
            for f in e["files"]:
                now = self.run / f["path"]
                if not now.is_file() or now.is_symlink() or now.read_bytes() != (self.base / f["path"]).read_bytes():
                    return True
        return False

    def manifest(self) -> dict:
        return json.loads((self.run / "MANIFEST.json").read_text())

    def write_manifest(self, m, raw: str | None = None):
        (self.run / "MANIFEST.json").write_text(raw if raw is not None else _dumps(m))


def snapshot(root: Path, skip=()) -> dict:
    """{relative path: (type, size, mtime_ns, mode, sha256 | link target)} of a tree, no links followed."""
    out = {}
    root = Path(root)
    skip = {os.path.normpath(s) for s in skip}
    if not os.path.lexists(root):
        return {"": ("missing",)}
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        rel_dir = os.path.relpath(dirpath, root)
        keep = []
        for n in sorted(dirnames):
            rel = os.path.normpath(os.path.join(rel_dir, n))
            if rel in skip:
                continue
            keep.append(n)
        dirnames[:] = keep
        for n in sorted(dirnames) + sorted(filenames):
            rel = os.path.normpath(os.path.join(rel_dir, n))
            if rel in skip:
                continue
            p = os.path.join(dirpath, n)
            try:
                st = os.lstat(p)
            except OSError:
                continue
            if stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(p))
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = ("dir", st.st_mode)
            elif stat.S_ISREG(st.st_mode):
                out[rel] = ("file", st.st_size, st.st_mtime_ns, st.st_mode, _sha(p))
            else:
                out[rel] = ("other", st.st_mode)
    return out


def _diff(a: dict, b: dict, limit=3) -> list[str]:
    out = []
    for k in sorted(set(a) | set(b)):
        if a.get(k) != b.get(k):
            what = "created" if k not in a else "deleted" if k not in b else "changed"
            out.append(f"{k or '.'} {what}")
            if len(out) >= limit:
                break
    return out


def _committed(run: Path) -> dict:
    """{relpath: sha256} of MANIFEST.json and the regular files it names inside the store."""
    out = {}
    mf = run / "MANIFEST.json"
    if not mf.is_file() or mf.is_symlink():
        return out
    out["MANIFEST.json"] = _sha(mf)
    try:
        m = json.loads(mf.read_text())
    except (ValueError, UnicodeDecodeError, RecursionError):
        return out
    if not isinstance(m, dict):
        return out
    base = os.path.realpath(run)
    for role in ("current", "previous"):
        e = m.get(role)
        files = e.get("files") if isinstance(e, dict) else None
        for f in files if isinstance(files, list) else []:
            p = f.get("path") if isinstance(f, dict) else None
            if not isinstance(p, str) or "\0" in p:
                continue
            full = os.path.realpath(os.path.join(run, p))
            if full.startswith(base + os.sep) and os.path.isfile(full) and not os.path.islink(os.path.join(run, p)):
                out[os.path.relpath(full, base)] = _sha(full)
    return out
