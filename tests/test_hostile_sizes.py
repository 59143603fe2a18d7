"""Sizes read from a file are checked before anything is allocated.

Each test copies a tiny run, makes one of its files declare a size far beyond what it holds
(trajectory frame rows, an npz member, a zarr chunk's inflated size, the manifest's history
capacity) or names a codec ooc-dem does not write, runs the command a user would in a fresh
process and measures that process's peak RSS (``ooc_dem.engine.memlimit.run_limited``): exit 2,
one line, and under 300 MB. tools/refusal_memory.py runs the same cases at the sizes of the
reports (2^25 rows, 4 GB members and chunks, hist_cap 100000, id 3·10^8).
"""

import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from support.cli import one_line_error
from support.runs import WHEEL_TEST
from support.stores import zarr_epochs_as_directories

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import refusal_memory as rm  # noqa: E402

PEAK_MB = 300


@pytest.fixture(scope="module")
def bases(tmp_path_factory):
    """Tiny finished runs, one per kind, built once."""
    made = {}

    def get(kind):
        if kind not in made:
            made[kind] = rm.base_run(tmp_path_factory.mktemp(f"base-{kind}") / "run", *rm.BASES[kind])
        return made[kind]

    return get


def refused_in_little_memory(cmd, *needles):
    r, _ = rm.measure(cmd)
    line = one_line_error(r, *needles)
    assert r.peak_rss_bytes < PEAK_MB * 1e6, (r.peak_rss_bytes, line)
    return line


def test_a_frame_declaring_millions_of_rows_is_refused_before_they_are_read(bases, tmp_path):
    cmd, needle = rm.make_frame_rows(bases("frame_rows"), tmp_path / "run", 1 << 23)
    assert (tmp_path / "run" / "trajectory").stat()  # the frame is ~110 KB
    refused_in_little_memory(cmd, needle, "frame-")


def test_an_initial_npz_member_of_deflated_zeros_is_refused_from_its_header(bases, tmp_path):
    cmd, needle = rm.make_npz_member(bases("npz_member"), tmp_path / "run", 1 << 30)
    assert (tmp_path / "run" / "initial.npz").stat().st_size < 8 << 20
    refused_in_little_memory(cmd, needle, "initial.npz")


def test_animate_bounds_an_initial_npz_member_by_the_first_frames_disc_count(bases, tmp_path):
    run = rm.copy_run(bases("npz_member"), tmp_path / "run")
    rm.bomb_member(run / "initial.npz", "x", 1 << 30)
    refused_in_little_memory(
        rm.cli("animate", run, "--out", tmp_path / "f.gif", "--no-progress"),
        "'x'",
        "134217728 rows, expected 1500",
        "initial.npz",
    )


@pytest.mark.parametrize("layout", ["archive", "directory"])
def test_a_zarr_chunk_behind_a_gzip_codec_is_refused_before_it_is_inflated(bases, tmp_path, layout):
    store = rm.copy_run(bases("zarr_gzip"), tmp_path / "run")
    if layout == "directory":
        zarr_epochs_as_directories(store)
    data, _, _ = rm.deflated_zeros(1 << 30, gzip=True)
    rm.zarr_array_edit(store, "domains/d0000/pos", rm.GZIP, data)
    refused_in_little_memory(rm.cli("checkpoint", "hash", store, "--epoch", 20), "gzip", "refused")


@pytest.mark.parametrize("layout", ["archive", "directory"])
def test_a_zarr_array_naming_the_sharding_codec_is_one_line_and_nothing_from_zarr(bases, tmp_path, layout):
    store = rm.copy_run(bases("zarr_gzip"), tmp_path / "run")
    if layout == "directory":
        zarr_epochs_as_directories(store)
    sharding = {
        "name": "sharding_indexed",
        "configuration": {"chunk_shape": [10, 2], "codecs": [rm.BYTES], "index_codecs": [rm.BYTES, {"name": "crc32c"}]},
    }
    rm.zarr_array_edit(store, "domains/d0000/pos", [sharding], None)
    line = refused_in_little_memory(rm.cli("checkpoint", "hash", store, "--epoch", 20), "sharding_indexed")
    assert "Task was destroyed" not in line


def test_a_manifest_history_capacity_beyond_the_maximum_is_refused_by_the_api(bases, tmp_path):
    cmd, needle = rm.make_hist_cap(bases("hist_cap"), tmp_path / "run", 20_000)
    refused_in_little_memory(cmd, needle, "20000")


def test_a_disc_id_of_hundreds_of_millions_costs_no_table_of_that_size(bases, tmp_path):
    """A serial-DDM store is valid with any distinct ids: it resumes in the memory of its
    discs (an owner table indexed by id would take 8 bytes per id up to the largest)."""
    big = 3 * 10**8
    cmd, _ = rm.make_ddm_big_id(bases("ddm_big_id"), tmp_path / "run", big)
    r, _ = rm.measure(cmd)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.peak_rss_bytes < 1e9, r.peak_rss_bytes  # 8 * 3e8 B = 2.4 GB before
    import ooc_dem

    state = ooc_dem.open_run(tmp_path / "run").state()
    assert big in set(state["id"].tolist()) and len(state["id"]) == 1500


def test_initial_npz_values_that_broke_the_figures_are_one_line_errors(bases, tmp_path):
    """An object member, a member of the wrong length and zero radii (the layer count's
    division) each refused in one line, naming the member."""
    base = bases("npz_member")
    z = dict(np.load(base / "initial.npz"))
    cases = {
        "object": dict(z, x=np.array([None] * len(z["x"]), dtype=object)),
        "short": {k: (v[:10] if v.ndim else v) for k, v in z.items()},
        "zero radii": dict(z, r=np.zeros_like(z["r"]), surface=np.float64(0.0)),
        "huge surface": dict(z, surface=np.float64(1e300)),
    }
    needles = {"object": "'x'", "short": "'id'", "zero radii": "'r'", "huge surface": "'surface'"}
    for name, arrays in cases.items():
        run = rm.copy_run(base, tmp_path / name.replace(" ", "-"))
        np.savez(run / "initial.npz", **arrays)
        refused_in_little_memory(rm.cli("report", run), needles[name], "initial.npz")


# ----------------------------------------------------------------------------- beds

BED_N = 300
BED_SETS = ["--set", f"soil.n={BED_N}", *(a for s in WHEEL_TEST for a in ("--set", s))]


@pytest.fixture(scope="module")
def bomb_bed(tmp_path_factory):
    """A bed.npz of BED_N discs whose 'r' member is 4 GB of deflated zeros (about 19 MB on
    disk), its header true to them; the other members as a bed's."""
    from ooc_dem.model.state import Particles

    f = tmp_path_factory.mktemp("bomb-bed") / "bed.npz"
    p = Particles.empty(BED_N, 2)
    p.id[:] = np.arange(BED_N)
    np.savez(f, **p.arrays())
    rm.bomb_member(f, "r", 4 << 30)
    assert f.stat().st_size < 32 << 20
    return f


def test_a_bed_member_of_deflated_zeros_is_refused_from_its_header(bomb_bed, tmp_path):
    bed = tmp_path / "bed"
    bed.mkdir()
    shutil.copy(bomb_bed, bed / "bed.npz")
    out = tmp_path / "run"
    line = refused_in_little_memory(
        rm.cli("run", "quick", *BED_SETS, "--bed", bed, "--out", out, "--steps", 2, "--no-progress", "--no-figures"),
        "--bed",
        "'r'",
        f"soil.n = {BED_N}",
    )
    assert "536870912 rows" in line
    assert not (out / "MANIFEST.json").exists()


def test_a_bed_cache_entry_of_deflated_zeros_is_rebuilt_with_a_warning(bomb_bed, tmp_path):
    """The cache entry is refused from its header (never inflated), settled again and
    cached again; the run says so in one warning line."""
    from ooc_dem.app.bed import BED_CACHE_VERSION
    from ooc_dem.model.scenario import load_scenario

    sc = load_scenario("quick", BED_SETS[1::2])
    entry = tmp_path / "cache" / "beds" / f"{sc.bed_hash()}.v{BED_CACHE_VERSION}.npz"
    entry.parent.mkdir(parents=True)
    shutil.copy(bomb_bed, entry)
    r, lines = rm.measure(
        rm.cli("run", "quick", *BED_SETS, "--out", tmp_path / "run", "--steps", 2, "--no-progress", "--no-figures"),
        env=dict(os.environ, OOC_DEM_CACHE=str(tmp_path / "cache")),
    )
    assert r.returncode == 0, r.stderr[-2000:]
    # the set-up warnings of a small test bed aside (app/advice.py), one line about the cache
    warnings = [ln for ln in lines if "warning" in ln and "cached bed" in ln]
    assert len(warnings) == 1 and "'r'" in warnings[0] and "rebuilding" in warnings[0], r.stderr
    assert r.peak_rss_bytes < 1e9, r.peak_rss_bytes  # 4.3 GB when the member was inflated
    with np.load(entry) as z:
        assert z["r"].shape == (BED_N,) and (z["r"] > 0).all()
