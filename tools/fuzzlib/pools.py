"""The pools the strategies draw from (commands, declared sizes, file-size limits), the
expectations of a case, and the flags of a command drawn from the real parser."""

from __future__ import annotations

from .common import BED_RUN, _opt
from .values import (
    BED_NAMES,
    BLOCK_VALUES,
    DOMAIN_VALUES,
    DURATION_VALUES,
    EPOCH_VALUES,
    HUGE_DIGITS,
    KEEP_VALUES,
    STEPS_VALUES,
    STORE_ARGS,
    UNTIL_VALUES,
)


MiB = 1 << 20
TRAJ_FIELDS = ["id", "pos", "vel", "spin", "r", "mat"]
DECLARED_ROWS = [2**20, 2**22, 2**25, 2**28, 2**31, 2**40 + 1]
BOMB_SIZES = [384 * MiB, 1024 * MiB]  # inflated sizes (each a few hundred KB on disk), > SIZE_BOUND
DECLARED_SHAPES = [[2**40], [2**31], [2**28], [2**62, 2**62], [1500, 2**30], [2**25]]
RESUME30 = ["resume", "run", "--steps", "30", "--no-progress", "--no-figures"]
EPOCH3D_CMDS = [
    ["checkpoint", "hash", "run"],
    ["checkpoint", "hash", "run"],
    ["checkpoint", "verify", "run"],
    ["checkpoint", "inspect", "run"],
    ["checkpoint", "export", "run", "--out", "out/s.csv"],
    ["checkpoint", "export", "run", "--out", "out/s.xdmf"],
    RESUME30,
    RESUME30,
    ["@api", "state", "run"],
]
TRAJ_CMDS = [
    ["animate", "run", "--out", "out/f.gif", "--no-progress"],
    ["animate", "run", "--out", "out/f.mp4", "--no-progress"],
    ["report", "run"],
    ["@api", "trajectory", "run"],
    ["@api", "trajectory", "run"],
    ["export-trajectory", "run", "--out", "out/t.xdmf"],
    RESUME30,
]
NPZ_CMDS = [
    ["report", "run"],
    ["report", "run"],
    ["compare", "run", "run2"],
    ["compare", "run2", "run"],
    ["animate", "run", "--out", "out/f.gif", "--no-progress"],
]
ZARR_CMDS = [
    RESUME30,
    RESUME30,
    ["checkpoint", "hash", "run"],
    ["checkpoint", "hash", "run"],
    ["checkpoint", "export", "run", "--out", "out/s.csv"],
    ["checkpoint", "export", "run", "--out", "out/s.vtp"],
    ["checkpoint", "verify", "run"],
    ["@api", "state", "run"],
]
FSIZE_LIMITS = [1024, 4096, 16384, 102400, 262144, 1 << 20, 4 << 20]
FSIZE_CMDS = (
    [
        (["checkpoint", "export", "run", "--out", f"out/e.{x}"], b, ())
        for x in ("csv", "xdmf", "vtk", "vtp")
        for b in ("h5", "zarr")
    ]
    + [(["checkpoint", "export", "run", "--out", "out/e.xdmf"], "h5_3d", ())]
    + [(RESUME30, b, ()) for b in ("h5", "zarr", "traj", "h5_3d")]
    + [
        ([*BED_RUN, "--out", "out/r"], "h5", ("cache",)),
        ([*BED_RUN, "--backend", "zarr", "--out", "out/r"], "h5", ("cache",)),
    ]
    + [(["animate", "run", "--out", f"out/f.{x}", "--no-progress"], "traj", ()) for x in ("mp4", "gif")]
    + [(["export-trajectory", "run", "--out", "out/t.xdmf"], "traj", ())]
)


def invalid_bed(edits) -> bool:
    """Whether the edits make a bed file detectably invalid (the store's own invariants)."""
    for ed in edits:
        n, k = ed.get("name"), ed.get("kind")
        if k in ("delete", "drop_disc", "remove_file", "shorter", "longer", "empty", "2d"):
            return True
        if (
            (n in FINITE and k in ("nan", "inf", "all_nan"))
            or (n == "id" and k in ("dup", "neg", "minus7", "minus1"))
            or (n == "hist_n" and k in ("99", "all_99", "neg", "999", "i32max", "minus7", "minus1"))
            or (n == "mat" and k in ("99", "all_99", "neg", "999", "i32max", "minus7", "minus1", "huge"))
            or (n in ("r", "mass", "inertia") and k in ("zero", "neg", "minus7", "minus1", "5e-324", "-5e-324"))
            or (n in ("vel", "spin") and k in ("1e300", "huge"))
        ):
            return True
    return False


def _bed_case(where, edits, extra=()) -> dict:
    """A run from an edited prepared bed (``where`` = "bed") or bed-cache entry ("cache"): a
    detectably invalid bed is refused; a cache entry that fails is rebuilt (the intact run's
    bits) or refused; whatever exits 0 leaves a store its own `resume` accepts."""
    bad = invalid_bed(edits)
    if where == "bed":
        argv = [*BED_RUN, *extra, "--bed", "out/bed", "--out", "out/r"]
        expect = {"resumable": 6, **({"refuse": "a run from a detectably invalid bed exited 0"} if bad else {})}
        return {"strategy": "bed", "base": "h5", "edits": edits, "argv": argv, "needs": ["bed"], "expect": expect}
    argv = [*BED_RUN, *extra, "--out", "out/r"]
    expect = {"resumable": 6, **({"same_as_intact_cache": True} if bad and not extra else {})}
    return {
        "strategy": "bed",
        "base": "h5",
        "edits": edits,
        "argv": argv,
        "needs": ["cache"],
        "expect": expect,
        "timeout": 60,
    }


def _size_expect(case: dict) -> dict:
    """A hostile declared size (rows, members, inflated chunks) is refused under SIZE_BOUND."""
    for ed in case["edits"]:
        if ed.get("what") in ("declare_rows", "bomb", "declared") or ed.get("codec") == "gzip_bomb":
            case.setdefault("expect", {})["size_bound"] = True
    return case


PER_DISC = ("id", "pos", "vel", "spin", "r", "mass", "inertia", "mat", "hist_n")
FINITE = ("pos", "vel", "spin", "r", "mass", "inertia", "hist_s", "hist_m")


def invalid_current(edits) -> bool:
    """Whether the edits make the current epoch's state detectably invalid (not finite, duplicate
    ids, history counts beyond capacity, arrays of the wrong length, bad wheel state, missing
    step/time attributes), whatever the checksums say."""
    for ed in edits:
        if ed.get("which") != "current":
            continue
        if ed["op"] == "array":
            n, k = ed["name"], ed["kind"]
            if k == "delete":
                return True
            if ed["group"] == "domain":
                if (
                    (n in FINITE and k in ("nan", "inf", "all_nan"))
                    or (n == "id" and k == "dup")
                    or (n == "hist_n" and k in ("99", "all_99", "neg"))
                    or (n in PER_DISC and k in ("shorter", "longer", "empty", "2d"))
                ):
                    return True
                # finite absurd values and indices out of range (the step's arithmetic and
                # the material table); 2D and 3D
                if (
                    (n == "mat" and k in ("999", "i32max", "minus1", "minus7"))
                    or (n == "id" and k in ("minus1", "minus7"))
                    or (n == "hist_n" and k in ("999", "i32max", "minus1", "minus7"))
                    or (n in ("r", "mass", "inertia") and k in ("5e-324", "-5e-324", "minus1", "minus7"))
                    or (n in ("vel", "spin") and k == "1e300")
                    or (n in ("r", "mass", "inertia") and k == "zero")
                    or (n in FINITE and k in ("float32", "int32", "complex", "u8", "bool"))
                ):
                    return True
            elif n == "wheel_state" and k in ("nan", "inf", "all_nan", "shorter", "longer", "empty", "2d"):
                return True
        elif (
            ed["op"] == "attrs"
            and ed["group"] == "globals"
            and ed["value"] in (None, "garbage", "[]", "null", '"\u0000"', "[" * 100000, '{"step": "x"}')
        ):
            return True
    return False


def _without_noop_expectations(case: dict) -> dict:
    """The case's expectations as if its edits that changed nothing had not been made."""
    real = [ed for ed in case["edits"] if not ed.get("noop")]
    if invalid_current(real):
        return case
    expect = {
        k: v
        for k, v in case.get("expect", {}).items()
        if k not in ("same_bits_as_intact", "hash_fallback", "export_fallback")
    }
    return dict(case, expect=expect)


def _epoch_expect(case: dict) -> dict:
    """`checkpoint verify` must not accept an epoch whose bytes changed without a checksum fix;
    `resume` of a detectably invalid current epoch must refuse or fall back (same final bits)."""
    argv = case["argv"]
    # the intact bits only when the epoch a fallback resumes is intact: a previous epoch edited
    # with its checksums recomputed holds another state that no reader can tell from the real one
    previous_edited = any(
        ed.get("which") == "previous" and (ed["op"] in ("array", "attrs") or ed.get("recompute"))
        for ed in case["edits"]
    )
    if argv[0] == "resume" and invalid_current(case["edits"]) and not previous_edited:
        case.setdefault("expect", {})["same_bits_as_intact"] = True
    # the readers of an epoch validate it as resume does: `hash` of a detectably invalid
    # current epoch refuses or falls back to the previous one (its hash)
    only_current = invalid_current(case["edits"]) and all(
        ed.get("which") == "current" and ed["op"] in ("array", "attrs") for ed in case["edits"]
    )
    if argv[:2] == ["checkpoint", "hash"] and _opt(argv, "--epoch") is None and only_current:
        case.setdefault("expect", {})["hash_fallback"] = True
    # ... and `export` of it refuses or writes the previous epoch
    if (
        argv[:2] == ["checkpoint", "export"]
        and _opt(argv, "--epoch") is None
        and only_current
        and (_opt(argv, "--out") or "").endswith(".csv")
    ):
        case.setdefault("expect", {})["export_fallback"] = True
    damaged = set()
    for ed in case["edits"]:
        if ed["op"] == "flip" and not ed.get("recompute"):
            damaged.add(ed["which"])
        if ed["op"] == "truncate" and not ed.get("recompute") and (ed["frac"] < 1 or ed.get("extra")):
            damaged.add(ed["which"])
        if ed["op"] in ("array", "attrs"):  # these recompute every checksum of their epoch, so
            damaged.discard(ed["which"])  # earlier damage there is covered by new checksums
    if argv[:2] == ["checkpoint", "verify"] and damaged:
        epoch = _opt(argv, "--epoch")
        if epoch is None or (epoch == "10" and "previous" in damaged) or (epoch == "20" and "current" in damaged):
            case.setdefault("expect", {})["refuse"] = (
                f"verify exit 0 although the {'/'.join(sorted(damaged))} epoch's bytes changed "
                f"(checksums not recomputed)"
            )
    return case


def _draw_args(draw, st, parser, cmd, sub, set_st) -> list[str]:
    """Positionals and options of one (sub)parser, from the hostile pools; long runs are kept short."""
    import argparse

    argv: list[str] = []
    opts: list[str] = []
    for a in parser._actions:
        if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        if not a.option_strings:  # positional
            if a.dest == "scenario":
                names = [
                    "quick",
                    "quick",
                    "quick",
                    "bed-1200",
                    "run/scenario.toml",
                    "victim_file",
                    "link_zero",
                    "nonexistent.toml",
                    "",
                    "run",
                    "dev_null",
                ] + BED_NAMES[:12]
                if cmd != "check":
                    # a valid million-disc bed is a real run, not a tiny one (check only plans it);
                    # substituted in place, so the draws of every other case stay the same
                    names = [n if n != "bed-1m" else "bed-100000m" for n in names]
                v = draw(st.sampled_from(names))
            else:
                v = draw(st.sampled_from(STORE_ARGS))
            argv.append(v)
            continue
        name = a.option_strings[-1]
        if a.dest in ("no_progress", "no_figures"):
            continue  # added below
        if draw(st.integers(0, 2)) != 0 and not (a.required and draw(st.integers(0, 20)) != 0):
            continue
        if a.nargs == 0:
            opts.append(name)
            continue
        if a.choices:
            v = draw(st.sampled_from(list(a.choices) + ["", "x", "HDF5"]))
        else:
            v = draw(st.sampled_from(_pool(a.dest, cmd, sub)))
        if a.dest == "set":
            for _ in range(draw(st.integers(1, 3))):
                opts += [name, draw(set_st)]
            continue
        opts += [name, v]
    # keep simulations tiny: `run` always gets a small step count or a hostile duration
    if cmd == "run":
        opts = _strip(opts, ("--steps", "--duration"))
        if draw(st.integers(0, 3)) == 0:
            opts += [
                "--duration",
                draw(st.sampled_from([d for d in DURATION_VALUES if d not in ("1e-5", "0.00002")] + ["0.00002"])),
            ]
        else:
            opts += ["--steps", draw(st.sampled_from(["0", "1", "3", "5", "100000000000", "1e11", "-1"]))]
    if cmd == "resume":
        opts = _strip(opts, ("--steps", "--until"))
        k = draw(st.integers(0, 2))
        if k == 0:
            opts += ["--steps", draw(st.sampled_from(["20", "21", "25", "30", "0", "10"] + STEPS_VALUES[4:]))]
        elif k == 1:
            opts += ["--until", draw(st.sampled_from(UNTIL_VALUES))]
    if cmd == "sweep":
        opts += [
            "--set",
            "wheel.settle_time=0",
            "--set",
            "wheel.travel_time=0.0001",
            "--set",
            "output.steady_start=0",
            "--set",
            "output.steady_end=0.0001",
        ]
    if cmd == "profile":  # never spawn: the --out check refuses first
        opts = _strip(opts, ("--out",)) + ["--out", "victim"]
    if cmd in ("run", "resume", "prepare", "sweep") and draw(st.integers(0, 5)) != 0:
        opts.append("--no-progress")
    if cmd in ("run", "resume") and draw(st.integers(0, 5)) != 0:
        opts.append("--no-figures")
    return argv + opts


def _strip(opts, names):
    out, skip = [], False
    for o in opts:
        if skip:
            skip = False
            continue
        if o in names:
            skip = True
            continue
        out.append(o)
    return out


EXPORT_OUTS_OK = [
    "out/s.csv",
    "out/s.xdmf",
    "out/s.vtk",
    "out/s.vtp",
    "out/noext",
    "out/sub/deep/s.csv",
    "out/s.CSV",
    "out/.csv",
    "out/s.h5",
]
EXPORT_OUTS_BAD = {
    "run/MANIFEST.json": "over the store's MANIFEST.json",
    "run/epochs/e000000000020.h5": "over an epoch file",
    "run/epochs/e000000000010.h5": "over an epoch file",
    "run/epochs/e000000000020.zarr/zarr.json": "over an epoch file",
    "run/epochs/e000000000020.zarr/domains/d0000/x/c/0": "over an epoch file",
    "run/epochs/../MANIFEST.json": "over the store's MANIFEST.json",
    "dev_null": "to a device node",
    "dev_full": "to a device node",
    "link_zero": "to a device node",
    "run": "over the store directory",
    "out": "over a directory",
    "run/epochs/x.csv": "inside epochs/",
}

# hostile values per option destination of the real parser (anything else: GENERIC_VALUES)
OPTION_POOLS = {
    "steps": STEPS_VALUES,
    "duration": DURATION_VALUES,
    "until": UNTIL_VALUES,
    "domains": DOMAIN_VALUES,
    "block": BLOCK_VALUES,
    "epoch": EPOCH_VALUES,
    "keep": KEEP_VALUES,
    "checkpoint_every": ["1", "2", "10", "0", "-1", "100000000000", HUGE_DIGITS, "abc"],
    "slips": [
        "0.1",
        "0.1,0.2",
        "abc",
        "",
        ",",
        "nan",
        "inf",
        "1",
        "-0.0",
        "0.99999999999",
        "1e-300",
        "0.1,abc",
        "-1",
        "0.5,0.5",
        HUGE_DIGITS,
    ],
    "modes": ["monolithic", "gpu", "", ",", "monolithic,ddm,ooc", "ooc,ooc", "é🦀"],
    "bed": ["run", "out", "victim", "link_zero", "nonexistent", "victim_file", "", "dev_null", "run2"],
    "out": [
        "out/x",
        "out/x",
        "run",
        "run2",
        "victim",
        "victim_file",
        "link_victim",
        "link_file",
        "dev_null",
        "",
        "out",
        "runs/y",
        "out/é🦀",
        "out/" + "x" * 300,
        "run/epochs",
    ],
    "format": ["xdmf", "vtk", "csv"],
}
EXPORT_OUT_POOL = EXPORT_OUTS_OK + list(EXPORT_OUTS_BAD)  # `checkpoint export --out`
GENERIC_VALUES = ["", "x", "0", "-1", "1e308", "nan", HUGE_DIGITS, "é🦀"]


def _pool(dest, cmd, sub) -> list[str]:
    if dest == "out" and cmd == "checkpoint":
        return EXPORT_OUT_POOL
    return OPTION_POOLS.get(dest, GENERIC_VALUES)
