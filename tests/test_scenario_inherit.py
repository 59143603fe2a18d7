"""Scenario files that inherit (``base = ...``), `scenarios --show`, "did you mean" and the
generated parameter reference (docs/parameters.md). All fast: no bed, no stepping."""

import json
import tomllib
from pathlib import Path

import pytest

from ooc_dem.model.scenario import ScenarioError, builtin_names, load_scenario
from ooc_dem.model.scenario_doc import every_key
from support.cli import cli_in_process, one_line_error

ROOT = Path(__file__).resolve().parent.parent
BUILTINS = [n for n in builtin_names() if not n.endswith("-N")] + ["bed-7000", "bed3d-20000"]

# the built-ins' scenario hashes before inheritance existed: they must not move
PINNED = {
    "bed": "d8cc783f3a647bf6bbbaa093b122236870a62d98561eb552a329174f80596ede",
    "bed3d": "27011f19eb1e8cc997b6e3b0b325d3db6b61ba960196dcd999bc8e67bd36998f",
    "paper2008": "1846ad705fe9ddfbdb01b7b8939ee51930d1e53c526cc6bbaec6023b33e5eabe",
    "paper2008-3d": "43673e473dd94c08ffe852353d22079b8f2636ede4734edabd423acfd596b62a",
    "quick": "b61a6bd91d1e6cd25e2ba91a614985b0a4a52a19dd4f7c08bba045854a3017e0",
    "quick-3d": "8a7dce0a428961c59a12c6d538d2b517cb159b1505f8689bcc57ef41b1c5d5e0",
    "repose2d": "2a8b9ee0d3e6e05eda81591f9cd3c9bf84a119c4db897dd01e13b42e1e5895ae",
    "repose3d": "6e54dccb6c70999a7914c8a5af409abee692cbdfb2e2a29d52943470dc78ba59",
    "bed-7000": "1d3da681acece57352fc3e9d608f3161a8a5b51a052465d35ea77e47db51e3fe",
    "bed3d-20000": "1c7b3674c4313c78a027e2a77d39be0c034e2583fad2cc96bda6973ad154a0d6",
}


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_hashes_do_not_move(name):
    assert load_scenario(name).hash() == PINNED[name]


def test_a_base_and_one_key_is_the_builtin_with_that_key_set(tmp_path):
    f = _write(tmp_path / "heavier.toml", 'base = "quick-3d"\n\n[wheel]\nload = 25.0\n')
    mine, theirs = load_scenario(f), load_scenario("quick-3d", ["wheel.load=25.0"])
    assert mine == theirs and mine.hash() == theirs.hash() and mine.bed_hash() == theirs.bed_hash()
    # the CLI's check prints the same scenario_hash for both
    a = json.loads(cli_in_process("check", f, check=True).stdout)["scenario_hash"]
    b = json.loads(cli_in_process("check", "quick-3d", "--set", "wheel.load=25.0", check=True).stdout)["scenario_hash"]
    assert a == b == theirs.hash()


def test_chains_of_files_resolve_relative_to_the_file_naming_them(tmp_path):
    _write(tmp_path / "lib" / "soft.toml", 'base = "quick"\n[contact.soil_soil]\nfriction = 0.3\n')
    _write(tmp_path / "lib" / "longer.toml", 'base = "soft.toml"\n[wheel]\ntravel_time = 3.0\n')
    top = _write(tmp_path / "runs" / "mine.toml", 'base = "../lib/longer.toml"\n[scenario]\nname = "mine"\n')
    sc = load_scenario(top)
    want = load_scenario("quick", ["contact.soil_soil.friction=0.3", "wheel.travel_time=3.0", "scenario.name=mine"])
    assert sc == want and sc.hash() == want.hash()
    assert sc.contact.soil_soil.rolling_friction == 0.1  # the rest of the pair's table is the base's


def test_nested_tables_merge_key_by_key_as_set_does(tmp_path):
    # the linear law's damping is one of restitution and damping_n: the file's replaces the base's
    f = _write(tmp_path / "a.toml", 'base = "quick-3d"\n[contact.soil_wall]\nrestitution = 0.4\n')
    assert load_scenario(f) == load_scenario("quick-3d", ["contact.soil_wall.restitution=0.4"])
    # a grading of another kind replaces the base's table; of the same kind it merges
    g1 = _write(
        tmp_path / "g1.toml",
        'base = "quick"\n[soil.grading]\nkind = "sieve"\nsizes = [0.0036, 0.0044]\npassing = [0.0, 100.0]\n',
    )
    g2 = _write(
        tmp_path / "g2.toml", 'base = "g1.toml"\n[soil.grading]\nkind = "normal"\nr_mean = 0.002\nr_std = 1e-4\n'
    )
    g3 = _write(
        tmp_path / "g3.toml", 'base = "g1.toml"\n[soil.grading]\npassing = [0.0, 100.0]\nsizes = [0.0037, 0.0044]\n'
    )
    assert (
        load_scenario(g2).soil.grading
        == load_scenario(
            "quick", ["soil.grading.kind=normal", "soil.grading.r_mean=0.002", "soil.grading.r_std=1e-4"]
        ).soil.grading
    )
    assert load_scenario(g1).soil.grading.kind == "sieve"
    assert load_scenario(g3).soil.grading.kind == "sieve" and load_scenario(g3).soil.grading.sizes == (0.0037, 0.0044)
    # a material's preset drops the base's own elastic constants of that body
    m1 = _write(
        tmp_path / "m1.toml", 'base = "quick-3d"\n[materials.wheel]\nyoungs_modulus = 1e9\npoisson_ratio = 0.25\n'
    )
    m2 = _write(tmp_path / "m2.toml", 'base = "m1.toml"\n[materials.wheel]\npreset = "glass"\n')
    direct = _write(tmp_path / "m3.toml", 'base = "quick-3d"\n[materials.wheel]\npreset = "glass"\n')
    assert load_scenario(m2) == load_scenario(direct) != load_scenario(m1)


def test_a_cycle_and_a_missing_base_are_one_line(tmp_path):
    _write(tmp_path / "a.toml", 'base = "b.toml"\n')
    _write(tmp_path / "b.toml", 'base = "a.toml"\n')
    one_line_error(cli_in_process("check", tmp_path / "a.toml"), "cycle", "a.toml -> b.toml -> a.toml")
    _write(tmp_path / "self.toml", 'base = "self.toml"\n')
    one_line_error(cli_in_process("check", tmp_path / "self.toml"), "cycle")
    _write(tmp_path / "typo.toml", 'base = "quik-3d"\n')
    one_line_error(cli_in_process("check", tmp_path / "typo.toml"), "base = 'quik-3d'", "did you mean 'quick-3d'?")
    _write(tmp_path / "gone.toml", 'base = "nowhere/x.toml"\n')
    one_line_error(cli_in_process("check", tmp_path / "gone.toml"), "base = 'nowhere/x.toml'", "no such file")
    _write(tmp_path / "num.toml", "base = 3\n")
    one_line_error(cli_in_process("check", tmp_path / "num.toml"), "base = 3", "a string")
    _write(tmp_path / "late.toml", '[physics]\nbase = "quick"\n')
    one_line_error(cli_in_process("check", tmp_path / "late.toml"), "physics.base", "top of the file")


@pytest.mark.parametrize(
    "args,needles",
    [
        (["check", "quikc"], ["'quikc'", "did you mean 'quick'?"]),
        (["check", "quick", "--set", "wheel.lod=3"], ["wheel.lod", "did you mean 'load'?"]),
        (["check", "quick", "--set", "wheell.load=3"], ["wheell", "unknown section", "did you mean 'wheel'?"]),
        (["check", "quick", "--set", "contact.soil_sol.kn=1"], ["contact.soil_sol", "did you mean 'soil_soil'?"]),
        (["check", "quick", "--mode", "oc"], ["--mode", "did you mean 'ooc'?"]),
        (["chek", "quick"], ["'chek'", "did you mean 'check'?"]),
    ],
)
def test_did_you_mean(args, needles):
    one_line_error(cli_in_process(*args), *needles)


def test_did_you_mean_in_a_file(tmp_path):
    f = _write(tmp_path / "k.toml", 'base = "quick"\n[soil]\ndensty = 2000.0\n')
    one_line_error(cli_in_process("check", f), "soil.densty", "did you mean 'density'?")
    f = _write(tmp_path / "m.toml", 'base = "quick-3d"\n[materials.whel]\nfriction = 0.3\n')
    one_line_error(cli_in_process("check", f), "materials.whel", "did you mean 'wheel'?")


@pytest.mark.parametrize("name", BUILTINS)
def test_show_prints_every_key_and_loads_back(name, tmp_path):
    cp = cli_in_process("scenarios", "--show", name, check=True)
    f = _write(tmp_path / "shown.toml", cp.stdout)
    assert load_scenario(f).hash() == load_scenario(name).hash() == PINNED[name]
    data = tomllib.loads(cp.stdout)
    sc = load_scenario(name)
    for info in every_key(sc):
        node = data
        for part in info.table.split("."):
            node = node[part]
        if info.default is None:  # an unset optional key: a commented-out line
            assert f"# {info.name} = (unset)" in cp.stdout, info.path
        else:
            assert info.name in node, info.path
    for line in cp.stdout.splitlines():
        if "=" in line and not line.startswith("#"):
            assert "  # " in line, line  # every key has its comment


def test_every_key_is_documented():
    for info in every_key():
        assert info.meaning and info.allowed, info.path


def test_a_base_file_is_refused_where_its_values_are(tmp_path):
    f = _write(tmp_path / "bad.toml", 'base = "quick"\n[physics]\ndt = 1e-3\n')
    with pytest.raises(ScenarioError, match="physics.dt"):
        load_scenario(f)
