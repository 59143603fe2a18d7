"""Edits of the array files of a world: epoch arrays and attributes (HDF5 and zarr), npz members
and inflation bombs, trajectory frames, zarr codecs."""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
from pathlib import Path

from .common import _sha
from .world import World


def _write_npz(path, spec):
    import numpy as np

    arrays = {}
    for name, kind in spec.items():
        if kind == "nan":
            arrays[name] = np.full(1500, np.nan)
        elif kind == "short":
            arrays[name] = np.zeros(3)
        elif kind == "2d":
            arrays[name] = np.zeros((1500, 7))
        elif kind == "str":
            arrays[name] = np.array(["a", "b"])
        elif kind == "object":
            arrays[name] = np.array([{"a": 1}, None], dtype=object)
        elif kind == "empty":
            arrays[name] = np.zeros(0)
        elif kind == "int":
            arrays[name] = np.arange(1500)
        elif kind == "huge_shape_hdr":
            arrays[name] = np.zeros(1)
    with open(path, "wb") as f:
        np.savez(f, **arrays)


def _semantic(arr, kind, rows):
    import numpy as np

    a = np.array(arr)
    n = len(a)
    idx = [min(int(r * n), n - 1) for r in rows] if n else []
    if kind == "nan":
        if a.dtype.kind == "f":
            a[idx] = np.nan
        else:
            a[idx] = -1
    elif kind == "inf":
        if a.dtype.kind == "f":
            a[idx] = np.inf
        else:
            a[idx] = np.iinfo(a.dtype).max
    elif kind == "all_nan":
        a = np.full(a.shape, np.nan) if a.dtype.kind == "f" else np.full(a.shape, -1, a.dtype)
    elif kind == "99":
        a[idx] = 99
    elif kind == "all_99":
        a[...] = 99
    elif kind == "neg":
        a[idx] = -(10**6)
    elif kind == "huge":
        a[idx] = np.iinfo(a.dtype).max if a.dtype.kind in "iu" else 1e308
    elif kind == "zero":
        a[idx] = 0
    elif kind == "dup" and n > 1:
        a[idx] = a[0]
    elif kind == "shorter":
        a = a[: max(0, n - 1)]
    elif kind == "longer":
        a = np.concatenate([a, a[:1]])
    elif kind == "empty":
        a = a[:0]
    elif kind == "2d":
        a = np.stack([a, a], axis=-1)
    elif kind == "int32":
        a = a.astype(np.int32) if a.dtype.kind == "f" else a.astype(np.float64)
    elif kind == "float32":
        a = a.astype(np.float32)
    elif kind == "bool":
        a = a.astype(bool)
    elif kind == "complex":
        a = a.astype(np.complex128)
    elif kind == "u8":
        a = a.astype(np.uint8)
    elif kind in EXTREMES:
        v = EXTREMES[kind]
        if a.dtype.kind in "iu":
            v = int(min(max(v, np.iinfo(a.dtype).min), np.iinfo(a.dtype).max))
        elif a.dtype.kind == "b":
            v = bool(v)
        if n:
            a[idx] = v
    elif kind == "drop_row" and n > 1:
        a = np.delete(a, idx[:1], axis=0)
    elif kind == "unsort" and n > 1 and a.ndim >= 2:
        a[idx] = a[idx][:, ::-1]
    return a


# finite absurd values and out-of-range indices (each written at the drawn rows)
EXTREMES = {
    "1e300": 1e300,
    "5e-324": 5e-324,
    "-5e-324": -5e-324,
    "999": 999,
    "i32max": 2**31 - 1,
    "minus7": -7,
    "minus1": -1,
    "1e-300": 1e-300,
    "1e150": 1e150,
    "3e8": 300_000_000,
}


@contextlib.contextmanager
def _zarr_tree(path):
    """A zarr epoch as a directory to edit: the epoch itself (directory layout of earlier
    versions), or its zip archive unpacked into a scratch directory and packed again (stored
    entries, the edited tree's files) when the edit is done."""
    import zipfile

    path = Path(path)
    if path.is_dir():
        yield path
        return
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "epoch"
        with zipfile.ZipFile(path) as zf:
            zf.extractall(base)
        yield base
        with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
            for f in sorted(p for p in base.rglob("*") if p.is_file()):
                zf.write(f, f.relative_to(base).as_posix())


def _edit_array(world: World, ed: dict):
    import numpy as np

    m = world.manifest()
    e = _epoch_entry(m, ed["which"])
    if not e:
        return
    group = ed["group"]
    if world.manifest().get("backend") == "hdf5":
        import h5py

        p = world.run / e["path"]
        with h5py.File(p, "r+") as f:
            gname = (
                "globals" if group == "globals" else f"domains/{sorted(f['domains'])[ed['dom'] % len(f['domains'])]}"
            )
            g = f[gname]
            names = sorted(g)
            name = ed["name"] if ed["name"] in g else names[ed.get("name_i", 0) % len(names)]
            if ed["kind"] == "delete":
                del g[name]
            else:
                old = g[name][()]
                new = _semantic(old, ed["kind"], ed.get("rows", [0.0]))
                ed["noop"] = _same_array(old, new)
                del g[name]
                g.create_dataset(name, data=new)
        if ed.get("update_meta"):
            _sync_meta_hdf5(world, ed["which"])
    else:
        with _zarr_tree(world.run / e["path"]) as base:
            doms = sorted((base / "domains").glob("d*"))
            gdir = base / "globals" if group == "globals" else doms[ed["dom"] % len(doms)]
            names = sorted(x.name for x in gdir.iterdir() if x.is_dir())
            name = ed["name"] if ed["name"] in names else names[ed.get("name_i", 0) % len(names)]
            adir = gdir / name
            meta = json.loads((adir / "zarr.json").read_text())
            dt = np.dtype(
                {"float64": "<f8", "int64": "<i8", "int32": "<i4", "float32": "<f4", "bool": "|b1", "uint8": "|u1"}.get(
                    meta["data_type"], "<f8"
                )
            )
            chunk = adir / "c" / "/".join(["0"] * max(1, len(meta["shape"])))
            if ed["kind"] == "delete":
                shutil.rmtree(adir)
            else:
                old = (
                    np.frombuffer(chunk.read_bytes(), dtype=dt).reshape(meta["shape"])
                    if chunk.exists()
                    else np.zeros(meta["shape"], dt)
                )
                new = _semantic(old, ed["kind"], ed.get("rows", [0.0]))
                ed["noop"] = _same_array(old, new)
                if new.ndim != old.ndim:
                    shutil.rmtree(adir / "c", ignore_errors=True)
                    chunk = adir / "c" / "/".join(["0"] * max(1, new.ndim))
                chunk.parent.mkdir(parents=True, exist_ok=True)
                chunk.write_bytes(np.ascontiguousarray(new).astype(new.dtype.newbyteorder("<")).tobytes())
                if ed.get("update_meta") or new.shape != old.shape or new.dtype != old.dtype:
                    names_ = {
                        "<f8": "float64",
                        "<i8": "int64",
                        "<i4": "int32",
                        "<f4": "float32",
                        "|b1": "bool",
                        "|u1": "uint8",
                        "<c16": "complex128",
                    }
                    if ed.get("update_meta", True):
                        meta["shape"] = list(new.shape)
                        meta["chunk_grid"]["configuration"]["chunk_shape"] = list(new.shape)
                        meta["data_type"] = names_.get(new.dtype.newbyteorder("<").str, meta["data_type"])
                        (adir / "zarr.json").write_text(json.dumps(meta, indent=2))
        if ed.get("update_meta"):
            _sync_meta_zarr(world, ed["which"])
    _fix_all_checksums(world, ed["which"])


def _fix_all_checksums(world: World, which: str):
    """Re-list and re-checksum every file of the epoch (the tampering is invisible to checksums)."""
    m = world.manifest()
    e = _epoch_entry(m, which)
    if not e:
        return
    base = world.run / e["path"]
    if base.is_dir():
        files = sorted(p for p in base.rglob("*") if p.is_file())
    else:
        files = [base]
    e["files"] = [
        {"path": p.relative_to(world.run).as_posix(), "size": p.stat().st_size, "sha256": _sha(p)} for p in files
    ]
    world.write_manifest(m)


def _sync_meta_hdf5(world, which):
    import h5py

    m = world.manifest()
    e = _epoch_entry(m, which)
    with h5py.File(world.run / e["path"], "r") as f:
        for i, dname in enumerate(sorted(f["domains"])):
            g = f["domains"][dname]
            key = str(int(dname[1:]))
            arrays = {n: [list(g[n].shape), g[n].dtype.str] for n in g}
            first = next(iter(arrays.values()), None)
            e["domains"][key] = {"n": first[0][0] if first and first[0] else 0, "arrays": arrays}
        g = f["globals"]
        e["globals"] = {"arrays": {n: [list(g[n].shape), g[n].dtype.str] for n in g}}
    world.write_manifest(m)


def _sync_meta_zarr(world, which):
    m = world.manifest()
    e = _epoch_entry(m, which)
    with _zarr_tree(world.run / e["path"]) as base:
        strs = {
            "float64": "<f8",
            "int64": "<i8",
            "int32": "<i4",
            "float32": "<f4",
            "bool": "|b1",
            "uint8": "|u1",
            "complex128": "<c16",
        }

        def arrays(gdir):
            out = {}
            for a in sorted(x for x in gdir.iterdir() if x.is_dir()):
                meta = json.loads((a / "zarr.json").read_text())
                out[a.name] = [meta["shape"], strs.get(meta["data_type"], meta["data_type"])]
            return out

        for dname in sorted((base / "domains").glob("d*")):
            arr = arrays(dname)
            first = next(iter(arr.values()), None)
            e["domains"][str(int(dname.name[1:]))] = {"n": first[0][0] if first and first[0] else 0, "arrays": arr}
        e["globals"] = {"arrays": arrays(base / "globals")}
    world.write_manifest(m)


def _edit_attrs(world: World, ed: dict):
    m = world.manifest()
    e = _epoch_entry(m, ed["which"])
    if not e:
        return
    value = ed["value"]  # None: delete the attribute, else the new JSON string
    if m.get("backend") == "hdf5":
        import h5py

        with h5py.File(world.run / e["path"], "r+") as f:
            g = (
                f["globals"]
                if ed["group"] == "globals"
                else f["domains"][sorted(f["domains"])[ed["dom"] % len(f["domains"])]]
            )
            if value is None:
                if "ooc_dem_attrs" in g.attrs:
                    del g.attrs["ooc_dem_attrs"]
            else:
                g.attrs["ooc_dem_attrs"] = value
    else:
        with _zarr_tree(world.run / e["path"]) as base:
            doms = sorted((base / "domains").glob("d*"))
            gdir = base / "globals" if ed["group"] == "globals" else doms[ed["dom"] % len(doms)]
            meta = json.loads((gdir / "zarr.json").read_text())
            if value is None:
                meta.get("attributes", {}).pop("ooc_dem_attrs", None)
            else:
                meta.setdefault("attributes", {})["ooc_dem_attrs"] = value
            (gdir / "zarr.json").write_text(json.dumps(meta, indent=2))
    _fix_all_checksums(world, ed["which"])


def _bombs_dir(world: World) -> Path:
    """Where built bombs are kept between cases (beside the session's case directories)."""
    d = world.root.parent.parent / "bombs"
    d.mkdir(exist_ok=True)
    return d


def _gzip_zeros(world: World, size: int) -> Path:
    """A gzip stream of ``size`` zero bytes (about size / 1000 bytes), built once a session."""
    import zlib

    p = _bombs_dir(world) / f"zeros-{size}.gz"
    if not p.is_file():
        c = zlib.compressobj(1, zlib.DEFLATED, 31)
        block = bytes(min(size, 16 << 20))
        with open(p.with_suffix(".part"), "wb") as f:
            left = size
            while left:
                k = min(left, len(block))
                f.write(c.compress(block[:k]))
                left -= k
            f.write(c.flush())
        os.replace(p.with_suffix(".part"), p)
    return p


def _npz_path(world: World, where: str) -> Path | None:
    if where == "bed":
        return world.w / "out" / "bed" / "bed.npz"
    if where == "cache":
        found = sorted((world.w / "cache" / "beds").glob("*.npz"))
        return found[0] if found else None
    return world.run / "initial.npz"


def _edit_npz_array(world: World, ed: dict):
    """One array of a bed file (a prepared bed.npz or a bed-cache entry) edited, or the file removed."""
    import numpy as np

    p = _npz_path(world, ed["file"])
    if p is None or not p.is_file():
        return
    if ed["kind"] == "remove_file":
        p.unlink()
        return
    with np.load(p, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    name = ed["name"] if ed["name"] in arrays else sorted(arrays)[0]
    if ed["kind"] == "delete":
        del arrays[name]
    elif ed["kind"] == "drop_disc":  # one disc removed from every array (a consistent tamper)
        i = min(int(ed.get("rows", [0.0])[0] * len(arrays["id"])), len(arrays["id"]) - 1)
        arrays = {k: np.delete(v, i, axis=0) for k, v in arrays.items()}
    else:
        arrays[name] = _semantic(arrays[name], ed["kind"], ed.get("rows", [0.0]))
    with open(p, "wb") as f:
        np.savez(f, **arrays)


def _npy_header(shape, descr="<f8", fortran=False) -> bytes:
    """A .npy version-1 header declaring ``shape`` (whatever data follows)."""
    d = "{'descr': %r, 'fortran_order': %s, 'shape': %s, }" % (descr, fortran, repr(tuple(shape)))
    pad = 64 - (10 + len(d) + 1) % 64
    d = (d + " " * pad + "\n").encode("latin1")
    return b"\x93NUMPY\x01\x00" + len(d).to_bytes(2, "little") + d


def _edit_npz_member(world: World, ed: dict):
    """``initial.npz`` rebuilt with one hostile member (the others kept as written):
    ``declared`` -- a header declaring ``shape`` over a few bytes of data; ``bomb`` -- ``size``
    bytes of deflated zeros under a header declaring all of them (a few MB on disk);
    ``object`` -- a pickled object array; ``shape``/``dtype``/``fortran`` -- wrong layouts."""
    import zipfile

    p = world.run / "initial.npz"
    member = ed["member"] + ".npy"
    kept = {}
    if p.is_file() and not p.is_symlink():
        try:
            with zipfile.ZipFile(p) as zf:
                kept = {n: zf.read(n) for n in zf.namelist() if n != member}
        except (zipfile.BadZipFile, OSError):
            kept = {}
    what = ed["what"]
    tmp = p.with_name("initial.npz.part")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for n, data in kept.items():
            zf.writestr(n, data)
        if what == "bomb":
            size = int(ed["size"])
            zi = zipfile.ZipInfo(member)
            zi.compress_type = zipfile.ZIP_DEFLATED
            block = bytes(16 << 20)
            with zf.open(zi, "w", force_zip64=True) as f:
                f.write(_npy_header((size // 8,)))
                left = size // 8 * 8
                while left:
                    k = min(left, len(block))
                    f.write(block[:k])
                    left -= k
        elif what == "declared":
            zf.writestr(member, _npy_header(tuple(ed["shape"]), ed.get("descr", "<f8")) + bytes(64))
        elif what == "object":
            import io
            import numpy as np

            b = io.BytesIO()
            np.save(b, np.array([{"a": 1}, None], dtype=object), allow_pickle=True)
            zf.writestr(member, b.getvalue())
        elif what == "fortran":
            zf.writestr(member, _npy_header((750, 2), "<f8", True) + bytes(750 * 2 * 8))
        elif what == "shape":
            zf.writestr(member, _npy_header(tuple(ed["shape"]), "<f8") + bytes(8 * math.prod(ed["shape"])))
        elif what == "dtype":
            zf.writestr(member, _npy_header((1500,), ed["descr"]) + bytes(1500 * 16))
    os.replace(tmp, p)


def _edit_bomb_npz(world: World, ed: dict):
    """The bomb member is built once per (member, size) and copied (it takes seconds to deflate)."""
    key = f"initial-{ed['member']}-{ed['size']}-{_sha(world.run / 'initial.npz')[:12]}.npz"
    built = _bombs_dir(world) / key
    if not built.is_file():
        _edit_npz_member(world, ed)
        shutil.copyfile(world.run / "initial.npz", built.with_suffix(".part"))
        os.replace(built.with_suffix(".part"), built)
    else:
        shutil.copyfile(built, world.run / "initial.npz")


def _frames(world: World) -> list[Path]:
    return sorted((world.run / "trajectory").glob("frame-*.h5"))


def _edit_traj(world: World, ed: dict):
    """One trajectory frame file edited: an attribute, one dataset (_semantic kinds), every row
    dataset re-declared at ``rows`` rows with no data written (a few KB on disk), or removed."""
    import h5py
    import numpy as np

    frames = _frames(world)
    if not frames:
        return
    p = frames[ed["frame"] % len(frames)]
    what = ed["what"]
    if what == "remove":
        p.unlink()
        return
    with h5py.File(p, "r+") as f:
        if what == "attr":
            v = _decode_value(ed["value"])
            if v is None:
                if ed["key"] in f.attrs:
                    del f.attrs[ed["key"]]
            else:
                f.attrs[ed["key"]] = np.array(v) if isinstance(v, list) else v
        elif what == "dataset":
            name = ed["name"] if ed["name"] in f else sorted(f)[0]
            new = _semantic(f[name][()], ed["kind"], ed.get("rows", [0.0]))
            del f[name]
            if ed["kind"] != "delete":
                f.create_dataset(name, data=new)
        elif what == "declare_rows":
            rows = int(ed["rows"])
            for name in sorted(f):
                ds = f[name]
                tail, dt = ds.shape[1:], ds.dtype
                del f[name]
                f.create_dataset(name, shape=(rows, *tail), dtype=dt, chunks=(min(rows, 1 << 16), *tail), fillvalue=0)
            if ed.get("n_discs"):
                f.attrs["n_discs"] = rows


ZARR_CODECS = {
    "gzip": {"name": "gzip", "configuration": {"level": 5}},
    "zstd": {"name": "zstd", "configuration": {"level": 0, "checksum": False}},
    "blosc": {
        "name": "blosc",
        "configuration": {"cname": "lz4", "clevel": 5, "shuffle": "shuffle", "typesize": 8, "blocksize": 0},
    },
    "crc32c": {"name": "crc32c"},
    "unknown": {"name": "frobnicate", "configuration": {}},
}


def _edit_zarr_codec(world: World, ed: dict):
    """One array document of a zarr epoch names another codec chain: a compressor over the
    chunk encoded with it (``encode``) or left as it was, a gzip chunk of ``size`` zero bytes
    (far beyond the declared shape), the sharding codec, an unknown codec."""
    m = world.manifest()
    e = _epoch_entry(m, ed["which"])
    if not e or m.get("backend") != "zarr":
        return
    import gzip

    with _zarr_tree(world.run / e["path"]) as base:
        doms = sorted((base / "domains").glob("d*"))
        gdir = base / "globals" if ed["group"] == "globals" else doms[ed["dom"] % len(doms)]
        names = sorted(x.name for x in gdir.iterdir() if x.is_dir())
        adir = gdir / (ed["name"] if ed["name"] in names else names[ed.get("name_i", 0) % len(names)])
        meta = json.loads((adir / "zarr.json").read_text())
        chunks = sorted(p for p in (adir / "c").rglob("*") if p.is_file()) if (adir / "c").is_dir() else []
        raw = chunks[0].read_bytes() if chunks else b""
        codec = ed["codec"]
        bytes_codec = {"name": "bytes", "configuration": {"endian": "little"}}
        data = raw
        if codec == "gzip_bomb":
            meta["codecs"] = [bytes_codec, ZARR_CODECS["gzip"]]
            data = None
        elif codec == "sharding":
            meta["codecs"] = [
                {
                    "name": "sharding_indexed",
                    "configuration": {
                        "chunk_shape": meta["chunk_grid"]["configuration"]["chunk_shape"],
                        "codecs": [bytes_codec],
                        "index_codecs": [bytes_codec, {"name": "crc32c"}],
                        "index_location": "end",
                    },
                }
            ]
        elif codec == "sharding_many":
            # inner chunks of one row, an index without checksum: the chunk's bytes read as
            # offsets, one read task per inner chunk
            meta["codecs"] = [
                {
                    "name": "sharding_indexed",
                    "configuration": {
                        "chunk_shape": [1] * len(meta["shape"]),
                        "codecs": [bytes_codec],
                        "index_codecs": [bytes_codec],
                        "index_location": ed.get("index_location", "end"),
                    },
                }
            ]
        elif codec == "transpose":
            meta["codecs"] = [
                {"name": "transpose", "configuration": {"order": list(range(len(meta["shape"])))[::-1]}},
                bytes_codec,
            ]
        else:
            meta["codecs"] = [bytes_codec, ZARR_CODECS[codec]]
            if ed.get("encode") and codec == "gzip":
                data = gzip.compress(raw)
            elif ed.get("encode") and codec in ("zstd", "blosc"):
                import numcodecs

                data = bytes(
                    (
                        numcodecs.Zstd(level=0)
                        if codec == "zstd"
                        else numcodecs.Blosc(cname="lz4", clevel=5, shuffle=1, typesize=8)
                    ).encode(raw)
                )
        (adir / "zarr.json").write_text(json.dumps(meta, indent=2))
        target = chunks[0] if chunks else adir / "c" / "/".join(["0"] * max(1, len(meta["shape"])))
        target.parent.mkdir(parents=True, exist_ok=True)
        if data is None:
            shutil.copyfile(_gzip_zeros(world, int(ed["size"])), target)
        else:
            target.write_bytes(data)
    _fix_all_checksums(world, ed["which"])


def _decode_value(v):
    """Values travel as JSON; {"$float": "nan"} and {"$deep": n} stand for what JSON cannot carry."""
    if isinstance(v, dict) and len(v) == 1:
        ((k, x),) = v.items()
        if k == "$float":
            return float(x)
        if k in ("$deep_list", "$deep_dict"):
            return v  # kept as a marker, written by _dumps
        if k == "$many_domains":
            return {str(i): {"n": 1, "arrays": {"x": [[1], "<f8"]}} for i in range(x)}
    if isinstance(v, list):
        return [_decode_value(x) for x in v]
    if isinstance(v, dict):
        return {k: _decode_value(x) for k, x in v.items()}
    return v


def _epoch_entry(m, which):
    e = m.get(which) if isinstance(m, dict) else None
    return e if isinstance(e, dict) else None


def _same_array(old, new) -> bool:
    """Whether an array edit changed nothing (e.g. "longer" or "nan" on a domain holding no
    disc): the epoch then holds the intact state, whatever the edit's kind says."""
    return old.dtype == new.dtype and old.shape == new.shape and old.tobytes() == new.tobytes()
