"""The Python API (`import ooc_dem`): the README's example run for real, overrides checked as
`--set` is, resume equal to an uninterrupted run, typed errors, read-only stores, docs kept current."""

import json
import os
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

import ooc_dem
from support.cli import cli_in_process, run_cli
from support.runs import WHEEL_TEST

ROOT = Path(__file__).resolve().parent.parent
# a short wheel run (0.1 s settling, 0.4 s travel) as an overrides mapping
SHORT = {k: float(v) for k, v in (item.split("=") for item in WHEEL_TEST)}


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def readme_example() -> str:
    """The first ```python block of the README's "Python API" section."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("\n## Python API\n", 1)[1].split("\n## ", 1)[0]
    m = re.search(r"```python\n(.*?)```", section, re.S)
    assert m, "README's Python API section has no ```python block"
    return m.group(1)


# ----------------------------------------------------------------- the README example


@pytest.mark.slow
def test_readme_example_runs(tmp_path):
    code = readme_example()
    assert len(code.strip().splitlines()) <= 10, "the notebook example should stay ten lines"
    t0 = time.time()
    cp = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=600
    )
    wall = time.time() - t0
    assert cp.returncode == 0, cp.stderr[-3000:]
    assert cp.stderr.strip() == "", f"the API printed on stderr (progress bar?): {cp.stderr[-2000:]}"
    out = cp.stdout
    m = re.search(r"slip (\S+) net traction \[N\] (\S+)", out)
    assert m, out
    slip, net = float(m.group(1)), float(m.group(2))
    assert 0.0 < slip < 1.0 and np.isfinite(net), out
    assert "'net_traction'" in out and "rows:" in out, out
    run_dir = tmp_path / "runs" / "quick-short"
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["slip"]["whole_travel"]["value"] == pytest.approx(slip, rel=1e-12)
    assert "(1500,)" in out  # every state array has one row per disc
    assert "9 trajectory frames" in out  # t = 0, 0.05, ..., 0.4 s
    print(f"README example: {wall:.1f} s")


def test_readme_relative_links_resolve():
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        text = doc.read_text(encoding="utf-8")
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            path = (doc.parent / target.split("#", 1)[0]).resolve()
            assert path.exists() and path.is_relative_to(ROOT), f"{doc.relative_to(ROOT)}: {target}"
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "shared/" not in readme and "DESIGN section" not in readme


# ------------------------------------------------------------------ surface and docs


def test_version_one_source():
    cp = run_cli("--version")
    assert cp.returncode == 0 and cp.stdout == f"ooc-dem {ooc_dem.__version__}\n", (cp.stdout, cp.stderr)
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "ooc_dem.__version__"}


def test_import_is_cheap_and_help_is_useful():
    code = (
        "import sys, pydoc, ooc_dem\n"
        "heavy = [m for m in ('numpy', 'numba', 'h5py', 'zarr', 'matplotlib') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
        "print(pydoc.render_doc(ooc_dem, renderer=pydoc.plaintext))\n"
    )
    cp = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=300)
    assert cp.returncode == 0, cp.stderr[-2000:]
    for name in (
        "load_scenario",
        "run(",
        "resume(",
        "open_store",
        "RunResult",
        "state(self, epoch",
        "ScenarioError",
        "StoreError",
    ):
        assert name in cp.stdout, name


def test_public_names_documented():
    for name in ooc_dem.__all__:
        if name.startswith("__"):
            continue
        obj = getattr(ooc_dem, name)
        assert (obj.__doc__ or "").strip() or name == "BedError", f"ooc_dem.{name} has no docstring"
    for name in ("summary", "series", "series_frame", "epochs", "state"):
        assert getattr(ooc_dem.RunResult, name).__doc__, name


def test_override_forms_agree():
    flat = ooc_dem.load_scenario(
        "quick",
        {
            "wheel.slip": 0.3,
            "contact.soil_soil.kn": 1.5e5,
            "wheel.control": "slip",
            "wheel.n_lugs": 12,
            "wheel.enabled": True,
        },
    )
    nested = ooc_dem.load_scenario(
        "quick",
        {
            "wheel": {"slip": 0.3, "control": "slip", "n_lugs": 12, "enabled": True},
            "contact": {"soil_soil": {"kn": 1.5e5}},
        },
    )
    cli = ooc_dem.load_scenario(
        "quick", ["wheel.slip=0.3", "contact.soil_soil.kn=1.5e5", "wheel.control=slip", "wheel.n_lugs=12"]
    )
    assert flat == nested == cli
    assert flat.wheel.slip == 0.3 and flat.contact.soil_soil.kn == 1.5e5 and flat.wheel.n_lugs == 12
    assert (
        ooc_dem.load_scenario(Path(ROOT / "ooc_dem" / "scenarios" / "quick.toml")).hash()
        == ooc_dem.load_scenario("quick").hash()
    )
    assert ooc_dem.load_scenario("quick", {"soil.seed": np.int64(3)}).soil.seed == 3


# the same value through --set and through overrides: the same one-line message
SAME_AS_CLI = [
    ("wheel.slip", 2.0, "2.0"),
    ("physics.dt", 1e-3, "1e-3"),
    ("soil.n", 12.5, "12.5"),
    ("wheel.control", "teleport", "teleport"),
    ("soil.colour", 3, "3"),
    ("physics.dt", "fast", "fast"),
    ("contact.soil_wall.friction", -0.2, "-0.2"),
]


@pytest.mark.parametrize("key,value,text", SAME_AS_CLI, ids=[k for k, _, _ in SAME_AS_CLI])
def test_override_errors_match_cli(key, value, text):
    with pytest.raises(ooc_dem.ScenarioError) as ei:
        ooc_dem.load_scenario("quick", {key: value})
    msg = str(ei.value)
    assert "\n" not in msg and key in msg
    cp = cli_in_process("check", "quick", "--set", f"{key}={text}")
    assert cp.returncode == 2
    assert cp.stderr.strip() == f"ooc-dem: error: {msg}"


@pytest.mark.parametrize(
    "overrides,needle",
    [
        ({"wheel.slip=1": 2}, "wheel.slip=1"),
        ({"wheel": 3}, "wheel"),
        ({"physicsdt": 1}, "physicsdt"),
        ({"wheel.slip": [0.1]}, "wheel.slip"),
        ({"wheel.slip": None}, "wheel.slip"),
        ({"physics.dt": float("nan")}, "physics.dt"),
        ({"physics.dt": float("inf")}, "physics.dt"),
        ({3: 1}, "3"),
        ("wheel.slip=0.3", "overrides"),
        (["wheel.slip"], "wheel.slip"),
    ],
)
def test_override_refusals_are_one_line(overrides, needle):
    with pytest.raises(ooc_dem.ScenarioError) as ei:
        ooc_dem.load_scenario("quick", overrides)
    msg = str(ei.value)
    assert "\n" not in msg and needle in msg and "--set" not in msg, msg


def test_unknown_scenario_is_typed():
    with pytest.raises(ooc_dem.ScenarioError, match="no-such-scenario"):
        ooc_dem.load_scenario("no-such-scenario")


# ------------------------------------------------------------------------------- runs


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """One short wheel run through the API (shared by the read-only tests)."""
    out = tmp_path_factory.mktemp("api") / "run"
    res = ooc_dem.run("quick", out=out, overrides=SHORT, steps=3000, checkpoint_every=1000)
    return res


def test_run_result(short_run):
    res = short_run
    assert res.path.is_dir() and res.summary["steps"] == 3000
    assert res.summary == json.loads((res.path / "summary.json").read_text())
    s = res.series
    assert s.dtype.names[:2] == ("t", "t_travel") and "net_traction" in s.dtype.names
    assert len(s) > 0 and np.all(np.diff(s["t"]) > 0)
    assert res.epochs() == [2000, 3000]
    cur, prev = res.state(), res.state(2000)
    assert np.array_equal(cur["id"], np.arange(1500)) and np.array_equal(prev["id"], cur["id"])
    assert all(len(a) == 1500 for a in cur.values())
    assert not np.array_equal(cur["vel"], prev["vel"])
    reread = ooc_dem.open_run(res.path)
    assert reread.summary == res.summary
    for c in res.series.dtype.names:
        assert np.array_equal(reread.series[c], res.series[c], equal_nan=True), c
    assert not (res.path / "figures").exists()  # figures only when asked for


def test_state_of_missing_epoch_raises(short_run):
    with pytest.raises(ooc_dem.StoreError, match=r"epoch 12345 is not in the manifest"):
        short_run.state(12345)
    with pytest.raises(ooc_dem.StoreError):
        ooc_dem.open_run(short_run.path.parent).state()  # not a store


def test_series_frame(short_run, monkeypatch):
    # pandas comes with the test extra: the real frame, then the message without it
    df = short_run.to_pandas()
    assert list(df.columns) == list(short_run.series.dtype.names) and len(df) == len(short_run.series)
    assert np.array_equal(df["t"].to_numpy(), short_run.series["t"])
    monkeypatch.setitem(sys.modules, "pandas", None)  # as if pandas were not installed
    with pytest.raises(ImportError, match=r"pip install pandas"):
        short_run.to_pandas()


def _tree(path: Path) -> dict:
    return {
        str(p.relative_to(path)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in sorted(path.rglob("*"))
        if p.is_file()
    }


def test_open_store_is_read_only(short_run):
    before = _tree(short_run.path)
    with ooc_dem.open_store(short_run.path) as store:
        assert store.epochs() == [2000, 3000] and store.current() == 3000
        assert store.verify() == []
        r = store.read_epoch(2000)
        assert sorted(r.domains()) == [0]
        r.close()
        with pytest.raises(ooc_dem.StoreError):
            store.begin_epoch(4000)
        with pytest.raises(ooc_dem.StoreError):
            store.prune(1)
        after = _tree(short_run.path)
        from ooc_dem.storage import open_store as open_for_writing

        writer = open_for_writing(short_run.path, repair=True)  # no lock held by the reader
        writer.close()
    assert after == before
    with pytest.raises(ooc_dem.StoreError):
        ooc_dem.open_store(short_run.path / "epochs")


@pytest.mark.slow
def test_resume_of_stopped_run_equals_uninterrupted(tmp_path):
    whole = ooc_dem.run("quick", out=tmp_path / "whole", overrides=SHORT, steps=4000, checkpoint_every=1000)
    part = ooc_dem.run(
        "quick", out=tmp_path / "part", mode="ddm", domains=3, overrides=SHORT, steps=1500, checkpoint_every=1000
    )
    assert part.summary["steps"] == 1500
    resumed = ooc_dem.resume(part.path, steps=4000)
    assert resumed.summary["steps"] == 4000
    a, b = whole.state(), resumed.state()
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), f"state array {k!r} differs"
    assert whole.summary["state_hash"] == resumed.summary["state_hash"]
    for c in whole.series.dtype.names:
        assert np.array_equal(whole.series[c], resumed.series[c], equal_nan=True), c
    again = ooc_dem.resume(part.path)  # finished: nothing to do, the same result
    assert again.summary["state_hash"] == whole.summary["state_hash"]


def test_run_errors_are_typed_and_touch_nothing(tmp_path, short_run):
    sc = ooc_dem.load_scenario("quick", SHORT)
    with pytest.raises(ooc_dem.RunError, match=r"--mode 'gpu'"):
        ooc_dem.run(sc, out=tmp_path / "x", mode="gpu")
    assert not (tmp_path / "x").exists()
    with pytest.raises(ooc_dem.RunError, match="steps and duration"):
        ooc_dem.run(sc, out=tmp_path / "x", steps=10, duration=0.1)
    with pytest.raises(ooc_dem.ScenarioError, match="overrides"):
        ooc_dem.run(sc, out=tmp_path / "x", overrides={"wheel.slip": 0.1})
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "precious.txt").write_text("keep me")
    with pytest.raises(ooc_dem.RunError, match="not empty"):
        ooc_dem.run(sc, out=busy, steps=10)
    assert [p.name for p in busy.iterdir()] == ["precious.txt"]
    with pytest.raises(ooc_dem.RunError):
        ooc_dem.resume(busy)
    with pytest.raises(ooc_dem.RunFileError):
        ooc_dem.open_run(tmp_path / "nowhere")


def test_memory_backend_and_bare_bed(tmp_path):
    res = ooc_dem.run("bed-1000", out=tmp_path / "bed", backend="memory", steps=20)
    assert res.summary["steps"] == 20 and "slip" not in res.summary
    assert len(res.series) == 0 and "slip" in res.series.dtype.names
    st = res.state()
    assert np.array_equal(st["id"], np.arange(1000))
    from ooc_dem.storage import drop_memory_store

    drop_memory_store(res.path)


# files another branch is rewriting: their `DESIGN section N` comments move to docs/design.md at merge
PENDING_DOC_REFS: set[str] = set()


def test_no_references_to_files_that_do_not_ship():
    """Code and docs point at docs/..., never at ../shared/ or the old "DESIGN section N"."""
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True)
    if tracked.returncode != 0:
        pytest.skip("not a git checkout")
    bad = []
    for rel in tracked.stdout.split():
        if rel in PENDING_DOC_REFS or rel == "tests/test_api.py" or not rel.endswith((".py", ".md", ".toml")):
            continue
        text = (ROOT / rel).read_text(encoding="utf-8", errors="replace")
        for n, line in enumerate(text.splitlines(), 1):
            if "shared/reference" in line or "DESIGN section" in line or "../shared" in line:
                bad.append(f"{rel}:{n}")
    assert not bad, bad
