"""A store's content is untrusted input: an epoch edited consistently (its checksums
recomputed) is refused before it is stepped, hashed or exported; hostile run options and scenario
text in the manifest are refused; `checkpoint export --out` never replaces a store's files or
anything that is not a regular file; a kill after the last commit or before the first one leaves
a run that `resume` / `run --out` finish. Every refusal: exit 2, one line on stderr."""

import hashlib
import json
import os
import shutil
import stat
from pathlib import Path

import h5py
import numpy as np
import pytest

from support.cli import cli_in_process, one_line_error, run_cli
from support.runs import BASE_RUN_STEPS as STEPS, WHEEL_TEST
from ooc_dem.physics.layout import AX_X


def _manifest(store: Path) -> dict:
    return json.loads((store / "MANIFEST.json").read_text())


def _tamper_current(store: Path, edit):
    """Apply `edit(h5py.File)` to the current HDF5 epoch, then recompute its recorded size and
    checksum as an attacker (or a careless script) would, so only a content check can notice."""
    m = _manifest(store)
    cur = m["current"]
    path = store / cur["path"]
    with h5py.File(path, "r+") as f:
        edit(f)
    data = path.read_bytes()
    for f in cur["files"]:
        if f["path"] == cur["path"]:
            f.pop("xxh3_128", None)  # re-signed the way older stores were (still read)
            f["size"], f["sha256"] = len(data), hashlib.sha256(data).hexdigest()
    # the previous epoch would be resumed from instead if it were left intact; drop it
    m["previous"] = None
    (store / "MANIFEST.json").write_text(json.dumps(m))
    return m


def _replace(f, name, values):
    attrs = dict(f[name].attrs)
    del f[name]
    f.create_dataset(name, data=values)
    for k, v in attrs.items():
        f[name].attrs[k] = v


def _dup_ids(f):
    ids = f["domains/d0000/id"][:]
    ids[1] = ids[0]
    f["domains/d0000/id"][:] = ids


def _nan_position(f):
    pos = f["domains/d0000/pos"][:]
    pos[len(pos) // 2, AX_X] = np.nan
    f["domains/d0000/pos"][:] = pos


def _hist_n_99(f):
    hn = f["domains/d0000/hist_n"][:]
    hn[0] = 99
    f["domains/d0000/hist_n"][:] = hn


def _globals_attrs_without_step(f):
    a = json.loads(f["globals"].attrs["ooc_dem_attrs"])
    del a["step"]
    f["globals"].attrs["ooc_dem_attrs"] = json.dumps(a)


def _wheel_state_nan(f):
    ws = f["globals/wheel_state"][:]
    ws[0] = np.nan
    f["globals/wheel_state"][:] = ws


TAMPERED = {
    "duplicate-ids": (_dup_ids, "more than once"),
    "nan-position": (_nan_position, "non-finite"),
    "hist_n-99": (_hist_n_99, "hist_n"),
    "globals-attrs-without-step": (_globals_attrs_without_step, "'step'"),
    "wheel-state-nan": (_wheel_state_nan, "wheel_state"),
}


@pytest.mark.parametrize("case", list(TAMPERED))
def test_consistently_tampered_epoch_is_refused(run_copy, case):
    edit, needle = TAMPERED[case]
    _tamper_current(run_copy, edit)
    assert cli_in_process("checkpoint", "verify", run_copy).returncode == 0  # the checksums do pass
    before = (run_copy / "MANIFEST.json").read_bytes()
    one_line_error(cli_in_process("resume", run_copy, "--steps", STEPS + 20, "--no-progress", "--no-figures"), needle)
    assert (run_copy / "MANIFEST.json").read_bytes() == before  # nothing committed over it
    if case in ("duplicate-ids", "globals-attrs-without-step", "wheel-state-nan", "hist_n-99"):
        one_line_error(cli_in_process("checkpoint", "hash", run_copy))
    if case in ("duplicate-ids", "globals-attrs-without-step", "wheel-state-nan"):
        one_line_error(cli_in_process("checkpoint", "export", run_copy, "--out", run_copy.parent / "x.csv"))


def test_missing_globals_group_is_refused(run_copy):
    def drop_globals(f):
        del f["globals"]

    m = _tamper_current(run_copy, drop_globals)
    m["current"]["globals"] = None
    (run_copy / "MANIFEST.json").write_text(json.dumps(m))
    one_line_error(cli_in_process("resume", run_copy, "--steps", STEPS + 20, "--no-progress"), "wheel_state")


HOSTILE_META = {
    "run-steps-string": (lambda meta: meta["run"].update(steps="many"), "'steps'"),
    "run-mode-list": (lambda meta: meta["run"].update(mode=["ooc"]), "'mode'"),
    "run-missing": (lambda meta: meta.pop("run"), "run options"),
    "run-domains-huge": (lambda meta: meta["run"].update(mode="ddm", domains=10**9), "'domains'"),
    "scenario-toml-garbage": (lambda meta: meta.update(scenario_toml="[[[ not toml"), "scenario"),
    "scenario-toml-not-a-string": (lambda meta: meta.update(scenario_toml={"a": 1}), "scenario"),
}


@pytest.mark.parametrize("case", list(HOSTILE_META))
def test_hostile_run_meta_is_refused(run_copy, case):
    edit, needle = HOSTILE_META[case]
    m = _manifest(run_copy)
    edit(m["meta"])
    (run_copy / "MANIFEST.json").write_text(json.dumps(m))
    one_line_error(cli_in_process("resume", run_copy, "--steps", STEPS + 20, "--no-progress"), needle)


def test_hostile_engine_attrs_are_refused(tmp_path):
    """A DDM epoch whose stored slab bounds are not a decomposition of its domains."""
    out = tmp_path / "ddm"
    run_cli(
        "run",
        "quick",
        "--out",
        out,
        "--mode",
        "ddm",
        "--domains",
        "3",
        "--steps",
        20,
        "--checkpoint-every",
        10,
        "--no-progress",
        "--no-figures",
        *sum((["--set", s] for s in WHEEL_TEST), []),
        check=True,
    )

    def bad_bounds(f):
        a = json.loads(f["globals"].attrs["ooc_dem_attrs"])
        a["engine"]["bounds"] = ["left", 0.2]
        f["globals"].attrs["ooc_dem_attrs"] = json.dumps(a)

    _tamper_current(out, bad_bounds)
    one_line_error(cli_in_process("resume", out, "--steps", 40, "--no-progress", "--no-figures"), "bounds")


# ------------------------------------------------------------------ export --out


def _export(store, out, *extra):
    return cli_in_process("checkpoint", "export", store, "--out", out, *extra)


def test_export_never_replaces_store_files(run_copy):
    m = _manifest(run_copy)
    targets = [
        run_copy / "MANIFEST.json",
        run_copy / m["current"]["path"],
        run_copy / "epochs" / "new.csv",
        run_copy / "final.vtk",
    ]
    for t in targets:
        before = t.read_bytes() if t.exists() else None
        one_line_error(_export(run_copy, t, "--format", "csv"), "store")
        assert (t.read_bytes() if t.exists() else None) == before, t
    # XDMF writes NAME.h5 beside NAME.xdmf: the .h5 sibling is checked too
    cur = run_copy / m["current"]["path"]
    before = cur.read_bytes()
    one_line_error(_export(run_copy, cur.with_suffix(".xdmf")), "store")
    assert cur.read_bytes() == before
    assert cli_in_process("checkpoint", "verify", run_copy).returncode == 0


def test_export_refuses_what_is_not_a_regular_file(run_copy, tmp_path):
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    target = tmp_path / "victim.txt"
    target.write_text("keep me")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    (tmp_path / "adir.csv").mkdir()
    cases = [fifo, link, tmp_path / "adir.csv"]
    if os.geteuid() == 0:  # a real device node, as /dev/null is (mknod needs root)
        dev = tmp_path / "null.csv"
        os.mknod(dev, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        cases.append(dev)
    for c in cases:
        mode = os.lstat(c).st_mode
        one_line_error(_export(run_copy, c, "--format", "csv"), str(c))
        assert os.lstat(c).st_mode == mode
    assert target.read_text() == "keep me"
    # an existing regular file outside any store is replaced, and gets ordinary permissions
    ok = tmp_path / "final.csv"
    ok.write_text("old")
    cp = _export(run_copy, ok)
    assert cp.returncode == 0, cp.stderr
    assert ok.read_text().startswith("#")
    assert stat.S_IMODE(ok.stat().st_mode) == 0o666 & ~_umask()
    assert not [p for p in tmp_path.iterdir() if ".tmp-" in p.name]


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


# ------------------------------------------------------------------ kills around the commits


@pytest.mark.slow
def test_resume_finishes_outputs_lost_after_the_final_commit(base_run, tmp_path):
    """A SIGKILL between the final commit and the outputs leaves exactly this: a committed final
    epoch and no (or a torn) summary.json, series.csv and figures."""
    summary = json.loads((base_run / "summary.json").read_text())
    series = (base_run / "series.csv").read_text()
    for damage in ("missing", "torn"):
        run = tmp_path / damage
        shutil.copytree(base_run, run)
        if damage == "missing":
            for f in ("summary.json", "series.csv"):
                (run / f).unlink()
            shutil.rmtree(run / "figures")
        else:
            (run / "summary.json").write_text((base_run / "summary.json").read_text()[:57])
            (run / "figures" / "deformation.png").unlink()
        cp = run_cli("resume", run, "--no-progress")
        assert cp.returncode == 0, cp.stderr
        assert "missing outputs" in cp.stdout
        got = json.loads((run / "summary.json").read_text())
        assert got["state_hash"] == summary["state_hash"]
        for key in ("slip", "net_traction", "gross_traction", "sinkage"):
            assert got[key] == summary[key], key
        assert (run / "series.csv").read_text() == series
        assert sorted(p.name for p in (run / "figures").iterdir()) == sorted(
            p.name for p in (base_run / "figures").iterdir()
        )
        assert run_cli("report", run).returncode == 0
        assert run_cli("compare", base_run, run).returncode == 0
    # a finished run with all its outputs: resume has nothing to do and writes nothing
    cp = run_cli("resume", base_run, "--no-progress")
    assert cp.returncode == 0 and "nothing to do" in cp.stdout


def test_run_stopped_before_its_first_commit_can_be_started_again(tmp_path):
    """The state a kill (or a full disk) leaves before the first commit: the store created with
    no committed epoch, and the run's set-up files. `resume` names the way out; `run --out` takes
    it; a directory holding anything else stays refused."""
    from ooc_dem.app.run import RunOptions, Simulation
    from ooc_dem.model.scenario import load_scenario
    from ooc_dem.storage import create_store

    sc = load_scenario("quick", WHEEL_TEST)
    out = tmp_path / "run"
    sim = Simulation(sc, out, RunOptions(steps=20, progress=False, figures=False))
    create_store(out, "hdf5", sim._meta()).close()
    (out / "scenario.toml").write_text(sc.to_toml())
    line = one_line_error(cli_in_process("resume", out, "--no-progress"), "no committed epoch")
    assert f"--out {out}" in line and "ooc-dem run" in line
    args = [
        "run",
        "quick",
        "--out",
        out,
        "--steps",
        20,
        "--no-progress",
        "--no-figures",
        *sum((["--set", s] for s in WHEEL_TEST), []),
    ]
    (out / "notes.txt").write_text("mine")  # a user's file: the directory is not ours
    one_line_error(cli_in_process(*args), "not empty")
    (out / "notes.txt").unlink()
    from ooc_dem.storage import open_store

    with open_store(out):  # a live run still setting up holds the store
        one_line_error(run_cli(*args), "another process is writing this store")
    cp = run_cli(*args)
    assert cp.returncode == 0, cp.stderr
    assert run_cli("checkpoint", "verify", out).returncode == 0
    assert _manifest(out)["current"]["step"] == 20
