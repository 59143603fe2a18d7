"""Store format 1: a store written before the state became dimension-generic (its
domain records hold the 2D components as their own arrays: x, y, vx, vy, w, hist_ft, hist_mr)
still opens for resume, hash, verify, inspect and export, and resumes to the bits of a run
that never left format 2.

The version-1 store is made by code at test time (no binary fixture): a real run's store is
rewritten the way the old engine wrote it (``to_v1``): every epoch's domain groups with the
format-1 arrays, the manifest and run meta at format_version 1 without the entries'
``format_version`` and the meta's ``dim``/``hist_cap``, sizes and checksums recomputed.
"""

import hashlib
import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from support.cli import cli_in_process, run_cli
from support.runs import WHEEL_TEST
from ooc_dem.physics.layout import AX_X, AX_Y, HM_R, HS_T, SP_Z
from ooc_dem.model.state import V1_ARRAYS

STEPS = 40
CKPT = 20
SETS = sum((["--set", s] for s in WHEEL_TEST), [])


def v1_record(rec: dict) -> dict:
    """The format-1 record of a format-2 (2D) record: the inverse of state.V1_ARRAYS."""
    out = {k: v for k, v in rec.items() if k not in V1_ARRAYS}
    out["x"], out["y"] = rec["pos"][:, AX_X], rec["pos"][:, AX_Y]
    out["vx"], out["vy"] = rec["vel"][:, AX_X], rec["vel"][:, AX_Y]
    out["w"] = rec["spin"][:, SP_Z]
    out["hist_ft"] = rec["hist_s"][:, HS_T]
    out["hist_mr"] = rec["hist_m"][:, HM_R]
    return {k: np.ascontiguousarray(v) for k, v in out.items()}


def to_v1(store: Path) -> None:
    """Rewrite an HDF5 run store (format 2, 2D) in place as the format-1 engine wrote it."""
    m = json.loads((store / "MANIFEST.json").read_text())
    for role in ("current", "previous"):
        e = m.get(role)
        if e is None:
            continue
        path = store / e["path"]
        with h5py.File(path, "r+") as f:
            for d, info in e["domains"].items():
                g = f[f"domains/d{int(d):04d}"]
                rec = {k: g[k][()] for k in g.keys()}
                for k in list(g.keys()):
                    del g[k]
                new = v1_record(rec)
                for k, a in new.items():
                    g.create_dataset(k, data=a)
                info["arrays"] = {k: [list(a.shape), a.dtype.str] for k, a in new.items()}
        data = path.read_bytes()
        for fe in e["files"]:
            if fe["path"] == e["path"]:
                # a version-1 store recorded sha256 checksums
                fe.pop("xxh3_128", None)
                fe["size"], fe["sha256"] = len(data), hashlib.sha256(data).hexdigest()
        e.pop("format_version", None)
    m["format_version"] = 1
    m["meta"]["format_version"] = 1
    m["meta"].pop("dim", None)
    m["meta"].pop("hist_cap", None)
    (store / "MANIFEST.json").write_text(json.dumps(m))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """(format-2 run to STEPS, format-1 copy of a run stopped at CKPT, the format-2 hash at CKPT)."""
    root = tmp_path_factory.mktemp("v1")
    full = root / "full"
    run_cli(
        "run",
        "quick",
        "--out",
        full,
        "--steps",
        STEPS,
        "--checkpoint-every",
        CKPT,
        "--no-progress",
        "--no-figures",
        *SETS,
        check=True,
    )
    half = root / "half"
    run_cli(
        "run",
        "quick",
        "--out",
        half,
        "--steps",
        CKPT,
        "--checkpoint-every",
        CKPT,
        "--no-progress",
        "--no-figures",
        *SETS,
        check=True,
    )
    h_half = cli_in_process("checkpoint", "hash", half, check=True).stdout.strip()
    v1 = root / "v1"
    shutil.copytree(half, v1)
    to_v1(v1)
    return full, v1, h_half


def test_the_fixture_is_format_1(runs):
    _, v1, _ = runs
    m = json.loads((v1 / "MANIFEST.json").read_text())
    assert m["format_version"] == 1 and m["meta"]["format_version"] == 1
    names = set(m["current"]["domains"]["0"]["arrays"])
    assert {"x", "y", "vx", "vy", "w", "hist_ft", "hist_mr"} <= names and "pos" not in names


def test_v1_store_hashes_verifies_inspects_exports(runs, tmp_path):
    full, v1, h_half = runs
    assert cli_in_process("checkpoint", "hash", v1, check=True).stdout.strip() == h_half
    cli_in_process("checkpoint", "verify", v1, check=True)
    info = json.loads(cli_in_process("checkpoint", "inspect", v1, check=True).stdout)
    assert info["step"] == CKPT and info["discs"] > 0
    out = tmp_path / "v1.csv"
    cli_in_process("checkpoint", "export", v1, "--out", out, check=True)
    out2 = tmp_path / "v2.csv"
    cli_in_process("checkpoint", "export", full, "--epoch", CKPT, "--out", out2, check=True)
    lines1 = out.read_text().splitlines()
    lines2 = out2.read_text().splitlines()
    assert lines1[3] == "id,x,y,vx,vy,w,r,mass,mat"
    assert lines1[2:] == lines2[2:]  # same columns and values (line 0 names the source)


def test_v1_store_resumes_to_the_v2_bits(runs):
    full, v1, _ = runs
    run_cli("resume", v1, "--steps", STEPS, "--no-progress", "--no-figures", check=True)
    h_full = json.loads((full / "summary.json").read_text())["state_hash"]
    assert json.loads((v1 / "summary.json").read_text())["state_hash"] == h_full
    m = json.loads((v1 / "MANIFEST.json").read_text())
    assert m["format_version"] == 2  # the store moved on to format 2 ...
    assert m["current"]["format_version"] == 2
    assert "pos" in m["current"]["domains"]["0"]["arrays"]
    if m["previous"] is not None and m["previous"]["step"] == CKPT:
        assert m["previous"]["format_version"] == 1  # ... its format-1 epoch stays named so
    assert cli_in_process("checkpoint", "hash", v1, check=True).stdout.strip() == h_full


def test_v1_epoch_reads_rows_as_v2(runs):
    """The adapter (checkpoint.V1Epoch) serves partial reads (rows of pos, CSR entries of
    hist_s) exactly as a format-2 epoch would."""
    from ooc_dem.model.checkpoint import V1Epoch, open_epoch
    from ooc_dem.storage import open_store

    full, v1, _ = runs
    s1, s2 = open_store(v1, repair=False), open_store(full, repair=False)
    try:
        r1 = open_epoch(s1, CKPT)  # format 1 (after the resume test too: the previous epoch)
        r2 = open_epoch(s2, CKPT)
        assert isinstance(r1, V1Epoch) and not isinstance(r2, V1Epoch)
        assert r1.domain_arrays(0) == r2.domain_arrays(0)
        for rows in (None, slice(3, 40), np.array([0, 5, 7])):
            a, b = r1.read_domain(0, rows=rows), r2.read_domain(0, rows=rows)
            assert a.keys() == b.keys()
            for k in a:
                assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), k
        r1.close()
        r2.close()
    finally:
        s1.close()
        s2.close()
