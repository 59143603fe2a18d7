#!/usr/bin/env python
"""Peak RSS of ooc-dem facing files that declare sizes far beyond what they hold.

Each case copies a small run, makes one of its files declare a hostile size (a trajectory
frame of 2^25 rows in 110 KB, an ``initial.npz`` member of 4 GB of deflated zeros, a zarr
epoch whose chunk inflates to 4 GB, a manifest ``meta.hist_cap`` of 100000, a serial-DDM
store holding the disc id 3·10^8), runs the command a user would in a fresh process and
measures its peak RSS (``ooc_dem.engine.memlimit.run_limited``: the child's own ``ru_maxrss``).
A refusal must be exit 2, one line, well under 300 MB; the DDM store with a large id is
valid and must resume in the memory of its discs, not of its largest id. Prints JSON.

    python tools/refusal_memory.py [--work DIR] [--cases frame_rows,npz_member,...]

tests/test_hostile_sizes.py runs the same cases at smaller sizes.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
import zlib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from ooc_dem.engine.memlimit import run_limited  # noqa: E402

PIECE = 64 << 20  # bytes of zeros compressed at a time
# the sizes of the reproductions (tests/test_hostile_sizes.py uses smaller ones)
FULL = {
    "frame_rows": 1 << 25,
    "npz_member": 4 << 30,
    "zarr_gzip": 4 << 30,
    "hist_cap": 100_000,
    "ddm_big_id": 3 * 10**8,
}
BYTES = {"name": "bytes", "configuration": {"endian": "little"}}
GZIP = [BYTES, {"name": "gzip", "configuration": {"level": 1}}]
API_STATE = (
    "import sys, ooc_dem\n"
    "try:\n    ooc_dem.open_run(sys.argv[1]).state()\n"
    "except (ooc_dem.StoreError, ooc_dem.StateError) as e:\n"
    "    print(f'ooc-dem: error: {e}', file=sys.stderr); sys.exit(2)\n"
)


def cli(*args) -> list[str]:
    return [sys.executable, "-m", "ooc_dem.cli", *map(str, args)]


def base_run(out: Path, *extra) -> Path:
    """A tiny finished run of the quick rig (frames every 10 steps)."""
    if not (out / "MANIFEST.json").exists():
        subprocess.run(
            cli(
                "run",
                "quick",
                "--out",
                out,
                "--steps",
                20,
                "--checkpoint-every",
                10,
                "--set",
                "output.snapshot_interval=0.0001",
                "--no-progress",
                *extra,
            ),
            check=True,
            capture_output=True,
            text=True,
        )
    return out


def copy_run(src: Path, dest: Path) -> Path:
    shutil.rmtree(dest, ignore_errors=True)
    shutil.copytree(src, dest, symlinks=True)
    return dest


def deflated_zeros(nbytes: int, head: bytes = b"", gzip: bool = False):
    """(compressed stream, its uncompressed size, crc32) of `head` then nbytes zero bytes."""
    c = zlib.compressobj(1, zlib.DEFLATED, 31 if gzip else -15)
    out, crc, left = [c.compress(head)], zlib.crc32(head), nbytes
    piece = bytes(min(PIECE, nbytes))
    while left:
        b = piece[: min(left, PIECE)]
        out.append(c.compress(b))
        crc = zlib.crc32(b, crc)
        left -= len(b)
    out.append(c.flush())
    return b"".join(out), len(head) + nbytes, crc


def rechecksum(store: Path) -> None:
    """Recompute the manifest's sizes and checksums of the epochs' files (only ooc-dem's own
    validation then stands between the edit and the reader): sha256, which stores of
    earlier versions were signed with and which is still accepted."""
    m = json.loads((store / "MANIFEST.json").read_text())
    for role in ("current", "previous"):
        for f in (m.get(role) or {}).get("files", []):
            f.pop("xxh3_128", None)
            data = (store / f["path"]).read_bytes()
            f["size"], f["sha256"] = len(data), hashlib.sha256(data).hexdigest()
    (store / "MANIFEST.json").write_text(json.dumps(m, indent=1))


def make_frame_rows(base: Path, dest: Path, rows: int):
    """A published trajectory frame whose datasets declare `rows` rows (unwritten chunks:
    the file stays about 110 KB)."""
    import h5py

    copy_run(base, dest)
    frame = sorted((dest / "trajectory").glob("frame-*.h5"))[1]
    with h5py.File(frame, "r+") as f:
        for k in ("id", "pos", "vel", "spin", "r", "mat"):
            f[k].resize(rows, axis=0)
        f.attrs["n_discs"] = rows
    return cli("animate", dest, "--out", dest.parent / f"{dest.name}.gif", "--no-progress"), "rows"


def make_npz_member(base: Path, dest: Path, nbytes: int):
    """initial.npz whose 'x' member is nbytes of deflated zeros (float64), its header true."""
    copy_run(base, dest)
    bomb_member(dest / "initial.npz", "x", nbytes)
    return cli("report", dest), "'x'"


def bomb_member(npz: Path, member: str, nbytes: int) -> None:
    """Replace the member ``member`` of the archive ``npz`` by nbytes of deflated zeros
    (float64, one row a number), its .npy header true to them; the other members kept."""
    hdr = _npy_header((nbytes // 8,), np.float64)
    data, size, crc = deflated_zeros(nbytes, hdr)
    tmp = npz.with_name(npz.name + ".new")
    with zipfile.ZipFile(npz) as zin, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as zout:
        for zi in zin.infolist():
            if zi.filename != f"{member}.npy":
                zout.writestr(zi, zin.read(zi))
        _raw_entry(zout, f"{member}.npy", data, size, crc)
    os.replace(tmp, npz)


def _npy_header(shape, dtype) -> bytes:
    import io

    b = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        b, {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)), "fortran_order": False, "shape": shape}
    )
    return b.getvalue()


def _raw_entry(zout: zipfile.ZipFile, name: str, data: bytes, size: int, crc: int) -> None:
    """A deflated entry whose compressed bytes are given (zipfile would compress them again)."""
    zi = zipfile.ZipInfo(name, (2020, 1, 1, 0, 0, 0))
    zi.compress_type = zipfile.ZIP_DEFLATED
    zi.file_size, zi.compress_size, zi.CRC = size, len(data), crc
    zi.header_offset = zout.fp.tell()
    zout.fp.write(zi.FileHeader(zip64=size > zipfile.ZIP64_LIMIT))
    zout.fp.write(data)
    zout.start_dir = zout.fp.tell()
    zout.filelist.append(zi)
    zout.NameToInfo[name] = zi
    zout._didModify = True


def zarr_array_edit(store: Path, array: str, codecs: list, chunk: bytes | None) -> None:
    """The current zarr epoch (an archive, or a directory of an earlier layout) with the
    array document of `array` (e.g. 'domains/d0000/pos') naming `codecs` and, if given, its
    chunk replaced; manifest checksums recomputed."""
    m = json.loads((store / "MANIFEST.json").read_text())
    path = store / m["current"]["path"]

    def edit(doc: bytes) -> bytes:
        meta = json.loads(doc)
        meta["codecs"] = codecs
        return json.dumps(meta).encode()

    key = f"{array}/zarr.json"
    if path.is_dir():
        (path / key).write_bytes(edit((path / key).read_bytes()))
        if chunk is not None:
            next(p for p in (path / array / "c").rglob("*") if p.is_file()).write_bytes(chunk)
    else:
        tmp = path.with_name(path.name + ".edit")
        with zipfile.ZipFile(path) as zin, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as zout:
            for zi in zin.infolist():
                b = zin.read(zi)
                if zi.filename == key:
                    b = edit(b)
                elif chunk is not None and zi.filename.startswith(f"{array}/c/"):
                    b = chunk
                zout.writestr(zi, b)
        os.replace(tmp, path)
    rechecksum(store)


def make_zarr_gzip(base: Path, dest: Path, nbytes: int):
    """A zarr epoch whose 'pos' array names the gzip codec, its chunk inflating to nbytes."""
    copy_run(base, dest)
    data, _, _ = deflated_zeros(nbytes, gzip=True)
    zarr_array_edit(dest, "domains/d0000/pos", GZIP, data)
    return cli("checkpoint", "hash", dest, "--epoch", 20), "gzip"


def make_hist_cap(base: Path, dest: Path, cap: int):
    copy_run(base, dest)
    m = json.loads((dest / "MANIFEST.json").read_text())
    m["meta"]["hist_cap"] = cap
    (dest / "MANIFEST.json").write_text(json.dumps(m, indent=1))
    return [sys.executable, "-c", API_STATE, str(dest)], "hist_cap"


def make_ddm_big_id(base: Path, dest: Path, big: int):
    """A serial-DDM store whose current epoch has its largest disc id renumbered to `big`
    (in the partners' contact histories too: every order stays ascending); valid, so
    `resume` continues it."""
    import h5py

    copy_run(base, dest)
    m = json.loads((dest / "MANIFEST.json").read_text())
    with h5py.File(dest / m["current"]["path"], "r+") as f:
        groups = list(f["domains"].values())
        old = max(int(np.max(g["id"], initial=-1)) for g in groups)
        for g in groups:
            for k in ("id", "hist_id"):
                a = np.asarray(g[k])
                if (a == old).any():
                    a[a == old] = big
                    g[k][...] = a
    rechecksum(dest)
    return cli("resume", dest, "--steps", 30, "--no-progress", "--no-figures"), None


CASES = {
    "frame_rows": make_frame_rows,
    "npz_member": make_npz_member,
    "zarr_gzip": make_zarr_gzip,
    "hist_cap": make_hist_cap,
    "ddm_big_id": make_ddm_big_id,
}
BASES = {
    "frame_rows": (),
    "npz_member": (),
    "zarr_gzip": ("--backend", "zarr"),
    "hist_cap": (),
    "ddm_big_id": ("--mode", "ddm", "--domains", "4", "--no-figures"),
}


def measure(cmd, env=None):
    r = run_limited(cmd, env=env)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    return r, lines


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default=None, help="directory for the runs (default: a temporary one)")
    ap.add_argument("--cases", default=",".join(CASES))
    a = ap.parse_args()
    work = Path(a.work or tempfile.mkdtemp(prefix="refusal-memory-"))
    work.mkdir(parents=True, exist_ok=True)
    out = []
    for name in a.cases.split(","):
        base = base_run(work / "-".join(["base", *(x.strip("-") for x in BASES[name])]), *BASES[name])
        cmd, _ = CASES[name](base, work / name, FULL[name])
        r, lines = measure(cmd)
        out.append(
            {
                "case": name,
                "size": FULL[name],
                "exit_code": r.returncode,
                "stderr_lines": len(lines),
                "peak_rss_mb": round(r.peak_rss_bytes / 1e6, 1),
                "message": lines[-1][:200] if lines else "",
            }
        )
        shutil.rmtree(work / name, ignore_errors=True)
        print(json.dumps(out[-1]), file=sys.stderr)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
