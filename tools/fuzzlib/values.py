"""Hostile values: TOML, JSON, paths, flag values, commands on a store; the scenario's keys."""

from __future__ import annotations

import math

from .world import TINY_SCENARIO


HUGE_DIGITS = "9" * 5000
# values as TOML text (for --set and scenario files)
TOML_FLOATS = [
    "1e308",
    "-1e308",
    "5e-324",
    "-5e-324",
    "-0.0",
    "0.0",
    "nan",
    "-nan",
    "inf",
    "-inf",
    "1e-200",
    "1e400",
    "1.7976931348623157e308",
    "2.2250738585072014e-308",
    "1e-5",
    "0.5",
]
TOML_INTS = [
    "0",
    "-1",
    "1",
    "2",
    "2147483647",
    "2147483648",
    "4294967296",
    "9223372036854775807",
    "9223372036854775808",
    "-9223372036854775809",
    "100000",
    "2000000000",
    "2000000001",
    "99999999999",
    "0x7fffffffffffffff",
    HUGE_DIGITS,
    "-" + HUGE_DIGITS,
]
TOML_STRINGS = [
    '"é🦀"',
    '"\\u0000"',
    '"../../x"',
    '"a\\nb"',
    '"\\u001b[31mred"',
    '""',
    "bare",
    "'x'",
    '"' + "x" * 100000 + '"',
    '"."',
    '".."',
    '"runs/../../x"',
    '"\\t"',
    '"con"',
    '"x/y"',
    '"drawbar"',
    '"slip"',
    '"wheel"',
    '"equal"',
]
TOML_OTHER = [
    "true",
    "false",
    "[1, 2]",
    "[]",
    "[[[[1]]]]",
    "{a = 1}",
    "{}",
    "[" * 5000 + "]" * 5000,
    "{a = " * 300 + "1" + "}" * 300,
    "1979-05-27T07:32:00Z",
    "[1.0, nan]",
    "= 1",
    "",
    "{dt = 1e-5}",
    "1_000",
    "+1",
    "0o777",
    "0b1",
    "1e",
    "[1,",
    '"unterminated',
]
TOML_VALUES = TOML_FLOATS + TOML_INTS + TOML_STRINGS + TOML_OTHER

NAME_VALUES = [
    '"é🦀"',
    '"\\u0000"',
    '"../../x"',
    '"../../victim/x"',
    '"a\\nb"',
    '"\\u001b[31m"',
    '""',
    '"."',
    '".."',
    '"runs"',
    '"x" ',
    '"' + "n" * 5000 + '"',
    '"../run2"',
    '"a/b/c"',
    '"\\r"',
    '"🦀/../../.."',
]

BED_NAMES = [
    "bed-inf",
    "bed-nan",
    "bed-1e400",
    "bed-2000000000",
    "bed-0",
    "bed--1",
    "bed-1.5",
    "bed-1e9",
    "bed-9999999999999",
    "bed-",
    "bed-1k",
    "bed-1m",
    "bed-100000m",
    "bed-1_000",
    "bed-\u0661\u0662\u0663",
    "bed-1e-5",
    "bed-" + HUGE_DIGITS,
    "bed-0x10",
    "bed-1e308",
    "bed-2000000001",
    "bed-1000",
    "bed-1200",
    "bed-Infinity",
    "bed- 12",
    "bed-12\n",
    "bed-100k",
    "bed-2e9",
    "bed-3e9",
    "bed-1.0000000001",
]

STEPS_VALUES = [
    "0",
    "1",
    "5",
    "10",
    "100000000000",
    "1e11",
    "99999999999999999999",
    "-1",
    "abc",
    HUGE_DIGITS,
    "",
    "2147483648",
    "9223372036854775808",
    " 3",
    "0x10",
    "1_0",
]
DURATION_VALUES = [
    "1e308",
    "5e-324",
    "1e-300",
    "nan",
    "inf",
    "-1",
    "0",
    "1e-5",
    "0.00002",
    "1e400",
    "abc",
    "",
    "-0.0",
    "1e20",
]
UNTIL_VALUES = ["0.0002", "0.0003", "0.00025", "1e308", "inf", "nan", "5e-324", "1e-300", "0", "-1", "1e20", "abc"]
DOMAIN_VALUES = ["1", "2", "3", "4096", "4097", "100000", "2147483648", "0", "-1", "1e11", HUGE_DIGITS, "abc"]
BLOCK_VALUES = ["1", "2", "10", "10000", "10001", "1000000000", "0", "-1", "abc", HUGE_DIGITS]
EPOCH_VALUES = ["10", "20", "0", "30", "-1", "1e11", "99999999999999999999", "abc", HUGE_DIGITS, "15"]
KEEP_VALUES = ["1", "2", "3", "0", "-1", "100000", "1e308", HUGE_DIGITS, "abc"]
STORE_ARGS = [
    "run",
    "run",
    "run",
    "run/",
    "run2",
    "victim",
    "victim_file",
    "link_victim",
    "link_zero",
    "nonexistent",
    "",
    ".",
    "run/epochs",
    "run/MANIFEST.json",
    "out",
    "dev_null",
    "run/../run",
    "./run",
    "run//",
]
SAFE_SECTIONS = ("scenario", "wheel", "output", "decomposition")

# hostile paths for manifest entries (relative to the store R/w/run; all stay inside R)
PATHS = [
    "../victim",
    "../victim_file",
    "../victim/a.txt",
    "../victim/sub",
    "../link_victim",
    "../link_file",
    "../link_zero",
    "../../dev/zero",
    "../dev_null",
    ".",
    "",
    "epochs",
    "epochs/",
    "MANIFEST.json",
    "./MANIFEST.json",
    "epochs/../MANIFEST.json",
    "summary.json",
    "initial.npz",
    "epochs/e000000000010.h5",
    "epochs/e000000000020.h5",
    "epochs/e000000000010.zarr",
    "epochs/e000000000020.zarr",
    "epochs/e000000000020.h5/x",
    "epochs/nonexistent.h5",
    "epochs\\..\\..\\victim",
    "epochs/\u0000",
    "..",
    "../..",
    "../run2/epochs/e000000000020.h5",
    "../run2",
    "epochs/e000000000020.zarr/zarr.json",
    "é🦀",
    "epochs/" + "x" * 5000,
    "../victim_epochs",
    "$ABS/victim",
    "$ABS/victim_file",
    "$ABS/link_zero",
    "$ABS/run/epochs/e000000000020.h5",
    "~/x",
    "epochs/*",
    "epochs/..",
]

SCENARIO_TOMLS = [
    "",
    "[[[",
    "x = 1",
    "[physics]\ndt = 1e308\n",
    "[soil]\nn = " + HUGE_DIGITS + "\n",
    "[physics]\ndt = nan\n",
    "a = " + "[" * 5000 + "]" * 5000,
    "\u0000",
    TINY_SCENARIO,
    "[soil]\nn = 2000000000\n",
    '[scenario]\nname = "../../x"\n',
    "[decomposition]\ndomains = 4096\n",
    "[wheel]\nenabled = 3\n",
    "[bin]\nlength = 1e308\n",
]


def _j(v):
    """JSON-able form of a value (NaN/inf and deep structures as markers)."""
    if isinstance(v, float) and not math.isfinite(v):
        return {"$float": repr(v)}
    return v


JSON_VALUES = [
    None,
    True,
    False,
    0,
    -1,
    1,
    2,
    10,
    20,
    2**31,
    2**63,
    2**64,
    -(2**63) - 1,
    10**100,
    1e308,
    -1e308,
    5e-324,
    -0.0,
    0.5,
    20.0,
    _j(float("nan")),
    _j(float("inf")),
    _j(float("-inf")),
    "",
    "x",
    "0",
    "20",
    "é🦀",
    "\u0000\u001b[31m\n",
    "../victim",
    [],
    [1],
    [[]],
    {},
    {"0": {}},
    {"$deep_list": 100000},
    {"$deep_dict": 100000},
    {"$deep_list": 50},
    "x" * 100000,
    "hdf5",
    "zarr",
    "memory",
    "ooc-dem-store",
    1,
    "1",
]
DOMAIN_MAPS = [
    {"x": {"n": 1, "arrays": {}}},
    {"-1": {"n": 1, "arrays": {}}},
    {"99999999999999999999": {"n": 0, "arrays": {}}},
    {"0.0": {}},
    {"1e3": {"n": 1}},
    {"0": {"n": 10**12, "arrays": {"x": [[10**12], "<f8"]}}},
    {"0": {"n": 1500, "arrays": {"x": [[1500], "|O"]}}},
    {"0": {"n": 1500, "arrays": {"x": [[-1], "<f8"]}}},
    {"0": {"n": 1500, "arrays": {"../../x": [[1500], "<f8"]}}},
    {" 0": {}},
    {"٠": {}},
    {"0": None},
    {"0": []},
    {"0": {"n": "many", "arrays": []}},
]


def _manifest_paths():
    top = [
        ["format"],
        ["format_version"],
        ["backend"],
        ["meta"],
        ["meta", "run"],
        ["meta", "run", "mode"],
        ["meta", "run", "backend"],
        ["meta", "run", "domains"],
        ["meta", "run", "block"],
        ["meta", "run", "steps"],
        ["meta", "run", "checkpoint_every"],
        ["meta", "scenario_toml"],
        ["meta", "scenario_hash"],
        ["meta", "scenario_name"],
        ["meta", "format_version"],
        ["meta", "engine_version"],
        ["created_at"],
        ["current"],
        ["previous"],
    ]
    ent = [
        ["step"],
        ["path"],
        ["files"],
        ["files", 0],
        ["files", 0, "path"],
        ["files", 0, "size"],
        ["files", 0, "sha256"],
        ["files", -1, "path"],
        ["domains"],
        ["domains", "0"],
        ["domains", "0", "n"],
        ["domains", "0", "arrays"],
        ["domains", "0", "arrays", "x"],
        ["domains", "0", "arrays", "x", 0],
        ["domains", "0", "arrays", "x", 1],
        ["domains", "0", "arrays", "hist_n"],
        ["globals"],
        ["globals", "arrays"],
        ["globals", "arrays", "wheel_state"],
        ["committed_at"],
    ]
    return top + [[e] + p for e in ("current", "previous") for p in ent]


MANIFEST_PATHS = _manifest_paths()
READ_CMDS = [
    ["checkpoint", "list", "run"],
    ["checkpoint", "verify", "run"],
    ["checkpoint", "inspect", "run"],
    ["checkpoint", "hash", "run"],
    ["checkpoint", "verify", "run", "--epoch", "10"],
    ["checkpoint", "hash", "run", "--epoch", "10"],
    ["checkpoint", "export", "run", "--out", "out/s.csv"],
    ["checkpoint", "export", "run", "--out", "out/s.xdmf"],
]
WRITE_CMDS = [
    ["checkpoint", "prune", "run", "--keep", "1"],
    ["resume", "run", "--steps", "30", "--no-progress", "--no-figures"],
]
OTHER_CMDS = [["report", "run"], ["compare", "run", "run2"]]
STORE_CMDS = READ_CMDS + WRITE_CMDS + WRITE_CMDS + OTHER_CMDS


def scenario_values(sc) -> list[tuple[str, object]]:
    """(section.key, value) of every value of a scenario, from ooc_dem.model.scenario's dataclasses."""
    import dataclasses

    out = []

    def walk(obj, prefix):
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            if dataclasses.is_dataclass(v):
                walk(v, f"{prefix}{f.name}.")
            else:
                out.append((f"{prefix}{f.name}", v))

    walk(sc, "")
    return out


def scenario_keys() -> list[str]:
    """section.key of every scenario value."""
    from ooc_dem.model.scenario import Scenario

    return [k for k, _ in scenario_values(Scenario())]
