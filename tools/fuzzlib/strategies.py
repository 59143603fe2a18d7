"""The hypothesis strategies, one per family of cases."""

from __future__ import annotations

import json

from .common import BASES
from .file_edits import EXTREMES
from .pools import (
    BOMB_SIZES,
    DECLARED_ROWS,
    DECLARED_SHAPES,
    EPOCH3D_CMDS,
    FSIZE_CMDS,
    FSIZE_LIMITS,
    NPZ_CMDS,
    TRAJ_CMDS,
    TRAJ_FIELDS,
    ZARR_CMDS,
    _bed_case,
    _draw_args,
    _epoch_expect,
    _size_expect,
)
from .values import (
    BED_NAMES,
    BLOCK_VALUES,
    DOMAIN_MAPS,
    DOMAIN_VALUES,
    DURATION_VALUES,
    HUGE_DIGITS,
    JSON_VALUES,
    MANIFEST_PATHS,
    NAME_VALUES,
    PATHS,
    READ_CMDS,
    SAFE_SECTIONS,
    SCENARIO_TOMLS,
    STEPS_VALUES,
    STORE_CMDS,
    TOML_VALUES,
    WRITE_CMDS,
    _j,
    scenario_keys,
)
from .worker import _subparsers
from .world import TINY_SCENARIO


def build_strategies():
    """{name: hypothesis strategy producing cases}."""
    from hypothesis import strategies as st

    keys = scenario_keys()
    safe_keys = [k for k in keys if k.split(".")[0] in SAFE_SECTIONS]
    hostile_keys = [
        "physics",
        "physics.dt.x",
        "a.b",
        "scenario.name.x",
        "contact.soil_soil",
        "x" * 1000 + ".y",
        ".",
        "physics..dt",
        ".".join(["a"] * 500),
        "contact.x.kn",
        "wheel.radius.",
        " physics.dt",
        "physics.dt ",
        "🦀.🦀",
        "physics.DT",
    ]
    random_float = st.floats(allow_nan=True, allow_infinity=True).map(repr)
    random_int = st.integers(min_value=-(2**70), max_value=2**70).map(str)
    value = st.one_of(
        st.sampled_from(TOML_VALUES),
        random_float,
        random_int,
        st.text(max_size=12).map(json.dumps),
        st.text(max_size=8),
    )

    def set_item(key_st):
        return st.builds(lambda k, v: f"{k}={v}", key_st, value)

    any_key = st.one_of(st.sampled_from(keys), st.sampled_from(keys), st.sampled_from(hostile_keys))
    scen_name = st.sampled_from(["quick", "quick", "bed-1000", "scenario.toml", "paper2008"])

    @st.composite
    def scenario_case(draw):
        base = draw(st.one_of(scen_name, st.sampled_from(BED_NAMES)))
        argv = ["check", base]
        for item in draw(
            st.lists(
                st.one_of(set_item(any_key), st.builds(lambda v: f"scenario.name={v}", st.sampled_from(NAME_VALUES))),
                min_size=0 if base.startswith("bed-") else 1,
                max_size=3,
            )
        ):
            argv += ["--set", item]
        for opt, pool in (
            ("--mode", ["monolithic", "ddm", "ooc", "gpu"]),
            ("--domains", DOMAIN_VALUES),
            ("--block", BLOCK_VALUES),
            ("--backend", ["hdf5", "zarr", "memory", "x"]),
        ):
            if draw(st.integers(0, 3)) == 0:
                argv += [opt, draw(st.sampled_from(pool))]
        k = draw(st.integers(0, 3))
        if k == 1:
            argv += ["--steps", draw(st.sampled_from(STEPS_VALUES))]
        elif k == 2:
            argv += ["--duration", draw(st.sampled_from(DURATION_VALUES))]
        return {"strategy": "scenario", "base": "h5", "edits": [], "argv": argv}

    toml_line = st.one_of(
        st.builds(lambda k, v: f"{k.rpartition('.')[2]} = {v}", st.sampled_from(keys), value),
        st.builds(lambda k: f"[{k.rpartition('.')[0] or k}]", st.sampled_from(keys)),
        st.sampled_from(
            [
                "[physics",
                "[[soil]]",
                "[soil]\n[soil]",
                "a.b.c = 1",
                'x = "\\u',
                "\ufeff",
                "[contact.soil_soil.extra]",
                "soil = 3",
                "[" * 1000,
                "a = " + "[" * 3000,
                "n = " + HUGE_DIGITS,
                "\u0000",
                "\r\n",
                "# comment",
                "physics = {dt = 1e308}",
            ]
        ),
        st.text(max_size=30),
    )

    @st.composite
    def scenario_file_case(draw):
        if draw(st.integers(0, 4)) == 0:
            ed = {"op": "scenario_file", "name": "s.toml", "bytes": list(draw(st.binary(max_size=200)))}
        else:
            head = draw(st.sampled_from(["", TINY_SCENARIO]))
            lines = draw(st.lists(toml_line, min_size=1, max_size=8))
            ed = {"op": "scenario_file", "name": "s.toml", "text": head + "\n".join(lines) + "\n"}
        argv = ["check", "out/s.toml"]
        if draw(st.booleans()):
            argv += ["--set", draw(set_item(any_key))]
        return {"strategy": "scenario_file", "base": "h5", "edits": [ed], "argv": argv}

    # ---- CLI flags, from the real parser
    @st.composite
    def cli_case(draw):
        from ooc_dem.cli import build_parser

        subs = _subparsers(build_parser())
        names = [n for n in subs if n not in ("profile", "check")] + ["profile"]
        weights = {
            "checkpoint": 6,
            "resume": 3,
            "run": 3,
            "report": 1,
            "compare": 1,
            "sweep": 1,
            "prepare": 1,
            "scenarios": 1,
            "profile": 1,
        }
        pool = [n for n in names for _ in range(weights.get(n, 1))]
        cmd = draw(st.sampled_from(pool))
        parser = subs[cmd]
        argv = [cmd]
        if cmd == "checkpoint":
            csubs = _subparsers(parser)
            c = draw(st.sampled_from(sorted(csubs)))
            argv.append(c)
            parser = csubs[c]
        # (scenario.name only from NAME_VALUES: a random absolute name would make `run` write outside R)
        set_st = st.one_of(
            set_item(st.sampled_from([k for k in safe_keys if k != "scenario.name"] + hostile_keys)),
            st.builds(lambda v: f"scenario.name={v}", st.sampled_from(NAME_VALUES)),
        )
        argv += _draw_args(draw, st, parser, cmd, argv[-1], set_st)
        if draw(st.integers(0, 15)) == 0:
            argv.insert(
                draw(st.integers(0, len(argv))),
                draw(
                    st.sampled_from(
                        [
                            "--frobnicate",
                            "-x",
                            "--",
                            "--help",
                            "-",
                            "--steps",
                            "--set",
                            "é🦀",
                            "--out=",
                            "--epoch=-1",
                            "\u0000",
                        ]
                    )
                ),
            )
        return {"strategy": "cli", "base": draw(st.sampled_from(BASES)), "edits": [], "argv": argv}

    # ---- manifest edits
    path_value = st.one_of(st.sampled_from(PATHS), st.sampled_from(JSON_VALUES))

    @st.composite
    def manifest_edit(draw):
        k = draw(st.integers(0, 12))
        if k <= 6:
            path = draw(st.sampled_from(MANIFEST_PATHS))
            last = path[-1]
            if last == "path":
                v = draw(path_value)
            elif last == "domains":
                v = draw(
                    st.one_of(
                        st.sampled_from(DOMAIN_MAPS), st.sampled_from(JSON_VALUES), st.just({"$many_domains": 100000})
                    )
                )
            elif last == "scenario_toml":
                v = draw(st.one_of(st.sampled_from(SCENARIO_TOMLS), st.sampled_from(JSON_VALUES)))
            else:
                v = draw(
                    st.one_of(
                        st.sampled_from(JSON_VALUES),
                        st.integers(min_value=-(2**70), max_value=2**70),
                        st.floats().map(_j),
                        st.text(max_size=10),
                    )
                )
            return {"op": "manifest_set", "path": path, "value": v}
        if k <= 8:
            return {"op": "manifest_delete", "path": draw(st.sampled_from(MANIFEST_PATHS))}
        if k == 9:
            return draw(
                st.sampled_from([{"op": "manifest_swap"}, {"op": "manifest_prev_is_cur"}, {"op": "epochs_symlink"}])
            )
        if k == 10:
            return {
                "op": "manifest_set",
                "path": [draw(st.sampled_from(["current", "previous"])), "files"],
                "value": [],
            }
        return draw(
            st.one_of(
                st.sampled_from(
                    [
                        {"op": "manifest_raw", "what": "huge_int"},
                        {"op": "manifest_raw", "what": "nan_step"},
                        {"op": "manifest_raw", "what": "deep", "n": 100000},
                        {"op": "manifest_raw", "what": "deep", "n": 900},
                    ]
                ),
                st.builds(lambda f: {"op": "manifest_raw", "what": "truncate", "frac": f}, st.floats(0, 0.999)),
                st.builds(lambda b: {"op": "manifest_raw", "what": "bytes", "data": list(b)}, st.binary(max_size=64)),
            )
        )

    @st.composite
    def manifest_case(draw):
        edits = draw(st.lists(manifest_edit(), min_size=1, max_size=3))
        return {
            "strategy": "manifest",
            "base": draw(st.sampled_from(BASES)),
            "edits": edits,
            "argv": draw(st.sampled_from(STORE_CMDS)),
        }

    # ---- epoch edits
    which = st.sampled_from(["current", "current", "previous"])
    arr_kinds = [
        "nan",
        "inf",
        "all_nan",
        "99",
        "all_99",
        "neg",
        "huge",
        "zero",
        "dup",
        "shorter",
        "longer",
        "empty",
        "2d",
        "int32",
        "float32",
        "bool",
        "complex",
        "u8",
        "delete",
    ]
    dom_names = [
        "id",
        "pos",
        "vel",
        "spin",
        "r",
        "mass",
        "inertia",
        "mat",
        "hist_n",
        "hist_id",
        "hist_s",
        "hist_m",
    ]  # a domain record of store format 2
    glob_names = ["wheel_state", "metrics_iacc", "metrics_wacc", "metrics_rows"]
    attr_values = [
        None,
        "garbage",
        "{}",
        "[]",
        "null",
        '{"step": "x"}',
        '{"step": 1e308}',
        '{"time": NaN}',
        '{"step": -1, "time": -1}',
        "[" * 100000,
        '"\u0000"',
        '{"step": 20, "time": 0.0002, "mode": "gpu"}',
        '{"engine": {"domains": 100000}}',
        '{"redecompositions": [{"step": 0, "bounds": [1e308]}]}',
        '{"xmin": NaN, "xmax": -1}',
        '{"n": 99999999}',
    ]
    fracs = st.floats(0, 0.9999)

    @st.composite
    def epoch_edit(draw, kinds=arr_kinds):
        k = draw(st.integers(0, 9))
        if k <= 2:
            n = draw(st.integers(1, 4))
            return {
                "op": "flip",
                "which": draw(which),
                "file": draw(st.integers(0, 1000)),
                "offsets": draw(st.lists(fracs, min_size=n, max_size=n)),
                "xors": draw(st.lists(st.integers(0, 254), min_size=n, max_size=n)),
                "recompute": draw(st.booleans()),
            }
        if k == 3:
            return {
                "op": "truncate",
                "which": draw(which),
                "file": draw(st.integers(0, 1000)),
                "frac": draw(fracs),
                "extra": list(draw(st.binary(max_size=8))),
                "recompute": draw(st.booleans()),
            }
        if k <= 7:
            g = draw(st.sampled_from(["domain", "domain", "domain", "globals"]))
            return {
                "op": "array",
                "which": draw(which),
                "group": g,
                "dom": draw(st.integers(0, 5)),
                "name": draw(st.sampled_from(dom_names if g == "domain" else glob_names)),
                "kind": draw(st.sampled_from(kinds)),
                "rows": draw(st.lists(fracs, min_size=1, max_size=3)),
                "update_meta": draw(st.booleans()),
            }
        return {
            "op": "attrs",
            "which": draw(which),
            "group": draw(st.sampled_from(["domain", "globals"])),
            "dom": draw(st.integers(0, 5)),
            "value": draw(st.sampled_from(attr_values)),
        }

    epoch_cmds = READ_CMDS[:6] + WRITE_CMDS * 2 + [["checkpoint", "export", "run", "--out", "out/s.csv"]]

    @st.composite
    def epoch_case(draw):
        edits = draw(st.lists(epoch_edit(), min_size=1, max_size=2))
        if draw(st.integers(0, 5)) == 0:
            edits.append({"op": "manifest_set", "path": [edits[0]["which"], "files"], "value": []})
        argv = draw(st.sampled_from(epoch_cmds))
        return _epoch_expect({"strategy": "epoch", "base": draw(st.sampled_from(BASES)), "edits": edits, "argv": argv})

    # ---- run-directory files for report / compare
    series_texts = [
        "",
        "t [s]\n",
        "garbage\n\x00\x01",
        "nan,nan,nan\n",
        "1e308," * 13 + "\n",
        "t [s],x\n" + "1,2\n" * 3,
        HUGE_DIGITS + "\n",
        "a" * 200000,
        "\ufeff\u0000",
        "t [s],t_travel [s],x [m]\n1,2\n",
        "1,2,3,4,5,6,7,8,9,10,11,12,13\n" * 1000,
        "inf,-inf,nan,0,0,0,0,0,0,0,0,0,0\n",
    ]
    summary_paths = [
        ["slip"],
        ["slip", "whole_travel", "value"],
        ["slip", "steady"],
        ["steps"],
        ["n_discs"],
        ["wall_time_s"],
        ["state_hash"],
        ["scenario"],
        ["mode"],
        ["simulated_time_s"],
        ["net_traction", "unit"],
        ["sinkage", "static"],
        ["engine"],
        ["sinkage"],
        ["net_traction", "steady", "window_s"],
    ]
    npz_specs = [
        {"x": "nan", "y": "nan"},
        {"x": "short"},
        {},
        {"x": "object"},
        {"x": "str", "y": "str"},
        {"x": "2d", "y": "2d", "id": "int"},
        {"x": "empty", "y": "empty"},
    ]

    @st.composite
    def runfile_edit(draw):
        name = draw(
            st.sampled_from(["summary.json", "summary.json", "series.csv", "initial.npz", "scenario.toml", "figures"])
        )
        k = draw(st.integers(0, 4))
        if name == "figures":
            return draw(
                st.sampled_from(
                    [
                        {"op": "runfile", "name": "figures", "text": "not a dir"},
                        {"op": "runfile_link", "name": "figures", "target": "../victim"},
                    ]
                )
            )
        if k == 0:
            return {"op": "runfile", "name": name, "delete": True}
        if k == 1:
            return {"op": "runfile", "name": name, "bytes": list(draw(st.binary(max_size=100)))}
        if k == 2 and name != "initial.npz":
            return {
                "op": "runfile_link",
                "name": name,
                "target": draw(st.sampled_from(["../link_zero", "../victim", "/dev/zero", "../dev_null"])),
            }
        if name == "summary.json":
            if draw(st.booleans()):
                return {"op": "runfile", "name": name, "json": draw(st.sampled_from(JSON_VALUES))}
            return {
                "op": "runfile",
                "name": name,
                "summary_set": draw(st.sampled_from(summary_paths)),
                "value": draw(st.one_of(st.sampled_from(JSON_VALUES), st.floats().map(_j))),
            }
        if name == "series.csv":
            return {"op": "runfile", "name": name, "text": draw(st.sampled_from(series_texts))}
        if name == "initial.npz":
            return {"op": "runfile", "name": name, "npz": draw(st.sampled_from(npz_specs))}
        return {"op": "runfile", "name": name, "text": draw(st.sampled_from(SCENARIO_TOMLS))}

    @st.composite
    def runfiles_case(draw):
        edits = draw(st.lists(runfile_edit(), min_size=1, max_size=3))
        argv = draw(
            st.sampled_from(
                [
                    ["report", "run"],
                    ["report", "run"],
                    ["compare", "run", "run2"],
                    ["compare", "run2", "run"],
                    ["compare", "run", "run"],
                ]
            )
        )
        return {"strategy": "runfiles", "base": draw(st.sampled_from(BASES)), "edits": edits, "argv": argv}

    # ---- 3D stores: the epoch edits (and finite absurd values) on quick-3d, HDF5 and zarr
    kinds3 = arr_kinds + list(EXTREMES) + ["drop_row", "unsort"]

    @st.composite
    def epoch3d_case(draw):
        edits = draw(st.lists(epoch_edit(kinds3), min_size=1, max_size=2))
        argv = draw(st.sampled_from(EPOCH3D_CMDS))
        return _epoch_expect(
            {"strategy": "epoch3d", "base": draw(st.sampled_from(["h5_3d", "zarr_3d"])), "edits": edits, "argv": argv}
        )

    # ---- beds: `run --bed` of an edited prepared bed, and an edited bed-cache entry
    bed_kinds = arr_kinds + list(EXTREMES) + ["drop_disc", "delete"]

    @st.composite
    def bed_case(draw):
        where = draw(st.sampled_from(["bed", "bed", "cache"]))
        kinds = bed_kinds + (["remove_file"] if where == "cache" else [])
        edits = [
            {
                "op": "npz_array",
                "file": where,
                "name": draw(st.sampled_from(dom_names)),
                "kind": draw(st.sampled_from(kinds)),
                "rows": draw(st.lists(fracs, min_size=1, max_size=3)),
            }
            for _ in range(draw(st.integers(1, 2)))
        ]
        extra = draw(
            st.sampled_from(
                [[], [], ["--mode", "ooc", "--domains", "2", "--backend", "zarr"], ["--mode", "ddm", "--domains", "2"]]
            )
        )
        return _bed_case(where, edits, extra)

    # ---- trajectory frames: declared row counts, shapes, dtypes, attributes
    traj_attr_values = [
        None,
        -1,
        0,
        1,
        3,
        2**25,
        2**40,
        2**62,
        1.5,
        "x",
        _j(float("nan")),
        [0.0] * 6,
        [_j(float("nan"))] * 6,
        [1.0, 2.0],
        1e308,
        5e-324,
    ]

    @st.composite
    def traj_edit(draw):
        k = draw(st.integers(0, 9))
        frame = draw(st.integers(0, 5))
        if k <= 2:
            return {
                "op": "traj",
                "frame": frame,
                "what": "attr",
                "key": draw(
                    st.sampled_from(
                        [
                            "n_discs",
                            "step",
                            "dim",
                            "frame_every_steps",
                            "dt",
                            "time",
                            "wheel_state",
                            "format_version",
                            "format",
                            "scenario_hash",
                        ]
                    )
                ),
                "value": draw(st.sampled_from(traj_attr_values)),
            }
        if k <= 6:
            return {
                "op": "traj",
                "frame": frame,
                "what": "dataset",
                "name": draw(st.sampled_from(TRAJ_FIELDS)),
                "kind": draw(st.sampled_from(kinds3)),
                "rows": draw(st.lists(fracs, min_size=1, max_size=3)),
            }
        if k <= 8:
            return {
                "op": "traj",
                "frame": frame,
                "what": "declare_rows",
                "rows": draw(st.sampled_from(DECLARED_ROWS)),
                "n_discs": draw(st.booleans()),
            }
        return {"op": "traj", "frame": frame, "what": "remove"}

    @st.composite
    def trajectory_case(draw):
        edits = draw(st.lists(traj_edit(), min_size=1, max_size=2))
        return _size_expect(
            {"strategy": "trajectory", "base": "traj", "edits": edits, "argv": draw(st.sampled_from(TRAJ_CMDS))}
        )

    # ---- npz members of initial.npz
    @st.composite
    def npz_edit(draw):
        member = draw(st.sampled_from(["x", "y", "r", "id", "surface"]))
        what = draw(st.sampled_from(["bomb", "declared", "declared", "object", "fortran", "shape", "dtype"]))
        ed = {"op": "npz_member", "member": member, "what": what}
        if what == "bomb":
            ed["size"] = draw(st.sampled_from(BOMB_SIZES))
        elif what == "declared":
            ed["shape"] = draw(st.sampled_from(DECLARED_SHAPES))
            ed["descr"] = draw(st.sampled_from(["<f8", "<i8", "|u1", "<c16"]))
        elif what == "shape":
            ed["shape"] = draw(st.sampled_from([[1500, 2], [3], [0], [1500, 1, 1], [1], [2, 750]]))
        elif what == "dtype":
            ed["descr"] = draw(st.sampled_from(["<c16", "|b1", "<U4", "|V16", ">f8", "<m8[s]"]))
        return ed

    @st.composite
    def npz_case(draw):
        edits = draw(st.lists(npz_edit(), min_size=1, max_size=2))
        argv = draw(st.sampled_from(NPZ_CMDS))
        base = "traj" if argv[0] == "animate" else draw(st.sampled_from(["h5", "zarr"]))
        return _size_expect({"strategy": "npz", "base": base, "edits": edits, "argv": argv})

    # ---- zarr archives with codecs
    @st.composite
    def zarr_codec_case(draw):
        base = draw(st.sampled_from(["zarr", "zarr", "zarr_3d", "zarr_zstd"]))
        g = draw(st.sampled_from(["domain", "domain", "domain", "globals"]))
        codec = draw(
            st.sampled_from(
                [
                    "gzip",
                    "zstd",
                    "blosc",
                    "crc32c",
                    "unknown",
                    "sharding",
                    "sharding_many",
                    "transpose",
                    "gzip_bomb",
                    "gzip_bomb",
                ]
            )
        )
        ed = {
            "op": "zarr_codec",
            "which": draw(which),
            "group": g,
            "dom": draw(st.integers(0, 5)),
            "name": draw(st.sampled_from(dom_names if g == "domain" else glob_names)),
            "codec": codec,
            "encode": draw(st.booleans()),
        }
        if codec == "gzip_bomb":
            ed["size"] = draw(st.sampled_from(BOMB_SIZES))
        case = _size_expect(
            {"strategy": "zarr_codec", "base": base, "edits": [ed], "argv": draw(st.sampled_from(ZARR_CMDS))}
        )
        if codec.startswith("sharding") and case["argv"][0] == "checkpoint":
            case["fresh"] = True  # what zarr prints at interpreter exit counts
        return case

    # ---- file-size limits on every writer
    @st.composite
    def fsize_case(draw):
        argv, base, needs = draw(st.sampled_from(FSIZE_CMDS))
        # log-uniform from 1 KB to 8 MB: every writer's output is cut somewhere, or fits
        limit = draw(st.one_of(st.sampled_from(FSIZE_LIMITS), st.floats(10, 23).map(lambda e: int(2**e))))
        return {
            "strategy": "fsize",
            "base": base,
            "edits": [],
            "argv": list(argv),
            "needs": list(needs),
            "fsize": limit,
            "timeout": 30,
        }

    return {
        "scenario": scenario_case(),
        "scenario_file": scenario_file_case(),
        "cli": cli_case(),
        "manifest": manifest_case(),
        "epoch": epoch_case(),
        "runfiles": runfiles_case(),
        "epoch3d": epoch3d_case(),
        "bed": bed_case(),
        "trajectory": trajectory_case(),
        "npz": npz_case(),
        "zarr_codec": zarr_codec_case(),
        "fsize": fsize_case(),
    }
