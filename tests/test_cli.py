"""CLI behaviour: bad input is one line on stderr, exit code 2, no traceback."""

import json

import pytest

from support.cli import cli_in_process, run_cli

BAD_INPUTS = [
    (["run", "no-such-scenario"], "no-such-scenario"),
    (["run", "quick", "--set", "physics.dt=1e-3"], "physics.dt"),
    (["run", "quick", "--set", "contact.soil_soil.kn=-1"], "contact.soil_soil.kn"),
    (["run", "quick", "--set", "contact.soil_wall.friction=-0.2"], "contact.soil_wall.friction"),
    (["run", "quick", "--set", "soil.colour=3"], "soil.colour"),
    (["run", "quick", "--set", "physics.dt=fast"], "physics.dt"),
    (["run", "quick", "--set", "soil.n=12.5"], "soil.n"),
    (["run", "quick", "--set", "soil.r_max=0.001"], "soil.r_max"),
    (["run", "quick", "--set", "wheel.control=teleport"], "wheel.control"),
    (["run", "quick", "--set", "wheel.x0=5.0"], "wheel.x0"),
    (["run", "quick", "--set", "physicsdt"], "physicsdt"),
    (["run", "quick", "--mode", "gpu"], "--mode"),
    (["run", "quick", "--domains", "0"], "--domains"),
    (["run", "quick", "--steps", "-5"], "--steps"),
    (["run", "quick", "--duration", "nan"], "--duration"),
    (["run", "bed-12x"], "bed-12x"),
    (["sweep", "quick", "--slips", "0.1,abc", "--out", "x"], "--slips"),
    (["sweep", "quick", "--slips=-1.5,0.2", "--out", "x"], "each slip must be in [-1, 1)"),
    (["run", "quick", "--set", "wheel.control=towed"], "wheel.speed"),
    (["frobnicate"], "frobnicate"),
]


@pytest.mark.parametrize("args,needle", BAD_INPUTS, ids=[" ".join(a) for a, _ in BAD_INPUTS])
def test_bad_input_one_line_exit_2(args, needle, tmp_path):
    cp = cli_in_process(*args)
    assert cp.returncode == 2, cp.stderr
    lines = [ln for ln in cp.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, cp.stderr
    assert "Traceback" not in cp.stderr
    assert needle in lines[0]


def test_bad_scenario_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[physics\ndt = 1")
    cp = cli_in_process("run", bad)
    assert cp.returncode == 2 and "invalid TOML" in cp.stderr and len(cp.stderr.strip().splitlines()) == 1
    wrong = tmp_path / "wrong.toml"
    wrong.write_text('[physics]\ndt = "soon"\n')
    cp = cli_in_process("run", wrong)
    assert cp.returncode == 2 and "physics.dt" in cp.stderr


def test_out_dir_not_empty_is_refused_and_kept(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "precious.txt").write_text("keep me")
    cp = cli_in_process("run", "bed-1000", "--out", out, "--steps", "10")
    assert cp.returncode == 2 and "not empty" in cp.stderr
    assert (out / "precious.txt").read_text() == "keep me"


def test_foreign_store_refused(tmp_path):
    d = tmp_path / "foreign"
    d.mkdir()
    (d / "data.bin").write_bytes(b"\0" * 10)
    for cmd in (["checkpoint", "hash", d], ["resume", d], ["checkpoint", "verify", d]):
        cp = cli_in_process(*cmd)
        assert cp.returncode == 2, cmd
        assert len(cp.stderr.strip().splitlines()) == 1 and "Traceback" not in cp.stderr


def test_scenarios_lists_builtins():
    cp = cli_in_process("scenarios", check=True)
    for name in ("paper2008", "quick", "bed-N"):
        assert name in cp.stdout


def test_bed_run_and_hash_reproducible(tmp_path):
    """Two identical runs give the same `checkpoint hash`; summary and epochs are written."""
    a, b = tmp_path / "a", tmp_path / "b"
    run_cli("run", "bed-1200", "--out", a, "--steps", "200", "--no-progress", check=True)
    run_cli("run", "bed-1200", "--out", b, "--steps", "200", "--no-progress", check=True)
    ha = cli_in_process("checkpoint", "hash", a, check=True).stdout.strip()
    hb = cli_in_process("checkpoint", "hash", b, check=True).stdout.strip()
    assert ha.startswith("mset-v2:") and len(ha) == 8 + 64 and ha == hb
    summary = json.loads((a / "summary.json").read_text())
    assert summary["steps"] == 200 and summary["n_discs"] == 1200 and summary["state_hash"] == ha
    lst = cli_in_process("checkpoint", "list", a, check=True).stdout
    assert "200" in lst
    assert "OK" in cli_in_process("checkpoint", "verify", a, check=True).stdout


def test_prepare_then_run_with_bed(tmp_path):
    bed = tmp_path / "bed"
    cp = run_cli("prepare", "bed-1200", "--out", bed, "--no-progress", check=True)
    info = json.loads(cp.stdout.strip().splitlines()[-1])
    assert info["n_discs"] == 1200 and 0.08 < info["surface_height_m"] < 0.21  # two 0.1 m tiles, one nearly empty
    out = tmp_path / "run"
    run_cli("run", "bed-1200", "--bed", bed, "--out", out, "--steps", "50", "--no-progress", check=True)
    cp = cli_in_process("run", "bed-2000", "--bed", bed, "--out", tmp_path / "x", "--steps", "5")
    assert cp.returncode == 2 and "1200" in cp.stderr
