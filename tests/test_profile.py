"""Memory profiler: real subprocesses, real RSS; out-of-core keeps one sub-domain resident."""

import pytest
import json


from support.cli import cli_in_process, run_cli
from ooc_dem.model.state import bytes_per_disc

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow


def test_profile_report(tmp_path):
    out = tmp_path / "prof"
    cp = run_cli(
        "profile",
        "bed-6000",
        "--modes",
        "monolithic,ddm,ooc",
        "--domains",
        "6",
        "--block",
        "4",
        "--steps",
        "8",
        "--out",
        out,
        check=True,
    )
    doc = json.loads((out / "memory.json").read_text())
    runs = {r["mode"]: r for r in doc["runs"]}
    assert set(runs) == {"monolithic", "ddm", "ooc"}
    # every mode computes the same state (the profile runs are real runs)
    assert len({r["state_hash"] for r in runs.values()}) == 1
    for r in runs.values():
        assert r["peak_rss_bytes"] >= r["baseline_rss_bytes"] > 50 * 2**20
        assert r["n_discs"] == 6000 and r["theoretical_state_bytes"] == 6000 * bytes_per_disc(2)
        assert len(r["rss_series"]) >= 2
        assert r["peak_reset_ok"] is True
    assert runs["monolithic"]["resident_discs_max"] == 6000
    # six slabs of ~1000 discs plus halos of 4 hops: far fewer than the whole bed resident
    assert runs["ooc"]["resident_discs_max"] < 6000 / 2
    assert runs["ooc"]["above_baseline_ratio_to_monolithic"] is not None
    md = (out / "memory.md").read_text()
    assert "| monolithic |" in md and "ooc/hdf5" in md
    assert (out / "memory.png").read_bytes()[:4] == b"\x89PNG"
    assert "x monolithic" in cp.stdout


def test_profile_bad_mode(tmp_path):
    cp = cli_in_process("profile", "bed-6000", "--modes", "monolithic,turbo", "--out", tmp_path / "p")
    assert cp.returncode == 2 and "--modes" in cp.stderr and len(cp.stderr.strip().splitlines()) == 1


def test_memsweep_stops_monolithic_at_its_limit(tmp_path):
    """tools/memsweep.py: monolithic runs only up to --monolithic-max, out-of-core goes on at a
    fixed slab size (D = ceil(N / slab)); JSON and PNG written, slopes fitted per mode."""
    import subprocess
    import sys
    from pathlib import Path

    tool = Path(__file__).resolve().parents[1] / "tools" / "memsweep.py"
    cp = subprocess.run(
        [
            sys.executable,
            str(tool),
            "--sizes",
            "1000,2000,3000",
            "--slab-discs",
            "1000",
            "--monolithic-max",
            "2000",
            "--steps",
            "2",
            "--out",
            str(tmp_path / "m"),
        ],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert cp.returncode == 0, cp.stderr[-3000:]
    doc = json.loads((tmp_path / "m" / "memsweep.json").read_text())
    seen = sorted((r["mode"], r["n_discs"]) for r in doc["runs"])
    assert seen == [("monolithic", 1000), ("monolithic", 2000), ("ooc", 1000), ("ooc", 2000), ("ooc", 3000)]
    assert {r["n_discs"]: r["resident_discs_max"] < r["n_discs"] for r in doc["runs"] if r["mode"] == "ooc"} == {
        1000: False,
        2000: True,
        3000: True,
    }
    assert set(doc["fits"]) == {"monolithic", "ooc", "ooc_over_monolithic_slope"}
    assert (tmp_path / "m" / "memsweep.png").stat().st_size > 10_000
