"""Every reader of an epoch validates it the same way: `checkpoint hash` and `checkpoint export`
refuse what `resume` refuses; materials beyond the contact table, absurd finite values (a speed
of 1e300, a mass of 5e-324) and counts against the scenario are refused before a step; beds from
`--bed` and from the cache go through the same validation (a refused cache entry is rebuilt,
with a warning); a hostile manifest meta gives the API's own StateError; the disk-space estimate
of a resume comes from the epoch it resumed from, never from a damaged entry."""

import hashlib
import json
import shutil

import numpy as np
import pytest

import ooc_dem
from support.cli import cli_in_process, one_line_error, run_cli
from support.runs import BASE_RUN_STEPS as STEPS, WHEEL_TEST
from ooc_dem.model.checkpoint import open_epoch, record_rows
from ooc_dem.model.decomposition import x_summary
from ooc_dem.physics.layout import AX_X
from ooc_dem.model.state import HIST_FIELDS
from ooc_dem.storage import StoreError, open_store
from test_untrusted_state import _manifest, _replace, _tamper_current

D0 = "domains/d0000"


def _edit(name, index, value):
    """An edit of one element of domain 0's array `name` (the dtype kept)."""

    def edit(f):
        a = f[f"{D0}/{name}"][:]
        a[index] = value
        f[f"{D0}/{name}"][:] = a

    return edit


def _float32_pos(f):
    _replace(f, f"{D0}/pos", f[f"{D0}/pos"][:].astype(np.float32))


def _globals_step(step):
    def edit(f):
        a = json.loads(f["globals"].attrs["ooc_dem_attrs"])
        a["step"] = step
        f["globals"].attrs["ooc_dem_attrs"] = json.dumps(a)

    return edit


# each: an edit of the current epoch (checksums recomputed) and a word of the refusal
TAMPERED = {
    "nan-position": (_edit("pos", (7, AX_X), np.nan), "non-finite"),
    "zero-radius": (_edit("r", 0, 0.0), "'r'"),
    "negative-id": (_edit("id", 3, -7), "'id'"),
    "hist_n-over-capacity": (_edit("hist_n", 0, 99), "hist_n"),
    "material-999": (_edit("mat", 0, 999), "'mat'"),
    "float32-positions": (_float32_pos, "'pos'"),
    "globals-step-not-the-manifests": (_globals_step(STEPS - 1), "'step'"),
}


@pytest.mark.parametrize("case", list(TAMPERED))
def test_hash_and_export_refuse_what_resume_refuses(run_copy, tmp_path, case):
    edit, needle = TAMPERED[case]
    m = _tamper_current(run_copy, edit)
    if case == "float32-positions":  # the manifest describes the array as it now is
        m["current"]["domains"]["0"]["arrays"]["pos"][1] = "<f4"
        (run_copy / "MANIFEST.json").write_text(json.dumps(m))
    assert cli_in_process("checkpoint", "verify", run_copy).returncode == 0  # the checksums pass
    one_line_error(cli_in_process("checkpoint", "hash", run_copy), needle)
    out = tmp_path / "e.csv"
    one_line_error(cli_in_process("checkpoint", "export", run_copy, "--out", out), needle)
    assert not out.exists()
    one_line_error(cli_in_process("resume", run_copy, "--steps", STEPS + 20, "--no-progress", "--no-figures"), needle)


@pytest.mark.parametrize(
    "field,index,value",
    [("vel", (0, 0), 1e300), ("mass", 0, 5e-324), ("pos", (0, AX_X), 1e12), ("spin", (0, 0), 1e300)],
)
def test_finite_absurd_values_are_refused_naming_the_array(run_copy, field, index, value):
    _tamper_current(run_copy, _edit(field, index, value))
    one_line_error(
        cli_in_process("resume", run_copy, "--steps", STEPS + 20, "--no-progress", "--no-figures"), f"'{field}'"
    )
    one_line_error(cli_in_process("checkpoint", "hash", run_copy), f"'{field}'")


def test_disk_space_estimate_ignores_a_damaged_current_epochs_size(run_copy):
    """The current epoch's recorded size says 10^18 bytes (nothing else recomputed, so it fails
    verification): the resume falls back to the previous epoch and finishes."""
    m = _manifest(run_copy)
    m["current"]["files"][0]["size"] = 10**18
    (run_copy / "MANIFEST.json").write_text(json.dumps(m))
    cp = run_cli("resume", run_copy, "--steps", STEPS + 20, "--no-progress", "--no-figures")
    assert cp.returncode == 0, cp.stderr[-2000:]
    assert "using previous epoch" in cp.stderr
    assert _manifest(run_copy)["current"]["step"] == STEPS + 20


@pytest.mark.parametrize("key,value", [("dim", 3.0), ("dim", "2"), ("hist_cap", "12"), ("hist_cap", 12.5)])
def test_hostile_meta_types_raise_the_packages_state_error(run_copy, key, value):
    m = _manifest(run_copy)
    m["meta"][key] = value
    (run_copy / "MANIFEST.json").write_text(json.dumps(m))
    with pytest.raises(ooc_dem.StateError, match=key):
        ooc_dem.open_run(run_copy).state()
    one_line_error(cli_in_process("checkpoint", "hash", run_copy), key)


def test_3d_material_index_beyond_the_table_is_refused(tmp_path):
    """mat = 2^31 - 1 in a 3D store: indexed into the contact table it read far out of bounds
    (a segmentation fault); refused by resume, hash and the API."""
    out = tmp_path / "run3"
    run_cli(
        "run",
        "quick-3d",
        "--out",
        out,
        "--steps",
        10,
        "--checkpoint-every",
        5,
        "--no-progress",
        "--no-figures",
        check=True,
    )
    _tamper_current(out, _edit("mat", 0, 2**31 - 1))
    one_line_error(cli_in_process("resume", out, "--steps", 20, "--no-progress", "--no-figures"), "'mat'")
    one_line_error(cli_in_process("checkpoint", "hash", out), "'mat'")
    with pytest.raises(ooc_dem.StateError, match="'mat'"):
        ooc_dem.open_run(out).state()


# ----------------------------------------------------------------------------- disc counts


def _commit_with_discs(run, edit):
    """Commit, through the store's own writer, a copy of the current epoch (one step on) whose
    first domain's record `edit` changed: every count, attribute (``n``, ``x_summary``), size
    and checksum agrees with the new discs, so only a check against the scenario can tell."""
    store = open_store(run)
    try:
        reader = open_epoch(store)
        arrays, attrs = reader.read_globals()
        step, groups = reader.step + 1, []
        for d in reader.domains():
            rec, dattrs = reader.read_domain(d), reader.domain_attrs(d)
            if not groups:
                rec = edit(rec)
            if "n" in dattrs:
                dattrs["n"] = len(rec["id"])
            if "x_summary" in dattrs:
                dattrs["x_summary"] = x_summary(rec["pos"][:, AX_X], dattrs["x_summary"]["length"])
            groups.append((d, rec, dattrs))
        reader.close()
        w = store.begin_epoch(step)
        for g in groups:
            w.write_domain(*g)
        w.write_globals(arrays, {**attrs, "step": step})
        w.commit()
    finally:
        store.close()
    return step


def _delete_discs(rec, k=3):
    """The record without its first k discs, and without the contacts others kept with them."""
    gone = rec["id"][:k]
    rec = record_rows(rec, np.arange(k, len(rec["id"])))
    owner = np.repeat(np.arange(len(rec["id"])), rec["hist_n"].astype(np.intp))
    keep = ~np.isin(rec["hist_id"], gone)
    for name in HIST_FIELDS:
        rec[name] = rec[name][keep]
    rec["hist_n"] = np.bincount(owner[keep], minlength=len(rec["id"])).astype(rec["hist_n"].dtype)
    return rec


def _add_disc(rec):
    """The record with a copy of its first disc (its contact history too) under a fresh id."""
    rec = record_rows(rec, np.r_[np.arange(len(rec["id"])), 0])
    rec["id"][-1] = rec["id"].max() + 1
    return rec


@pytest.fixture(scope="module")
def run_3d_zarr(tmp_path_factory):
    out = tmp_path_factory.mktemp("zarr3d") / "run"
    run_cli(
        "run",
        "quick-3d",
        "--backend",
        "zarr",
        "--out",
        out,
        "--steps",
        10,
        "--checkpoint-every",
        5,
        "--no-progress",
        "--no-figures",
        check=True,
    )
    return out


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("edit", [_delete_discs, _add_disc], ids=["deleted", "added"])
def test_a_consistent_change_of_the_disc_count_is_refused(base_run, run_3d_zarr, tmp_path, dim, edit):
    """Spheres deleted (with the contacts others kept with them) or one added (a copy under a
    fresh id), the epoch otherwise consistent and committed by the store itself: refused
    against the scenario's soil.n by resume and hash (2D: quick, HDF5; 3D: quick-3d, zarr)."""
    run = tmp_path / "run"
    shutil.copytree(base_run if dim == 2 else run_3d_zarr, run)
    step = _commit_with_discs(run, edit)
    assert cli_in_process("checkpoint", "verify", run).returncode == 0  # the store finds nothing wrong
    line = one_line_error(cli_in_process("checkpoint", "hash", run), f"epoch {step} holds", "soil.n")
    one_line_error(cli_in_process("resume", run, "--steps", step + 10, "--no-progress", "--no-figures"), line)


# ----------------------------------------------------------------------------- MPI parts


def _resign(store, entry, rel):
    """Record file `rel` (the main file or a part of manifest entry `entry`) at its size and
    checksum as they now are."""
    data = (store / rel).read_bytes()
    for f in entry["files"] + [f for p in entry.get("parts", ()) for f in p["files"]]:
        if f["path"] == rel:
            f.pop("xxh3_128", None)
            f["size"], f["sha256"] = len(data), hashlib.sha256(data).hexdigest()


def test_a_part_of_another_epoch_is_refused_naming_the_part(tmp_path):
    """An MPI run's epoch is a main file and one part per rank; each file records its epoch's
    step. Part 1 of the previous epoch copied over the current one's (the manifest's size,
    checksum and domain entries made to match it) is refused by verify, hash, export and
    resume in one line naming the part, and by a reader that skips verification (as the
    ranks' do) when it opens the part."""
    from support.mpi import run_mpi

    run = tmp_path / "mpi"
    run_mpi(
        2,
        "run",
        "quick",
        "--mode",
        "mpi",
        "--steps",
        20,
        "--checkpoint-every",
        10,
        "--out",
        run,
        "--no-progress",
        "--no-figures",
    )
    m = _manifest(run)
    cur, prev = m["current"], m["previous"]
    assert cur["parts"] and prev["parts"]
    part = cur["parts"][0]["path"]
    shutil.copyfile(run / prev["parts"][0]["path"], run / part)
    _resign(run, cur, part)
    for d, info in cur["domains"].items():
        if info.get("part") == 1:
            cur["domains"][d] = prev["domains"][d]
    m["previous"] = None  # else the previous epoch, intact, would be used instead
    (run / "MANIFEST.json").write_text(json.dumps(m))
    needle = f"{part.rpartition('/')[2]}: the file records step {prev['step']}"
    cp = cli_in_process("checkpoint", "verify", run)
    assert cp.returncode == 2 and needle in cp.stdout, (cp.stdout, cp.stderr)
    one_line_error(cli_in_process("checkpoint", "hash", run), needle)
    out = tmp_path / "e.csv"
    one_line_error(cli_in_process("checkpoint", "export", run, "--out", out), needle)
    assert not out.exists()
    one_line_error(cli_in_process("resume", run, "--steps", 30, "--no-progress", "--no-figures"), needle)
    one_line_error(run_mpi(2, "resume", run, "--steps", 30, "--no-progress", "--no-figures", check=False), needle)
    store = open_store(run, repair=False)
    try:
        with store.read_epoch(verify=False) as reader:
            d = next(int(d) for d, info in cur["domains"].items() if info.get("part") == 1)
            with pytest.raises(StoreError, match=needle.replace(".", r"\.")):
                reader.read_domain(d)
    finally:
        store.close()


# ----------------------------------------------------------------------------- beds

SMALL = ["--set", "soil.n=300", *sum((["--set", s] for s in WHEEL_TEST), [])]


@pytest.fixture(scope="module")
def prepared_bed(tmp_path_factory):
    """A settled bed of a small quick scenario, prepared with its own cache."""
    root = tmp_path_factory.mktemp("bed")
    run_cli(
        "prepare",
        "quick",
        *SMALL,
        "--out",
        root / "bed",
        "--no-progress",
        check=True,
        env={"OOC_DEM_CACHE": str(root / "cache")},
    )
    return root


def _bed_with(src, dst, edit):
    shutil.copytree(src, dst)
    with np.load(dst / "bed.npz") as z:
        arrays = {k: z[k] for k in z.files}
    edit(arrays)
    np.savez(dst / "bed.npz", **arrays)
    return dst


def _set(name, index, value):
    def edit(a):
        a[name][index] = value

    return edit


BAD_BEDS = {
    "zero-radius": (_set("r", 0, 0.0), "'r'"),
    "hist_n-over-capacity": (_set("hist_n", 0, 99), "hist_n"),
    "negative-id": (_set("id", 0, -7), "'id'"),
    "material-minus-1": (_set("mat", 0, -1), "'mat'"),
    "material-999": (_set("mat", 0, 999), "'mat'"),
    "nan-position": (_set("pos", (0, AX_X), np.nan), "non-finite"),
    "speed-1e300": (_set("vel", (0, 0), 1e300), "'vel'"),
}


@pytest.mark.parametrize("case", list(BAD_BEDS))
def test_run_refuses_a_bad_bed_in_one_line(prepared_bed, tmp_path, case):
    edit, needle = BAD_BEDS[case]
    bed = _bed_with(prepared_bed / "bed", tmp_path / "bed", edit)
    out = tmp_path / "run"
    one_line_error(
        cli_in_process(
            "run", "quick", *SMALL, "--bed", bed, "--out", out, "--steps", 2, "--no-progress", "--no-figures"
        ),
        "--bed",
        needle,
    )
    assert not (out / "MANIFEST.json").exists()  # nothing committed from it


def test_a_refused_cache_entry_is_rebuilt_with_a_warning(prepared_bed, tmp_path):
    """A cached bed with one disc removed (a consistent file: it loads) is refused against
    soil.n, rebuilt and cached again; the run says so in one warning line."""
    from ooc_dem.app.bed import BED_CACHE_VERSION

    cache = tmp_path / "cache"
    shutil.copytree(prepared_bed / "cache", cache)
    (entry,) = (cache / "beds").glob(f"*.v{BED_CACHE_VERSION}.npz")
    with np.load(entry) as z:
        arrays = {k: z[k][:-1] for k in z.files}
    np.savez(entry, **arrays)
    cp = run_cli(
        "run",
        "quick",
        *SMALL,
        "--out",
        tmp_path / "run",
        "--steps",
        2,
        "--no-progress",
        "--no-figures",
        env={"OOC_DEM_CACHE": str(cache)},
    )
    assert cp.returncode == 0, cp.stderr[-2000:]
    # the cache's warning (a bed this small is also warned of as shallow)
    warnings = [ln for ln in cp.stderr.splitlines() if "rebuilding" in ln]
    assert len(warnings) == 1 and "soil.n = 300" in warnings[0] and "rebuilding" in warnings[0], cp.stderr
    with np.load(entry) as z, np.load(prepared_bed / "bed" / "bed.npz") as bed:
        assert np.array_equal(z["pos"], bed["pos"])  # the same bed, settled again


def test_a_format_1_bed_at_another_capacity_reads_as_the_bed_it_stores(prepared_bed, tmp_path):
    """The bed reader takes what older engines wrote: format-1 component arrays, another
    history capacity, deflated members."""
    from ooc_dem.app.bed import read_bed
    from ooc_dem.model.scenario import load_scenario

    with np.load(prepared_bed / "bed" / "bed.npz") as z:
        a = {k: z[k] for k in z.files}
    wider = {
        k: np.concatenate([v, np.zeros((len(v), 4) + v.shape[2:], v.dtype)], axis=1)
        for k, v in a.items()
        if k.startswith("hist_") and k != "hist_n"
    }
    v1 = {k: v for k, v in a.items() if k not in ("pos", "vel", "spin", "hist_s", "hist_m")}
    v1.update(
        hist_id=wider["hist_id"],
        x=a["pos"][:, 0],
        y=a["pos"][:, 1],
        vx=a["vel"][:, 0],
        vy=a["vel"][:, 1],
        w=a["spin"][:, 0],
        hist_ft=wider["hist_s"][..., 0],
        hist_mr=wider["hist_m"][..., 0],
    )
    np.savez_compressed(tmp_path / "bed.npz", **v1)
    p = read_bed(tmp_path / "bed.npz", load_scenario("quick", SMALL[1::2]), "--bed")
    assert p.hist_cap == a["hist_id"].shape[1] + 4
    for k in ("id", "pos", "vel", "spin", "r", "mass", "mat", "hist_n"):
        assert np.array_equal(getattr(p, k), a[k]), k
    assert np.array_equal(p.hist_s, wider["hist_s"]) and np.array_equal(p.hist_m, wider["hist_m"])
