"""The bugs found by hand: cases always run (hypothesis @example)."""

from __future__ import annotations

from .common import BASES, BED_RUN
from .pools import MiB, RESUME30, _bed_case, _epoch_expect, _size_expect
from .values import HUGE_DIGITS


RUN_TAIL = ["--no-progress", "--no-figures"]


def _c(strategy, argv, edits=(), base="h5", expect=None):
    case = {"strategy": strategy, "base": base, "edits": list(edits), "argv": list(argv)}
    if expect:
        case["expect"] = expect
    return case


def _known_cases() -> dict:
    ck = lambda *a: _c("scenario", ["check", "quick", *a])  # noqa: E731
    sets = lambda *kv: [x for k in kv for x in ("--set", k)]  # noqa: E731
    scen = [
        ck(*sets("soil.r_min=1e-200")),
        ck(*sets("soil.r_min=1e-200", "soil.r_max=1e-200")),
        ck(*sets("physics.dt=5e-324")),
        ck(*sets("wheel.settle_time=1e308")),
        ck(*sets("wheel.travel_time=1e308")),
        ck(*sets("output.series_interval=5e-324")),
        ck(*sets("contact.soil_soil.kn=1e308")),
        ck(*sets("soil.density=5e-324")),
        ck(*sets("physics.thickness=1e308")),
        ck(*sets("bin.length=1e308")),
        ck(*sets("physics.gravity=-0.0")),
        ck(*sets("wheel.omega=nan")),
        ck(*sets("wheel.radius=inf")),
        ck("--steps", "100000000000"),
        ck("--duration", "1e308"),
        ck("--mode", "ooc", "--domains", "100000"),
        ck("--mode", "ddm", "--domains", "100000"),
        ck("--block", "1000000000"),
        ck(*sets("physics.dt=" + "[" * 5000 + "]" * 5000)),
        ck(*sets("soil.n=" + HUGE_DIGITS)),
        ck(*sets("soil.seed=" + HUGE_DIGITS)),
        ck(*sets('scenario.name="é🦀"')),
        ck(*sets('scenario.name="\\u0000\\u001b[31m"')),
        ck(*sets('scenario.name="../../x"')),
        ck(*sets("physics.dt={a = " + "{a = " * 300 + "1" + "}" * 301)),
        ck(*sets(".".join(["a"] * 500) + "=1")),
    ]
    scen += [
        _c("scenario", ["check", n])
        for n in ("bed-inf", "bed-nan", "bed-1e400", "bed-2000000000", "bed-" + HUGE_DIGITS, "bed-1e308")
    ]
    scen_file = [
        _c("scenario_file", ["check", "out/s.toml"], [{"op": "scenario_file", "name": "s.toml", "text": t}])
        for t in (
            "a = " + "[" * 5000 + "]" * 5000 + "\n",
            "[soil]\nn = " + HUGE_DIGITS + "\n",
            "[" * 1000 + "\n",
            '[scenario]\nname = "../../x"\n',
        )
    ]
    scen_file.append(
        _c(
            "scenario_file",
            ["check", "out/s.toml"],
            [{"op": "scenario_file", "name": "s.toml", "bytes": list(b"\xff\xfe\x00[\x80")}],
        )
    )
    cli = [
        _c("cli", ["run", "quick", "--steps", "100000000000", "--out", "out/r", *RUN_TAIL]),
        _c("cli", ["run", "quick", "--duration", "1e308", "--out", "out/r", *RUN_TAIL]),
        _c("cli", ["resume", "run", "--until", "1e308", *RUN_TAIL]),
        _c("cli", ["resume", "run", "--steps", "100000000000", *RUN_TAIL]),
        _c(
            "cli", ["run", "quick", "--mode", "ooc", "--domains", "100000", "--steps", "1", "--out", "out/r", *RUN_TAIL]
        ),
        _c("cli", ["run", "quick", "--set", 'scenario.name="../../x"', "--steps", "1", *RUN_TAIL]),
        _c("cli", ["run", "quick", "--set", 'scenario.name="../victim"', "--steps", "1", *RUN_TAIL]),
        _c("cli", ["run", "bed-inf", "--steps", "1", *RUN_TAIL]),
        _c("cli", ["run", "bed-2000000000", "--steps", "1", "--out", "out/r", *RUN_TAIL]),
        _c("cli", ["prepare", "bed-nan", "--out", "out/p", "--no-progress"]),
        _c("cli", ["run", "quick", "--out", "victim", "--steps", "1", *RUN_TAIL]),
        _c("cli", ["checkpoint", "export", "run", "--out", "run/MANIFEST.json", "--format", "csv"]),
        _c("cli", ["checkpoint", "export", "run", "--out", "run/epochs/e000000000020.h5", "--format", "csv"]),
        _c("cli", ["checkpoint", "export", "run", "--out", "run/epochs/e000000000020.h5", "--format", "xdmf"]),
        _c("cli", ["checkpoint", "export", "run", "--out", "dev_null", "--format", "csv"]),
        _c("cli", ["checkpoint", "export", "run", "--out", "dev_full", "--format", "vtk"]),
        _c(
            "cli",
            ["checkpoint", "export", "run", "--out", "run/epochs/e000000000020.zarr/zarr.json", "--format", "csv"],
            base="zarr",
        ),
        _c("cli", ["checkpoint", "hash", "run", "--epoch", HUGE_DIGITS]),
    ]
    M = lambda path, value: {"op": "manifest_set", "path": path, "value": value}  # noqa: E731
    prune = ["checkpoint", "prune", "run", "--keep", "1"]
    resume = ["resume", "run", "--steps", "30", *RUN_TAIL]
    verify = ["checkpoint", "verify", "run"]
    man = []
    for pth in (
        "../victim",
        "../victim_file",
        "$ABS/victim",
        "$ABS/victim_file",
        ".",
        "epochs",
        "MANIFEST.json",
        "../link_victim",
        "..",
    ):
        man.append(_c("manifest", prune, [M(["previous", "path"], pth)]))
        man.append(_c("manifest", prune, [M(["previous", "path"], pth)], base="zarr"))
    man += [
        _c("manifest", prune, [{"op": "manifest_prev_is_cur"}]),
        _c("manifest", prune, [{"op": "manifest_prev_is_cur"}], base="zarr"),
        _c("manifest", resume, [{"op": "manifest_prev_is_cur"}]),
        _c("manifest", resume, [{"op": "epochs_symlink"}]),
        _c("manifest", resume, [{"op": "epochs_symlink"}], base="zarr"),
        _c("manifest", prune, [{"op": "epochs_symlink"}]),
        _c("manifest", verify, [M(["current", "files", 0, "path"], "../../dev/zero")]),
        _c(
            "manifest",
            verify,
            [M(["current", "files", 0, "path"], "../../dev/zero"), M(["current", "files", 0, "size"], 0)],
        ),
        _c("manifest", ["checkpoint", "hash", "run"], [M(["current", "files", 0, "path"], "../../dev/zero")]),
        _c("manifest", ["checkpoint", "list", "run"], [M(["current", "files", 0, "path"], "../link_zero")]),
        _c("manifest", verify, [M(["current", "files", 0, "path"], "$ABS/victim_file")]),
        _c(
            "manifest",
            verify,
            [
                M(["current", "path"], "../run2/epochs/e000000000020.h5"),
                M(["current", "files", 0, "path"], "../run2/epochs/e000000000020.h5"),
            ],
        ),
        _c("manifest", ["checkpoint", "hash", "run"], [{"op": "manifest_delete", "path": ["current", "globals"]}]),
        _c("manifest", resume, [{"op": "manifest_delete", "path": ["current", "globals"]}]),
        _c("manifest", ["checkpoint", "inspect", "run"], [M(["current", "domains"], {"x": {"n": 1, "arrays": {}}})]),
        _c("manifest", resume, [M(["current", "domains"], {"x": {"n": 1, "arrays": {}}})]),
        _c("manifest", resume, [M(["meta", "run", "domains"], "many")]),
        _c("manifest", resume, [M(["meta", "run", "mode"], ["ooc"])]),
        _c("manifest", resume, [M(["meta", "run", "steps"], "30")]),
        _c("manifest", resume, [M(["meta", "run", "checkpoint_every"], 0)]),
        _c("manifest", resume, [M(["meta", "run"], None)]),
        _c("manifest", resume, [M(["meta", "scenario_toml"], "[[[")]),
        _c("manifest", resume, [M(["meta", "scenario_toml"], 12)]),
        _c("manifest", resume, [M(["meta", "scenario_toml"], "[soil]\nn = " + HUGE_DIGITS + "\n")]),
        _c("manifest", verify, [{"op": "manifest_raw", "what": "deep", "n": 100000}]),
        _c("manifest", resume, [{"op": "manifest_raw", "what": "huge_int"}]),
        _c("manifest", ["checkpoint", "list", "run"], [M(["current", "step"], "20")]),
        _c("manifest", ["checkpoint", "list", "run"], [M(["current", "files", 0, "size"], "big")]),
        _c("manifest", ["checkpoint", "list", "run"], [M(["current", "domains"], [])]),
    ]
    A = lambda name, kind, which="current", **kw: {
        "op": "array",
        "which": which,
        "group": kw.get("group", "domain"),  # noqa: E731
        "dom": 0,
        "name": name,
        "kind": kind,
        "rows": [0.0, 0.5],
        "update_meta": kw.get("update_meta", False),
    }
    ep = []
    for base in BASES:
        ep += [
            _c("epoch", resume, [A("hist_n", "99")], base),
            _c("epoch", resume, [A("hist_n", "all_99")], base),
            _c("epoch", resume, [A("pos", "nan")], base),
            _c("epoch", resume, [A("vel", "all_nan")], base),
            _c("epoch", resume, [A("id", "dup")], base),
            _c("epoch", verify, [A("id", "dup")], base),
            _c("epoch", ["checkpoint", "hash", "run"], [A("hist_n", "all_99")], base),
            _c("epoch", resume, [A("pos", "shorter", update_meta=True)], base),
            _c("epoch", resume, [A("pos", "int32", update_meta=True)], base),
            _c("epoch", resume, [A("wheel_state", "shorter", group="globals", update_meta=True)], base),
            _c(
                "epoch",
                resume,
                [{"op": "attrs", "which": "current", "group": "globals", "dom": 0, "value": None}],
                base,
            ),
            _c(
                "epoch",
                ["checkpoint", "hash", "run"],
                [{"op": "attrs", "which": "current", "group": "globals", "dom": 0, "value": None}],
                base,
            ),
            _c(
                "epoch",
                ["checkpoint", "inspect", "run"],
                [{"op": "attrs", "which": "current", "group": "globals", "dom": 0, "value": "garbage"}],
                base,
            ),
            _epoch_expect(
                _c(
                    "epoch",
                    verify,
                    [
                        {
                            "op": "flip",
                            "which": "current",
                            "file": 0,
                            "offsets": [0.5],
                            "xors": [7],
                            "recompute": False,
                        },
                        M(["current", "files"], []),
                    ],
                    base,
                )
            ),
            _epoch_expect(
                _c(
                    "epoch",
                    verify,
                    [
                        {
                            "op": "flip",
                            "which": "previous",
                            "file": 0,
                            "offsets": [0.3],
                            "xors": [1],
                            "recompute": False,
                        },
                        M(["previous", "files"], []),
                    ],
                    base,
                )
            ),
        ]
    rf = [
        _c("runfiles", ["report", "run"], [{"op": "runfile", "name": "summary.json", "json": []}]),
        _c(
            "runfiles",
            ["report", "run"],
            [{"op": "runfile", "name": "summary.json", "summary_set": ["slip"], "value": 3}],
        ),
        _c("runfiles", ["report", "run"], [{"op": "runfile", "name": "summary.json", "json": {"$deep_list": 100000}}]),
        _c("runfiles", ["report", "run"], [{"op": "runfile", "name": "series.csv", "text": "garbage\n\x00\x01"}]),
        _c("runfiles", ["report", "run"], [{"op": "runfile", "name": "initial.npz", "bytes": list(b"PK\x03\x04junk")}]),
        _c("runfiles", ["report", "run"], [{"op": "runfile_link", "name": "summary.json", "target": "../link_zero"}]),
        _c("runfiles", ["report", "run"], [{"op": "runfile_link", "name": "figures", "target": "../victim"}]),
        _c("runfiles", ["compare", "run", "run2"], [{"op": "runfile", "name": "summary.json", "json": "x"}]),
        _c(
            "runfiles",
            ["compare", "run", "run2"],
            [{"op": "runfile", "name": "summary.json", "summary_set": ["slip", "steady"], "value": None}],
        ),
        _c("runfiles", ["compare", "run", "run2"], [{"op": "runfile", "name": "initial.npz", "npz": {"x": "object"}}]),
        _c(
            "runfiles",
            ["compare", "run", "run2"],
            [{"op": "runfile", "name": "series.csv", "text": "1e308," * 13 + "\n"}],
        ),
        _c(
            "runfiles",
            ["compare", "run", "run2"],
            [{"op": "runfile_link", "name": "summary.json", "target": "/dev/zero"}],
        ),
    ]
    # the readers that skipped the epoch validation (hash, export) and finite absurd values
    hash_ = ["checkpoint", "hash", "run"]
    csv = ["checkpoint", "export", "run", "--out", "out/s.csv"]
    for base in BASES:
        ep += [
            _c("epoch", hash_, [A("pos", "nan")], base),
            _c("epoch", csv, [A("pos", "nan")], base),
            _c("epoch", hash_, [A("r", "zero")], base),
            _c("epoch", hash_, [A("id", "minus7")], base),
            _c("epoch", hash_, [A("hist_n", "99")], base),
            _c("epoch", hash_, [A("pos", "float32", update_meta=True)], base),
            _c("epoch", resume, [A("vel", "1e300")], base),
            _c("epoch", resume, [A("mass", "5e-324")], base),
            _c("epoch", resume, [A("mat", "999")], base),
        ]
    # a damaged current epoch whose recorded size is absurd: resume falls back, never "disk full"
    for base in BASES:
        ep.append(
            _c(
                "epoch",
                resume,
                [
                    {"op": "flip", "which": "current", "file": 0, "offsets": [0.5], "xors": [7], "recompute": False},
                    M(["current", "files", 0, "size"], 10**18),
                ],
                base,
                expect={"same_bits_as_intact": True},
            )
        )
    # a domain's attributes replaced (no n, xmin, xmax): an out-of-core resume read the group
    # as empty and committed an epoch short of its discs; an array edit that changes nothing
    # (a domain holding no disc) leaves the intact state
    DA = lambda which, dom, value: {
        "op": "attrs",
        "which": which,
        "group": "domain",
        "dom": dom,  # noqa: E731
        "value": value,
    }
    ep += [
        _c("epoch", resume, [DA("current", 5, '{"step": 1e308}')], "zarr"),
        _c(
            "epoch",
            resume,
            [
                {
                    "op": "flip",
                    "which": "current",
                    "file": 187,
                    "offsets": [0.0, 0.6],
                    "xors": [88, 188],
                    "recompute": False,
                },
                DA("previous", 3, '{"engine": {"domains": 100000}}'),
            ],
            "zarr",
        ),
    ]
    # an absurd finite value that `check` accepts crashes `run`
    cli += [
        _c("cli", ["run", "quick-3d", "--set", "wheel.width=1e-300", "--steps", "1", "--out", "out/r", *RUN_TAIL]),
        _c("cli", ["check", "quick-3d", "--set", "wheel.width=1e-300"]),
    ]
    # untyped exceptions from the API on a hostile manifest; hist_cap sizing an allocation
    api = ["@api", "state", "run"]
    man += [
        _c("manifest", api, [M(["meta", "dim"], 3.0)]),
        _c("manifest", api, [M(["meta", "dim"], 3.0)], base="zarr"),
        _c("manifest", api, [M(["meta", "hist_cap"], 100000)], expect={"size_bound": True}),
        _c("manifest", ["checkpoint", "hash", "run"], [M(["meta", "hist_cap"], 100000)], expect={"size_bound": True}),
    ]
    ep = [_epoch_expect(c) for c in ep]
    # 3D stores: a material index past the table, the same readers
    ep3 = []
    for base in ("h5_3d", "zarr_3d"):
        ep3 += [
            _c("epoch3d", resume, [A("mat", "i32max")], base),
            _c("epoch3d", hash_, [A("pos", "nan")], base),
            _c("epoch3d", csv, [A("pos", "nan")], base),
            _c("epoch3d", resume, [A("vel", "1e300")], base),
            _c("epoch3d", hash_, [A("hist_n", "all_99")], base),
            _c("epoch3d", api, [A("r", "zero")], base),
        ]
    big_id = dict(A("id", "3e8"), rows=[0.0])  # one disc, so that the ids stay distinct
    ep3.append(_c("epoch3d", resume, [big_id], "zarr_3d", expect={"size_bound": True}))
    ep += [
        _c("epoch", resume, [big_id], "zarr", expect={"size_bound": True}),
        dict(_c("epoch", resume, [big_id], "ddm", expect={"size_bound": True}), heavy=True),
    ]
    ep3.append(_c("epoch3d", hash_, [A("spin", "longer") | {"dom": 5}], "zarr_3d"))
    ep3 = [_epoch_expect(c) for c in ep3]
    # beds: `run --bed` and the bed cache load beds without the store's validation
    B = lambda name, kind, where="bed": {"op": "npz_array", "file": where, "name": name, "kind": kind, "rows": [0.0]}  # noqa: E731
    beds = [
        _bed_case("bed", [B("mat", "999")]),
        _bed_case("bed", [B("r", "zero")]),
        _bed_case("bed", [B("hist_n", "99")]),
        _bed_case("bed", [B("id", "minus7")]),
        _bed_case("bed", [B("mat", "minus1")]),
        _bed_case("bed", [B("pos", "nan")]),
        _bed_case("bed", [B("mat", "i32max")], ["--mode", "ooc", "--domains", "2", "--backend", "zarr"]),
        _bed_case("cache", [B("id", "drop_disc", "cache")]),
        _bed_case("cache", [B("r", "zero", "cache")]),
        _bed_case("cache", [B("pos", "nan", "cache")]),
        _bed_case("cache", [B("mat", "999", "cache")]),
        # a ratio of the state bounds overflowing: numpy's warning made the one-line error three
        _bed_case(
            "bed",
            [B("hist_m", "5e-324"), B("inertia", "huge")],
            ["--mode", "ooc", "--domains", "2", "--backend", "zarr"],
        ),
    ]
    # allocations sized by a declared size: a frame declaring 2^25 rows, an npz member of 4 GB
    # deflated zeros, a gzip zarr chunk inflating to 4 GB
    T = lambda *e, argv=("animate", "run", "--out", "out/f.gif", "--no-progress"): _size_expect(  # noqa: E731
        _c("trajectory", list(argv), list(e), base="traj")
    )
    traj = [
        T({"op": "traj", "frame": 1, "what": "declare_rows", "rows": 2**25, "n_discs": True}),
        T({"op": "traj", "frame": 1, "what": "declare_rows", "rows": 2**25, "n_discs": False}),
        T(
            {"op": "traj", "frame": 0, "what": "declare_rows", "rows": 2**25, "n_discs": True},
            argv=("@api", "trajectory", "run"),
        ),
        T({"op": "traj", "frame": 2, "what": "dataset", "name": "pos", "kind": "nan", "rows": [0.0]}),
        T({"op": "traj", "frame": 2, "what": "dataset", "name": "mat", "kind": "i32max", "rows": [0.0]}),
        T({"op": "traj", "frame": 1, "what": "attr", "key": "n_discs", "value": 2**40}),
        # an array attribute where a string belongs compares element-wise (a traceback)
        T(
            {"op": "traj", "frame": 2, "what": "attr", "key": "format", "value": [1.0, 2.0]},
            argv=("animate", "run", "--out", "out/f.mp4", "--no-progress"),
        ),
    ]
    Z = lambda *e, argv=("report", "run"), base="h5": _size_expect(_c("npz", list(argv), list(e), base=base))  # noqa: E731
    npz = [
        Z({"op": "npz_member", "member": "x", "what": "bomb", "size": 4 << 30}),
        Z({"op": "npz_member", "member": "x", "what": "bomb", "size": 384 * MiB}),
        Z({"op": "npz_member", "member": "x", "what": "bomb", "size": 384 * MiB}, argv=("compare", "run", "run2")),
        Z({"op": "npz_member", "member": "x", "what": "declared", "shape": [2**40], "descr": "<f8"}),
        Z({"op": "npz_member", "member": "x", "what": "object"}),
        Z({"op": "npz_member", "member": "x", "what": "dtype", "descr": "<c16"}),
        Z({"op": "npz_member", "member": "surface", "what": "shape", "shape": [0]}),
        Z({"op": "npz_member", "member": "x", "what": "shape", "shape": [1500, 2]}),
        Z({"op": "npz_member", "member": "y", "what": "shape", "shape": [1]}),
    ]
    zc = lambda codec, argv, base="zarr", **kw: _size_expect(
        _c(  # noqa: E731
            "zarr_codec",
            list(argv),
            [
                {
                    "op": "zarr_codec",
                    "which": "current",
                    "group": "domain",
                    "dom": 0,
                    "name": "pos",
                    "codec": codec,
                    "encode": kw.get("encode", False),
                    **({"size": kw["size"]} if "size" in kw else {}),
                }
            ],
            base=base,
        )
    )
    zarr = [
        zc("gzip_bomb", resume, size=4 << 30),
        zc("gzip_bomb", hash_, size=384 * MiB),
        zc("gzip_bomb", resume, size=384 * MiB),
        zc("gzip_bomb", csv, base="zarr_3d", size=384 * MiB),
        zc("sharding", hash_),
        zc("unknown", hash_),
        zc("gzip", resume, encode=True),
        zc("blosc", verify),
        zc("zstd", ["@api", "state", "run"], base="zarr_zstd"),
    ]
    zarr += [zc("sharding_many", hash_), zc("sharding_many", csv, base="zarr_zstd")]
    for c in zarr:
        if c["edits"][0]["codec"].startswith("sharding"):
            c["fresh"] = True  # zarr's messages at interpreter exit count
    # the 4 GB reproductions take seconds to build: campaigns only (the CI slice has the 512 MB ones)
    for c in npz + zarr:
        if c["edits"][0].get("size", 0) >= 4 << 30:
            c["heavy"] = True
    # a cache rebuild settles a bed (seconds): one in the CI slice, the others in campaigns
    for c in beds:
        if "cache" in c["needs"] and c["edits"][0]["kind"] != "drop_disc":
            c["heavy"] = True
    # writers under a file-size limit (`ulimit -f 100`: 102400 bytes)
    F = lambda argv, base="h5", limit=102400, needs=(): {  # noqa: E731
        "strategy": "fsize",
        "base": base,
        "edits": [],
        "argv": list(argv),
        "fsize": limit,
        "needs": list(needs),
        "timeout": 30,
    }
    fs = [
        F(["checkpoint", "export", "run", "--out", "out/e.xdmf"]),
        F(["checkpoint", "export", "run", "--out", "out/e.xdmf"], base="zarr"),
        F(RESUME30, base="traj", limit=4096),
        F(RESUME30, base="h5", limit=102400),
        F(["animate", "run", "--out", "out/f.mp4", "--no-progress"], base="traj", limit=16384),
        F([*BED_RUN, "--out", "out/r"], needs=("cache",), limit=102400),
    ]
    return {
        "scenario": scen,
        "scenario_file": scen_file,
        "cli": cli,
        "manifest": man,
        "epoch": ep,
        "runfiles": rf,
        "epoch3d": ep3,
        "bed": beds,
        "trajectory": traj,
        "npz": npz,
        "zarr_codec": zarr,
        "fsize": fs,
    }


KNOWN = _known_cases()
