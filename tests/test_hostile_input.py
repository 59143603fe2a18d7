"""Hostile input: every bad scenario value, flag or file is ONE line on stderr naming
the offending key, flag or file, exit code 2, no traceback, nothing committed lost.

Refusals run `ooc-dem` in-process (support.cli.cli_in_process: the same `main()`, no interpreter
start each); real subprocesses (support.cli.run_cli) run the simulations and the refusals whose
point is the process (a bed larger than memory). The systematic sweep over every scenario key
calls `main()` directly (hundreds of `check`s).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil

import numpy as np
import psutil
import pytest

from support.cli import cli_in_process, error_lines, one_line_error, run_cli
from support.runs import WHEEL_TEST

from ooc_dem import cli
from ooc_dem.model.schema import Scenario, dict_to_toml

EMOJI = "r\U0001f600n"
MAX_STEPS = 10**10  # the documented maximum step count


def toml_string(text: str) -> str:
    """A TOML basic string (escapes only what TOML requires), to pass any text through --set."""
    special = {'"': '\\"', "\\": "\\\\"}
    return (
        '"'
        + "".join(special.get(c) or (f"\\u{ord(c):04X}" if ord(c) < 0x20 or ord(c) == 0x7F else c) for c in text)
        + '"'
    )


@pytest.fixture(scope="module")
def finished_wheel_run(tmp_path_factory):
    """A finished short wheel run (series, summary, initial.npz, store) to copy and damage."""
    out = tmp_path_factory.mktemp("wheel") / "run"
    args = [a for kv in WHEEL_TEST for a in ("--set", kv)]
    run_cli("run", "quick", *args, "--steps", "600", "--out", out, "--no-progress", "--no-figures", check=True)
    return out


@pytest.fixture
def wheel_run_copy(finished_wheel_run, tmp_path):
    dst = tmp_path / "run"
    shutil.copytree(finished_wheel_run, dst)
    return dst


@pytest.fixture(scope="module")
def finished_bed_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bed") / "run"
    run_cli("run", "bed-1200", "--steps", "10", "--out", out, "--no-progress", check=True)
    return out


# ------------------------------------------------------------------ A. memory


def test_step_count_beyond_the_maximum_is_refused_by_the_flag(tmp_path):
    # today `--steps 1000000000000000` sizes the series for every step up front (189 TiB)
    for steps in ("1000000000000000", "100000000000", "1e11", "1e30"):
        cp = cli_in_process("run", "quick", "--steps", steps, "--out", tmp_path / "o", "--no-progress")
        one_line_error(cp, "--steps", "1e10")
        assert not (tmp_path / "o").exists()


def test_series_buffer_is_sized_by_the_rows_kept_not_the_step_count(monkeypatch):
    """--steps 1e9 must not allocate 1e9 / steps_per_row rows up front; the grown buffer gives
    the same bits as one sized for the whole run."""
    from ooc_dem.app import metrics
    from ooc_dem.engine.stepper import N_REC, REC_T, REC_X, REC_VX, REC_WZ, REC_FX, REC_Y
    from ooc_dem.model.scenario import load_scenario

    sc = load_scenario("quick", ["output.series_interval=1e-5"])  # one row per step
    assert metrics.WheelMetrics(sc, 0.05, 10**9).rows.nbytes < 1 << 20
    rng = np.random.default_rng(3)
    rec = rng.normal(size=(3 * metrics.SERIES_START_ROWS + 7, N_REC))
    rec[:, REC_T] = np.arange(len(rec)) * sc.physics.dt
    for col in (REC_X, REC_VX, REC_WZ, REC_FX, REC_Y):
        rec[:, col] = rng.uniform(0.1, 1.0, len(rec))
    grown = metrics.WheelMetrics(sc, 0.05, len(rec))
    for a in range(0, len(rec), 500):
        grown.add(rec[a : a + 500], a)
    monkeypatch.setattr(metrics, "SERIES_START_ROWS", 10**6)
    whole = metrics.WheelMetrics(sc, 0.05, len(rec))
    whole.add(rec, 0)
    assert grown.series().shape == (len(rec), len(metrics.SERIES_COLUMNS))
    assert np.array_equal(grown.series(), whole.series(), equal_nan=True)
    assert grown.summary() == whole.summary()


def test_bed_larger_than_memory_refused_before_allocating(tmp_path):
    total = psutil.virtual_memory().total
    out = tmp_path / "o"
    line = one_line_error(run_cli("run", "bed-2000000000", "--out", out), "soil.n", "memory", "this machine has")
    assert not out.exists()
    # monolithic needs ~1 kB a disc: a billion discs never fit; the message offers out-of-core
    # when that would fit here
    line = one_line_error(run_cli("run", "bed-1000000000", "--out", out), "soil.n", "memory")
    if total > 20e9:
        assert "--mode ooc" in line
    one_line_error(
        run_cli("run", "quick", "--set", "soil.n=2000000000", "--mode", "ddm", "--out", out), "soil.n", "memory"
    )
    one_line_error(run_cli("prepare", "bed-2000000000", "--out", out), "soil.n", "memory")
    assert not out.exists()


# ------------------------------------------------------------------ B. domains


def test_domains_and_block_flags_bounded_like_the_scenario(tmp_path):
    one_line_error(
        cli_in_process("run", "quick", "--mode", "ddm", "--domains", "5000", "--out", tmp_path / "o", timeout=120),
        "--domains",
        "4096",
    )
    one_line_error(
        cli_in_process("run", "quick", "--mode", "ooc", "--block", "20000", "--out", tmp_path / "o", timeout=120),
        "--block",
        "10000",
    )


def test_more_domains_than_the_bed_holds_refused_naming_the_maximum(tmp_path):
    # 1500 discs in 0.4 m: at most 75 slabs of >= 20 discs (1000 took 110 s a step)
    line = one_line_error(
        cli_in_process("run", "quick", "--mode", "ddm", "--domains", "1000", "--out", tmp_path / "o", timeout=120),
        "--domains 1000",
        "at most 75",
    )
    one_line_error(
        cli_in_process(
            "run", "quick", "--mode", "ooc", "--set", "decomposition.domains=500", "--out", tmp_path / "o", timeout=120
        ),
        "decomposition.domains",
        "at most 75",
    )
    assert not (tmp_path / "o").exists(), line
    plan = json.loads(cli_in_process("check", "quick", "--mode", "ddm", "--domains", "75", check=True).stdout)
    assert plan["domains"] == 75


# ------------------------------------------------------------------ C. extreme numbers

EXTREME_RUNS = [
    (["--set", "soil.r_min=1e-200"], "soil.r_min"),
    (["--set", "physics.dt=5e-324"], "physics.dt"),
    (["--set", "wheel.settle_time=1e308"], "wheel.settle_time"),
    (["--set", "wheel.travel_time=1e308"], "wheel.travel_time"),
    (["--set", "output.series_interval=1e308"], "output.series_interval"),
    (["--set", "soil.density=1e308"], "soil.density"),
    (["--set", "physics.thickness=1e-200"], "physics.thickness"),  # below the shortest length
    (["--set", "soil.density=5e-324"], "soil.r_min"),  # the lightest disc's mass underflows
    (["--set", "soil.n=" + "1" * 5000], "soil.n"),  # beyond Python's int-string limit
    (["--set", "soil.seed=0x" + "f" * 5000], "soil.seed"),  # hex ints have no digit limit
    (["--duration", "1e308"], "--duration"),
]


@pytest.mark.parametrize("args,needle", EXTREME_RUNS, ids=[" ".join(a)[:40] for a, _ in EXTREME_RUNS])
def test_extreme_numbers_one_line(args, needle, tmp_path):
    cp = cli_in_process("run", "quick", *args, "--out", tmp_path / "o", "--no-progress", timeout=120)
    one_line_error(cp, needle)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("scenario", ["quick", "quick-3d"])
def test_a_tile_narrower_than_a_disc_is_refused_alike_by_check_and_run(scenario, tmp_path):
    """bed.tile = 1 passed `check`; `run` then refused the tile's own scenario, naming a
    bin.length the user never wrote. Both refuse it now, in the same line, naming bed.tile."""
    args = [scenario, "--set", "bed.tile=1"]
    checked = one_line_error(cli_in_process("check", *args, timeout=120), "bed.tile = 1", "bin.length")
    ran = one_line_error(
        cli_in_process("run", *args, "--out", tmp_path / "o", "--no-progress", timeout=120), "bed.tile = 1"
    )
    assert ran == checked
    assert not (tmp_path / "o").exists()


def test_bad_bed_counts(tmp_path):
    for name in ("bed-inf", "bed-nan", "bed-1e400", "bed-" + "9" * 5000, "bed-0", "bed--5", "bed-1e-5"):
        one_line_error(cli_in_process("run", name, "--out", tmp_path / "o"), "bed-N needs a disc count")
    assert not (tmp_path / "o").exists()


def test_resume_until_huge_keeps_the_store(finished_bed_run, tmp_path):
    store = tmp_path / "store"
    shutil.copytree(finished_bed_run, store)
    before = cli_in_process("checkpoint", "hash", store, check=True).stdout
    one_line_error(cli_in_process("resume", store, "--until", "1e308", "--no-progress"), "--until", "1e10")
    one_line_error(cli_in_process("resume", store, "--steps", "1e30", "--no-progress"), "--steps")
    assert cli_in_process("checkpoint", "hash", store, check=True).stdout == before


def test_deeply_nested_overrides_and_files(tmp_path):
    deep_key = "scenario.name." + ".".join(["a"] * 3000)
    one_line_error(cli_in_process("run", "quick", "--set", f"{deep_key}=1", "--out", tmp_path / "o"), "--set")
    one_line_error(cli_in_process("run", "quick", "--set", "a." * 3000 + "b=1", "--out", tmp_path / "o"), "--set")
    one_line_error(
        cli_in_process("run", "quick", "--set", "scenario.name=" + "[" * 3000 + "]" * 3000, "--out", tmp_path / "o"),
        "scenario.name",
    )
    for body in (
        "[scenario]\nname = " + "[" * 5000 + "]" * 5000 + "\n",
        "[scenario]\nname = " + "{a = " * 3000 + "1" + "}" * 3000 + "\n",
        "[soil]\nn = " + "7" * 5000 + "\n",
    ):
        f = tmp_path / "deep.toml"
        f.write_text(body)
        one_line_error(cli_in_process("run", f, "--out", tmp_path / "o"), str(f))
    f = tmp_path / "nested.toml"
    f.write_text("[scenario.name." + ".".join(["a"] * 3000) + "]\nx = 1\n")
    one_line_error(cli_in_process("run", f, "--out", tmp_path / "o"), "scenario.name")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("name", [EMOJI, "../../x", ".hidden", "a/b", "tab\there", "x" * 101, ""])
def test_scenario_name_is_one_safe_path_component(name, tmp_path):
    cp = cli_in_process(
        "run",
        "bed-1200",
        "--set",
        f"scenario.name={json.dumps(name)}",
        "--steps",
        "5",
        "--out",
        tmp_path / "o",
        "--no-progress",
    )
    one_line_error(cp, "scenario.name")
    assert not (tmp_path / "o").exists()


def test_any_description_is_stored_as_valid_toml_and_resumes(tmp_path):
    text = f'{EMOJI} "quoted" back\\slash\ttab \x01\x7f ü'
    out = tmp_path / "o"
    run_cli(
        "run",
        "bed-1200",
        "--set",
        f"scenario.description={toml_string(text)}",
        "--steps",
        "5",
        "--out",
        out,
        "--no-progress",
        check=True,
    )
    run_cli("resume", out, "--steps", "10", "--no-progress", check=True)
    assert json.loads((out / "summary.json").read_text())["steps"] == 10
    import tomllib

    assert tomllib.loads((out / "scenario.toml").read_text(encoding="utf-8"))["scenario"]["description"] == text


def test_dict_to_toml_writes_any_string():
    import tomllib

    for text in (EMOJI, "\x00\x1f\x7f", '"\\', "\U0010ffff", "line\nbreak", "\u2028"):
        assert tomllib.loads(dict_to_toml({"s": {"v": text}}))["s"]["v"] == text


def _scenario_keys():
    """(dotted key, default) of every key of every section of the scenario."""
    out = []

    def walk(obj, prefix):
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            key = f"{prefix}.{f.name}" if prefix else f.name
            if dataclasses.is_dataclass(v):
                walk(v, key)
            else:
                out.append((key, v))

    walk(Scenario(), "")
    return out


def _hostile_values(default):
    if isinstance(default, bool):
        return ["1", '"true"', "1e308"]
    if isinstance(default, int):
        return ["-1", "0", str(2**31), str(2**63), "1" + "0" * 30, "0x" + "f" * 3000, "1e308", "-0.0", "5e-324", '"7"']
    if isinstance(default, float):
        return [
            "1e308",
            "-1e308",
            "5e-324",
            "1e-200",
            "-0.0",
            "0",
            "1e400",
            "nan",
            "inf",
            "1" + "0" * 400,
            "true",
            '"1"',
        ]
    return [
        json.dumps(EMOJI),
        '"../../x"',
        '""',
        json.dumps("\x01\x7f"),
        json.dumps("x" * 20000),
        "[1, [2]]",
        "{a = 1}",
        "1e308",
    ]


SCENARIO_KEYS = _scenario_keys()


@pytest.mark.parametrize("scenario", ["quick", "bed-1200"])
@pytest.mark.parametrize("key,default", SCENARIO_KEYS, ids=[k for k, _ in SCENARIO_KEYS])
def test_every_key_at_extreme_values_is_accepted_or_one_line(scenario, key, default, capsys):
    """Every key of every section at 1e308, 5e-324, 1e-200, -0.0, ... : `check` (run's own
    validation and planning) accepts it with a finite plan, or refuses it in one line naming it."""
    for value in _hostile_values(default):
        rc = cli.main(["check", scenario, "--set", f"{key}={value}"])
        captured = capsys.readouterr()
        where = f"{key}={value[:40]}"
        if rc == 0:
            plan = json.loads(captured.out)
            assert 0 <= plan["steps"] <= MAX_STEPS, where
            for k in ("simulated_time_s", "dt_s", "dt_critical_s", "memory_bytes"):
                assert np.isfinite(plan[k]) and plan[k] >= 0, (where, k, plan[k])
            assert plan["dt_s"] <= plan["dt_critical_s"], where
            assert error_lines(captured.err) == [], where
            continue
        assert rc == 2, where
        lines = [ln for ln in captured.err.splitlines() if ln.strip()]
        assert len(lines) == 1 and "Traceback" not in captured.err, (where, captured.err[-2000:])
        # the key itself (a quantity derived from several keys names each of them)
        assert key in lines[0], (where, lines[0])
        assert len(lines[0]) < 600, (where, lines[0])


FLAG_VALUES = [
    "0",
    "-1",
    "1e308",
    "-1e308",
    "5e-324",
    "1e-200",
    "-0.0",
    "nan",
    "inf",
    "1e400",
    "9" * 5000,
    "1e999999999999999999",
    "1.5",
    "0x10",
    "",
    "abc",
]


@pytest.mark.parametrize("flag", ["--steps", "--duration", "--domains", "--block", "--checkpoint-every"])
def test_every_numeric_flag_at_extreme_values_is_accepted_or_one_line(flag, capsys):
    for value in FLAG_VALUES:
        try:
            rc = cli.main(["check", "quick", "--mode", "ooc", f"{flag}={value}"])
        except SystemExit as e:  # argparse refuses the flag (the parser's error() exits 2)
            rc = e.code
        captured = capsys.readouterr()
        where = f"{flag}={value[:40]}"
        if rc == 0:
            plan = json.loads(captured.out)
            assert 0 <= plan["steps"] <= MAX_STEPS and error_lines(captured.err) == [], where
            continue
        lines = [ln for ln in captured.err.splitlines() if ln.strip()]
        assert rc == 2 and len(lines) == 1 and flag in lines[0], (where, captured.err[-2000:])
        assert len(lines[0]) < 400, (where, lines[0])


# ------------------------------------------------------------------ D. hostile run files


def _damage(run, name, data: bytes | str):
    f = run / name
    f.unlink(missing_ok=True)
    if isinstance(data, str):
        f.write_text(data)
    else:
        f.write_bytes(data)


SUMMARY_CASES = {
    "array": "[1, 2, 3]",
    "string": '"summary"',
    "empty object": "{}",
    "not json": "{'slip': 1",
    "nested 10000 deep": "[" * 10000 + "]" * 10000,
    "deep object": '{"a": ' * 10000 + "1" + "}" * 10000,
    "5000-digit int": '{"steps": ' + "9" * 5000 + "}",
    "binary": bytes(range(256)) * 4,
}


@pytest.mark.parametrize("command", ["report", "compare"])
def test_hostile_summary_json(command, wheel_run_copy, finished_wheel_run):
    for case, data in SUMMARY_CASES.items():
        _damage(wheel_run_copy, "summary.json", data)
        args = [wheel_run_copy] if command == "report" else [finished_wheel_run, wheel_run_copy]
        one_line_error(cli_in_process(command, *args), "summary.json")


def _summary_with(run, edit):
    s = json.loads((run / "summary.json").read_text())
    edit(s)
    (run / "summary.json").write_text(json.dumps(s))


WRONG_TYPES = {
    "steps is text": lambda s: s.update(steps="many"),
    "missing state_hash": lambda s: s.pop("state_hash"),
    "missing slip's partner": lambda s: s.pop("net_traction"),
    "slip value text": lambda s: s["slip"]["whole_travel"].update(value="fast"),
    "window text": lambda s: s["slip"]["steady"].update(window_s="ab"),
    "window of three": lambda s: s["slip"]["steady"].update(window_s=[1, 2, 3]),
    "interval text": lambda s: s["net_traction"]["steady"].update(ci95="wide"),
    "blocks a fraction": lambda s: s["net_traction"]["steady"].update(blocks=2.5),
    "flag a list": lambda s: s["net_traction"]["steady"].update(flag=["short"]),
    "slip a list": lambda s: s.update(slip=[1]),
    "engine a number": lambda s: s.update(engine=3),
    "domains text": lambda s: s.update(engine={"domains": "six"}),
    "wall time bool": lambda s: s.update(wall_time_s=True),
}


@pytest.mark.parametrize("case", list(WRONG_TYPES))
def test_summary_with_wrong_types_or_missing_keys(case, wheel_run_copy, finished_wheel_run):
    _summary_with(wheel_run_copy, WRONG_TYPES[case])
    one_line_error(cli_in_process("report", wheel_run_copy), "summary.json")
    one_line_error(cli_in_process("compare", wheel_run_copy, finished_wheel_run), "summary.json")


def test_huge_summary_json(wheel_run_copy):
    with open(wheel_run_copy / "summary.json", "w") as f:
        f.write('{"pad": "' + "x" * (20 << 20) + '"}')
    one_line_error(cli_in_process("report", wheel_run_copy), "summary.json", "too large")


SERIES_CASES = {
    "non-numeric": lambda h: h + "\n" + ",".join(["abc"] * 13) + "\n",
    "wrong column count": lambda h: h + "\n1,2,3\n",
    "empty": lambda h: "",
    "header only, wrong names": lambda h: "a,b,c\n1,2,3\n",
    "binary": lambda h: bytes(range(256)) * 16,
}


@pytest.mark.parametrize("case", list(SERIES_CASES))
def test_hostile_series_csv(case, wheel_run_copy):
    header = (wheel_run_copy / "series.csv").read_text().splitlines()[0]
    _damage(wheel_run_copy, "series.csv", SERIES_CASES[case](header))
    one_line_error(cli_in_process("report", wheel_run_copy), "series.csv")


def _npz(path, **arrays):
    with open(path, "wb") as f:
        np.savez(f, **arrays)


def test_hostile_initial_npz(wheel_run_copy, tmp_path):
    f = wheel_run_copy / "initial.npz"
    with np.load(f) as z:
        good = {k: z[k] for k in z.files}
    cases = {
        "not a zip": lambda: f.write_bytes(b"PK\x03\x04 but not really a zip archive" * 10),
        "random bytes": lambda: f.write_bytes(os.urandom(4096)),
        "pickled objects": lambda: _npz(f, **{**good, "x": np.array([object()] * len(good["x"]), dtype=object)}),
        "a pickle": lambda: f.write_bytes(__import__("pickle").dumps({"x": 1})),
        "a bare npy": lambda: np.save(open(f, "wb"), good["x"]),
        "2-D positions": lambda: _npz(f, **{**good, "x": np.zeros((3, 3))}),
        "text radii": lambda: _npz(f, **{**good, "r": np.array(["a"] * len(good["r"]))}),
        "short y": lambda: _npz(f, **{**good, "y": good["y"][:5]}),
        "nan surface": lambda: _npz(f, **{**good, "surface": np.float64("nan")}),
        "missing id": lambda: _npz(f, **{k: v for k, v in good.items() if k != "id"}),
        "empty file": lambda: f.write_bytes(b""),
    }
    for name, make in cases.items():
        f.unlink()
        make()
        one_line_error(cli_in_process("report", wheel_run_copy), "initial.npz")


def test_not_a_run_directory(tmp_path, finished_wheel_run):
    cp = run_cli("report", finished_wheel_run, check=True)  # a run reports and compares
    assert "wheel slip" in cp.stdout and cp.stderr == ""
    assert "BIT-IDENTICAL" in run_cli("compare", finished_wheel_run, finished_wheel_run, check=True).stdout
    empty = tmp_path / "empty"
    empty.mkdir()
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "data.bin").write_bytes(os.urandom(100))
    foreign = tmp_path / "foreign"  # another tool's directory with its own summary.json
    foreign.mkdir()
    (foreign / "summary.json").write_text('{"accuracy": 0.93, "epochs": 12}')
    a_file = tmp_path / "file.txt"
    a_file.write_text("hello")
    for d in (foreign, empty, junk, a_file, tmp_path / "missing"):
        one_line_error(cli_in_process("report", d), "summary.json")
        one_line_error(cli_in_process("compare", finished_wheel_run, d), "summary.json")


def test_report_reads_only_regular_files_inside_the_run(wheel_run_copy, tmp_path):
    outside = tmp_path / "outside.json"
    outside.write_text((wheel_run_copy / "summary.json").read_text())
    (wheel_run_copy / "summary.json").unlink()
    (wheel_run_copy / "summary.json").symlink_to(outside)
    one_line_error(cli_in_process("report", wheel_run_copy), "summary.json", "outside")
    (wheel_run_copy / "summary.json").unlink()
    (wheel_run_copy / "summary.json").write_text(outside.read_text())
    (wheel_run_copy / "series.csv").unlink()
    os.mkfifo(wheel_run_copy / "series.csv")  # opening it would block forever
    one_line_error(cli_in_process("report", wheel_run_copy, timeout=60), "series.csv", "regular file")


# ------------------------------------------------------------------ E. sweep window


@pytest.mark.parametrize("window", [["output.steady_start=100", "output.steady_end=200"], ["wheel.travel_time=0.05"]])
def test_sweep_with_an_empty_steady_window_refused_before_running(window, tmp_path):
    out = tmp_path / "sweep"
    args = [a for kv in WHEEL_TEST + window for a in ("--set", kv)]
    cp = cli_in_process("sweep", "quick", *args, "--slips", "0.1,0.2", "--out", out, "--no-progress", timeout=300)
    one_line_error(cp, "output.steady_start", "holds no step")
    assert not out.exists()


def test_sweep_slips_sharing_a_directory_refused(tmp_path):
    out = tmp_path / "sweep"
    args = [a for kv in WHEEL_TEST for a in ("--set", kv)]
    one_line_error(
        cli_in_process("sweep", "quick", *args, "--slips", "0.1,0.1001", "--out", out, timeout=300), "--slips"
    )
    assert not out.exists()


# ------------------------------------------------------------------ F. --backend memory


def test_memory_backend_run_writes_its_outputs(tmp_path):
    out = tmp_path / "mem"
    args = [a for kv in WHEEL_TEST for a in ("--set", kv)]
    cp = run_cli(
        "run", "quick", *args, "--backend", "memory", "--steps", "300", "--out", out, "--no-progress", check=True
    )
    assert "state hash" in cp.stdout
    for name in (
        "summary.json",
        "series.csv",
        "initial.npz",
        "scenario.toml",
        "figures/series.png",
        "figures/deformation.png",
    ):
        assert (out / name).is_file(), name
    assert not (out / "MANIFEST.json").exists()  # the store lived only in the process
    summary = json.loads((out / "summary.json").read_text())
    assert summary["backend"] == "memory" and summary["steps"] == 300
    run_cli("report", out, check=True)  # figures from the files that remain
    one_line_error(cli_in_process("resume", out, "--no-progress"), str(out))


# ------------------------------------------------------------------ G. check


CHECK_KEYS = {
    "scenario",
    "estimated_wall_time",
    "scenario_hash",
    "mode",
    "backend",
    "n_discs",
    "steps",
    "simulated_time_s",
    "dt_s",
    "dt_critical_s",
    "checkpoint_every",
    "domains",
    "block",
    "streamed_bed",
    "memory_bytes",
    "memory_available_bytes",
    "memory_budget_bytes",
}


def test_check_prints_the_plan_and_writes_nothing(tmp_path):
    before = set(os.listdir("."))
    cp = cli_in_process("check", "quick", "--mode", "ooc", "--domains", "6", "--steps", "1e3", check=True)
    plan = json.loads(cp.stdout)
    assert set(plan) == CHECK_KEYS
    assert plan["steps"] == 1000 and plan["domains"] == 6 and plan["n_discs"] == 1500
    assert plan["block"] >= 1 and 0 < plan["dt_s"] <= plan["dt_critical_s"]
    assert 0 < plan["memory_bytes"] < plan["memory_available_bytes"]
    plan = json.loads(cli_in_process("check", "paper2008", check=True).stdout)
    assert plan["steps"] == 4_600_000 and plan["domains"] == 1
    plan = json.loads(cli_in_process("check", "bed-100k", "--mode", "ooc", "--duration", "0.01", check=True).stdout)
    assert plan["steps"] == 1000 and plan["streamed_bed"] is True
    assert set(os.listdir(".")) == before and error_lines(cp.stderr) == []


@pytest.mark.parametrize(
    "args",
    [
        ["quick", "--set", "physics.dt=1e-3"],
        ["quick", "--mode", "ddm", "--domains", "1000"],
        ["bed-2000000000"],
        ["quick", "--set", "scenario.name=../x"],
        ["quick", "--duration", "1e308"],
        ["no-such-scenario"],
        ["quick", "--backend", "tape"],
    ],
)
def test_check_refuses_exactly_what_run_refuses(args, tmp_path):
    run = one_line_error(cli_in_process("run", *args, "--out", tmp_path / "o", timeout=120))
    check = one_line_error(cli_in_process("check", *args, timeout=120))
    assert check.replace("ooc-dem check", "ooc-dem run") == run


# ------------------------------------------------------------------ H. out of memory


def test_memory_error_is_one_line(monkeypatch, capsys):
    def exhausted(args):
        raise MemoryError("Unable to allocate 20.0 GiB")

    monkeypatch.setitem(cli.COMMANDS, "scenarios", exhausted)
    assert cli.main(["scenarios"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("ooc-dem: error: out of memory (Unable to allocate")
