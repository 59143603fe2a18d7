"""`ooc-dem` command line. Every user error is one line on stderr and exit code 2."""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from .errors import OocDemError

EXIT_USAGE = 2
EXIT_OOM = 137      # a profiled run killed by its --memory-limit (128 + SIGKILL, as a shell reports it)


class CliError(OocDemError):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        print(f"ooc-dem: error: {message} (see `{self.prog} --help`)", file=sys.stderr)
        sys.exit(EXIT_USAGE)


def _positive_int(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{_show(text)} is not an integer") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"{_show(text)} must be >= 1")
    return v


def _nonneg_int(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{_show(text)} is not an integer") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"{_show(text)} must be >= 0")
    return v


def _show(text) -> str:
    from .model.scenario import show
    return show(text, 40)


def _count(lo: int, hi: int):
    """An integer flag in [lo, hi]; integral scientific notation (1e6) is accepted."""
    from decimal import Decimal, InvalidOperation
    from .model.scenario import big

    def parse(text):
        allowed = f"an integer in [{lo}, {big(hi)}]" if hi >= 10**6 else f"an integer in [{lo}, {hi}]"
        t = text.strip().replace("_", "")
        try:
            if len(t) > 40:   # also keeps int() clear of Python's digit limit
                raise InvalidOperation
            d = Decimal(t)
            if not d.is_finite() or d != d.to_integral_value():
                raise InvalidOperation
        except (InvalidOperation, ValueError):
            raise argparse.ArgumentTypeError(f"{_show(text)} is not {allowed}") from None
        if not lo <= d <= hi:
            raise argparse.ArgumentTypeError(f"{_show(text)} must be {allowed}")
        return int(d)
    return parse


def _size(text):
    """A memory size: 2GB, 1.5G, 512MiB, 300MB or bytes."""
    from .engine.memlimit import parse_size
    try:
        return parse_size(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _positive_float(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{_show(text)} is not a number") from None
    if not v > 0 or v != v or v == float("inf"):
        raise argparse.ArgumentTypeError(f"{_show(text)} must be a finite number > 0")
    return v


def build_parser() -> argparse.ArgumentParser:
    from .model.scenario import MAX_BLOCK, MAX_DOMAINS, MAX_STEPS
    p = _Parser(prog="ooc-dem", description="Out-of-core 2D DEM of soil-wheel interaction "
                "(serial domain decomposition, bit-identical modes).")
    from . import __version__
    p.add_argument("--version", action="version", version=f"ooc-dem {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    def add_scenario_args(q):
        q.add_argument("scenario", help="built-in name (see `ooc-dem scenarios`) or a TOML file")
        q.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                       help="override a scenario value (repeatable)")

    def add_plan_args(q):
        """The options `run` and `check` share (check validates them exactly as run would)."""
        q.add_argument("--mode", default="monolithic", choices=["monolithic", "ddm", "ooc", "mpi", "mpi-ooc"],
                       help="mpi, mpi-ooc: under mpiexec, serial DDM / out-of-core spread over the ranks")
        q.add_argument("--backend", default="hdf5", choices=["hdf5", "zarr", "memory"],
                       help="memory: the store lives only in this process (no resume); summary, "
                            "series and figures are still written to --out")
        q.add_argument("--compression", default="none", choices=["none", "zstd", "blosc", "gzip", "lzf"],
                       help="compress the store's arrays: zarr zstd|blosc, hdf5 gzip|lzf (default "
                            "none: see the README's Disk economy)")
        q.add_argument("--io-overlap", action="store_true",
                       help="out-of-core: read the next slab and write the last one in threads while a "
                            "slab computes (same bits; up to three slabs resident)")
        q.add_argument("--domains", type=_count(1, MAX_DOMAINS), help="number of sub-domains D (ddm, ooc)")
        q.add_argument("--block", type=_count(1, MAX_BLOCK), help="steps per epoch K (temporal blocking)")
        g = q.add_mutually_exclusive_group()
        g.add_argument("--steps", type=_count(0, MAX_STEPS), help="total steps to run")
        g.add_argument("--duration", type=_positive_float, help="total simulated time to run, s")
        q.add_argument("--checkpoint-every", type=_count(1, MAX_STEPS), metavar="STEPS",
                       help="commit an epoch every STEPS steps")
        q.add_argument("--memory", type=_size, metavar="SIZE",
                       help="memory budget, e.g. 2GB: out-of-core chooses the sub-domains D and "
                            "block K whose slab, halo and I/O buffers fit; other modes are checked "
                            "against it")

    q = sub.add_parser("run", help="run a scenario")
    add_scenario_args(q)
    q.add_argument("--out", required=False, help="output directory (a new store); default runs/<scenario>")
    add_plan_args(q)
    q.add_argument("--durable", action="store_true", help="fsync files and directory before each commit")
    q.add_argument("--bed", help="a prepared bed directory (from `ooc-dem prepare`)")
    q.add_argument("--no-progress", action="store_true")
    q.add_argument("--no-figures", action="store_true")

    q = sub.add_parser("prepare", help="generate and settle the scenario's bed")
    add_scenario_args(q)
    q.add_argument("--out", required=True, help="directory for the settled bed")
    q.add_argument("--no-progress", action="store_true")

    q = sub.add_parser("resume", help="continue a killed or finished run from its last committed epoch")
    q.add_argument("store")
    g = q.add_mutually_exclusive_group()
    g.add_argument("--steps", type=_count(0, MAX_STEPS), help="new total step count")
    g.add_argument("--until", type=_positive_float, help="new total simulated time, s")
    q.add_argument("--mode", choices=["ddm", "mpi", "ooc", "mpi-ooc"],
                   help="continue a ddm (ooc) run on MPI ranks as mpi (mpi-ooc), or the other way round "
                        "(the same epochs)")
    q.add_argument("--no-progress", action="store_true")
    q.add_argument("--no-figures", action="store_true")

    q = sub.add_parser("checkpoint", help="list, verify, inspect, prune and export the epochs of a store")
    csub = q.add_subparsers(dest="ckpt_command", required=True, parser_class=_Parser)
    for name, hlp in (("hash", "the canonical state hash (mset-v2) of the latest state"),
                      ("list", "list committed epochs"),
                      ("verify", "verify checksums and structure (exit 2 if a problem is found)"),
                      ("inspect", "show one epoch")):
        c = csub.add_parser(name, help=hlp)
        c.add_argument("store")
        if name != "list":
            c.add_argument("--epoch", type=_nonneg_int, help="epoch step (default: current)")
    c = csub.add_parser("prune", help="delete committed epochs beyond the newest N (never the current)")
    c.add_argument("store")
    c.add_argument("--keep", type=_positive_int, required=True, metavar="N",
                   help="number of newest committed epochs to keep (>= 1; the current is always kept)")
    c = csub.add_parser("export", help="write one epoch as XDMF+HDF5, VTK or CSV")
    c.add_argument("store")
    c.add_argument("--format", choices=["xdmf", "vtk", "csv"],
                   help="xdmf (NAME.xdmf + NAME.h5), vtk (legacy ASCII .vtk, or XML if --out ends in "
                        ".vtp) or csv; default from the --out suffix")
    c.add_argument("--out", required=True, metavar="FILE", help="output file")
    c.add_argument("--epoch", type=_nonneg_int, help="epoch step (default: current)")

    q = sub.add_parser("export-trajectory", help="write a run's trajectory as an XDMF time series "
                                                 "for ParaView (refers to the frame files in RUN/trajectory/, no copy)")
    q.add_argument("run", metavar="RUN", help="run directory (with trajectory/)")
    q.add_argument("--out", required=True, metavar="FILE.xdmf", help="XDMF file to write (outside the run)")

    q = sub.add_parser("animate", help="render a run's trajectory as a film (MP4 or GIF)")
    q.add_argument("run", metavar="RUN", help="run directory (with trajectory/)")
    q.add_argument("--out", metavar="FILE", help="FILE.mp4 (ffmpeg from imageio-ffmpeg) or FILE.gif; "
                                                 "default RUN.mp4 beside the run directory")
    q.add_argument("--fps", type=_count(1, 120), default=20, help="frames per second (default 20)")
    q.add_argument("--no-progress", action="store_true")

    sub.add_parser("scenarios", help="list built-in scenarios")

    q = sub.add_parser("check", help="validate a scenario and run options as `run` would; print the "
                                     "resolved plan as JSON (no files, no bed, no stepping)")
    add_scenario_args(q)
    add_plan_args(q)

    q = sub.add_parser("report", help="regenerate figures and print the wheel-performance table")
    q.add_argument("store")

    q = sub.add_parser("compare", help="compare two runs (Table 3 style) and their final states")
    q.add_argument("a")
    q.add_argument("b")

    q = sub.add_parser("profile", help="peak RSS of each mode (fresh subprocess each) against monolithic")
    add_scenario_args(q)
    q.add_argument("--modes", default="monolithic,ddm,ooc", help="comma-separated: monolithic,ddm,ooc")
    q.add_argument("--out", required=True, help="directory for memory.json, memory.md, memory.png")
    q.add_argument("--domains", type=_count(1, MAX_DOMAINS))
    q.add_argument("--block", type=_count(1, MAX_BLOCK))
    q.add_argument("--backend", default="hdf5", choices=["hdf5", "zarr"])
    q.add_argument("--steps", type=_count(1, MAX_STEPS), default=200, help="steps measured per mode")
    q.add_argument("--memory-limit", type=_size, metavar="SIZE",
                   help="run each mode under this hard memory limit (a memory cgroup made for it, "
                        "removed after; needs root or a delegated cgroup); a mode that exceeds it is "
                        f"reported as killed by the limit, exit code {EXIT_OOM}")

    q = sub.add_parser("sweep", help="drawbar pull - slip curve (slip-controlled runs)")
    add_scenario_args(q)
    q.add_argument("--slips", required=True, help="comma-separated slips, e.g. 0.1,0.2,0.4")
    q.add_argument("--out", required=True)
    q.add_argument("--no-progress", action="store_true")
    return p


# ------------------------------------------------------------------ commands


def _load(args):
    from .model.scenario import load_scenario
    return load_scenario(args.scenario, args.set)


def cmd_scenarios(args):
    from .model.scenario import builtin_names, load_scenario
    for name in builtin_names():
        if name == "bed-N":
            print("bed-N        bare bed of N discs (e.g. bed-7000, bed-100k, bed-1m), tiled from `bed`")
            continue
        if name == "bed3d-N":
            print("bed3d-N      bare 3D bed of N spheres (e.g. bed3d-20000, bed3d-1m), tiled from "
                  "`bed3d` along x and across the width")
            continue
        sc = load_scenario(name)
        print(f"{name:12s} {sc.scenario.description}")
    return 0


def cmd_prepare(args):
    import numpy as np
    from .app.bed import settled_bed, surface_height, wheel_footprint
    from .app.run import check_bed_memory
    sc = _load(args)
    check_bed_memory(sc)   # before the bed is allocated
    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise CliError(f"--out {out}: directory exists and is not empty")
    bed = settled_bed(sc, progress=None if args.no_progress else _settle_progress(sc))
    out.mkdir(parents=True, exist_ok=True)
    np.savez(out / "bed.npz", **bed.arrays())
    (out / "scenario.toml").write_text(sc.to_toml(), encoding="utf-8")
    surf = surface_height(bed, sc.bin.length, sc.soil.r_max, across=wheel_footprint(sc))
    info = {"scenario": sc.name, "n_discs": len(bed), "surface_height_m": surf,
            "bed_hash": sc.bed_hash()}
    (out / "bed.json").write_text(json.dumps(info, indent=2))
    print(json.dumps(info))
    return 0


def _settle_progress(sc):
    import time
    state = {"last": 0.0}

    def cb(t, speed):
        if time.time() - state["last"] > 1.0:
            state["last"] = time.time()
            print(f"settling bed: t = {t:.3f} s, mean speed {speed:.2e} m/s (target {sc.bed.settle_speed:.1e})",
                  file=sys.stderr, flush=True)
    return cb


def _load_bed(path, sc):
    from .app.bed import read_bed
    from .model.checkpoint import StateError
    f = Path(path) / "bed.npz"
    if not f.is_file():
        raise CliError(f"--bed {path}: no bed.npz (make one with `ooc-dem prepare`)")
    try:
        return read_bed(f, sc, "--bed")   # what a store holding it would be refused for
    except StateError as e:
        raise CliError(str(e)) from None


def _run_options(args):
    from .app.run import RunOptions
    return RunOptions(mode=args.mode, backend=args.backend, domains=args.domains, block=args.block,
                      steps=args.steps, duration=args.duration, checkpoint_every=args.checkpoint_every,
                      durable=getattr(args, "durable", False),
                      memory=getattr(args, "memory", None),
                      progress=not getattr(args, "no_progress", True),
                      figures=not getattr(args, "no_figures", True),
                      compression=None if getattr(args, "compression", "none") == "none" else args.compression,
                      io_overlap=getattr(args, "io_overlap", False))


def cmd_run(args):
    from .app.run import Simulation
    sc = _load(args)
    out = args.out or os.path.join("runs", sc.name)
    sim = Simulation(sc, out, _run_options(args))   # plans and checks everything (ooc-dem check)
    if sim.opts.memory is not None:
        from .engine.budget import fmt_bytes
        p = sim.plan
        print(f"ooc-dem: memory budget {fmt_bytes(p.memory_budget_bytes)}: {p.mode} with D = {p.domains} "
              f"sub-domain{'s' if p.domains > 1 else ''}, K = {p.block} step{'s' if p.block > 1 else ''} per "
              f"sweep; expected peak {fmt_bytes(p.memory_bytes)}", file=sys.stderr, flush=True)
    bed = _load_bed(args.bed, sc) if args.bed else None
    sim.start(bed, streamed=True)   # a tiled bare bed goes into an out-of-core store tile by tile
    summary = sim.run()
    _print_run_result(summary, out)
    return 0


def cmd_check(args):
    """`run`'s validation and planning (Simulation's own plan_run), without a run."""
    from .app.run import plan_run
    sc = _load(args)
    plan = plan_run(sc, _run_options(args))
    print(json.dumps({"scenario_hash": sc.hash(), **plan.as_dict()}, indent=2))
    return 0


def _print_run_result(summary, out):
    from .app.plots import print_table
    if "slip" in summary:
        print(print_table(summary))
    print(f"steps: {summary['steps']}  simulated: {summary['simulated_time_s']:.4f} s  "
          f"wall: {summary['wall_time_s']:.1f} s  discs: {summary['n_discs']}")
    print(f"state hash: {summary['state_hash']}")
    print(f"output: {out}  (shown by `ooc-dem report {out}`; in Python: ooc_dem.open_run({str(out)!r}))")


def cmd_resume(args):
    from .app.run import resume_simulation
    sim = resume_simulation(args.store, steps=args.steps, until=args.until,
                            progress=not args.no_progress, figures=not args.no_figures, mode=args.mode)
    if sim is None:
        return 0
    summary = sim.run()
    _print_run_result(summary, args.store)
    return 0


def _one_line(text) -> str:
    return " ".join(str(text).split())


def _store_leftovers(store, manifest: dict | None = None) -> list:
    """Temporaries and unnamed epoch files of a store (what `resume` would delete)."""
    return store.leftovers(manifest)


def _live_writers(store) -> list[int]:
    """Pids of running processes writing the store (its lock holder, temporaries' writers)."""
    return store.live_writers()


def _read_manifest(store) -> dict:
    """The store's validated manifest as it is now (a run may have committed since opening)."""
    return store.manifest(fresh=True)


def _checkpoint_list(store, path) -> None:
    infos = store.list_epochs()
    if not infos:
        print(f"{path}: no committed epoch")
        return
    for info in infos:
        line = (f"epoch {info.step:>10d}  {info.path}  {info.nbytes / 1e6:8.3f} MB  "
                f"domains {info.n_domains}")
        bad = info.problems
        if bad:
            print(f"{line}  DAMAGED ({bad[0]}{f' and {len(bad) - 1} more' if len(bad) > 1 else ''}) "
                  f"({info.role})")
            continue
        try:
            r = store.read_epoch(info.step, verify=False)   # sizes match; `verify` checks the bytes
            try:
                _, attrs = r.read_globals()
                n = sum(r.domain_len(d) for d in r.domains())
            finally:
                r.close()
            t = attrs.get("time", 0)
            t = f"{t:.6f}" if isinstance(t, (int, float)) else "?"
            print(f"{line}  t = {t} s  discs {n}  ({info.role})")
        except Exception as ex:  # noqa: BLE001 - listing goes on; `verify` names the problem
            print(f"{line}  UNREADABLE ({_one_line(ex)}) ({info.role})")


def _checkpoint_verify(store, args) -> int:
    problems = store.verify(args.epoch)
    if args.epoch is None and store.current() is None:
        print(f"{args.store}: no committed epoch (nothing to verify)")
    m = _read_manifest(store)
    if problems:
        # a run writing the store may have replaced an epoch while it was being checked
        named = {e["step"] for e in (m["current"], m["previous"]) if e}
        gone = {p.step for p in problems if p.step is not None and p.step not in named}
        for s in sorted(gone):
            print(f"note: epoch {s} was superseded by a newer commit while being verified "
                  f"(a run is writing this store)")
        problems = [p for p in problems if p.step not in gone]
    for x in _store_leftovers(store, m):
        if x.running:
            print(f"note: {x.path}: epoch being written by running process {x.pid}")
        else:
            print(f"warning: {x.path}: leftover of an interrupted write, not part of any committed "
                  f"epoch (`ooc-dem resume` deletes it)")
    if problems:
        for pr in problems:
            print(f"FAIL {_one_line(pr)}")
        bad = {p.step for p in problems}
        cur, prev = m["current"], m["previous"]
        hint = ""
        if args.epoch is None and cur and cur["step"] in bad:
            hint = (f"; `ooc-dem resume` falls back to epoch {prev['step']}" if prev and prev["step"] not in bad
                    else "; no intact epoch to resume from")
        raise CliError(f"{args.store}: {len(problems)} problem(s) found{hint}")
    which = store.epochs() if args.epoch is None else [args.epoch]
    print(f"OK: {args.store} epochs {which} verified")
    return 0


def _checkpoint_prune(args) -> int:
    from ooc_dem.storage import open_store
    with open_store(args.store, repair=False) as looking:
        live = _live_writers(looking)
    if live:
        raise CliError(f"{args.store}: a run is writing this store (pid {', '.join(map(str, live))}); "
                       f"prune it when the run has stopped")
    store = open_store(args.store, repair=True)    # the write lock: no run can start meanwhile
    try:
        for p in store.repaired:
            print(f"removed leftover {p}")
        cur = store.current()
        if cur is None:
            print(f"{args.store}: no committed epoch (nothing to prune)")
            return 0
        # never leave only a damaged epoch: the one kept must verify first
        bad = store.verify(cur)
        if bad:
            raise CliError(f"{args.store}: refusing to prune: current epoch {cur} fails verification "
                           f"({_one_line(bad[0])}); the previous epoch is its fallback")
        before = {info.step: info.path for info in store.list_epochs()}
        removed = store.prune(args.keep)
        for s in removed:
            print(f"removed epoch {s} ({before.get(s, '?')})")
        if not removed:
            print(f"nothing to remove: {len(before)} committed epoch(s), keeping up to {args.keep}")
        print(f"kept epochs {store.epochs()} (current {cur})")
        for w in store.warnings:
            print(f"warning: {_one_line(w)}")
        return 0
    finally:
        store.close()


def _checkpoint_export(store, args) -> int:
    from .model.checkpoint import StateError
    from .app.export import ExportError, check_targets, export_snapshot, infer_format, output_files, read_snapshot
    fmt = args.format or infer_format(args.out)
    if fmt is None:
        raise CliError(f"--out {args.out}: cannot tell the format from the suffix; give --format "
                       f"xdmf|vtk|csv")
    out = Path(args.out)
    try:
        check_targets(output_files(fmt, out), out)   # before reading anything
        from .model.checkpoint import open_epoch, stored_layout, validate_epoch
        dim, cap, bounds = stored_layout(store.meta or {}, args.store)
        reader = open_epoch(store, args.epoch)
        try:
            validate_epoch(reader, args.store, dim, cap, bounds)
            # sorted on disk beside the output (never inside the store): bounded memory
            snap = read_snapshot(reader, args.store, workdir=out.resolve().parent)
        finally:
            reader.close()
        with snap:
            files = export_snapshot(snap, fmt, out)
    except (ExportError, StateError) as e:
        raise CliError(str(e)) from None
    _warn_fallback(store)   # after the work: a refusal stays one line
    print(f"exported epoch {snap.step} ({len(snap)} discs, t = {snap.time:.6f} s) as {fmt}: "
          + ", ".join(map(str, files)))
    return 0


def _warn_fallback(store) -> None:
    for w in store.warnings:
        print(f"ooc-dem: warning: {_one_line(w)}", file=sys.stderr)


def cmd_checkpoint(args):
    from .model.checkpoint import hash_epoch, open_epoch, stored_layout, validate_globals
    from ooc_dem.storage import open_store
    if args.ckpt_command == "prune":
        return _checkpoint_prune(args)
    # read-only: no repair (a running writer's temporary epoch must not be deleted under it)
    store = open_store(args.store, repair=False)
    try:
        if args.ckpt_command == "list":
            _checkpoint_list(store, args.store)
            return 0
        if args.ckpt_command == "verify":
            return _checkpoint_verify(store, args)
        if args.ckpt_command == "export":
            return _checkpoint_export(store, args)
        layout = stored_layout(store.meta or {}, args.store) if args.ckpt_command == "hash" else None
        reader = open_epoch(store, args.epoch)
        try:
            if args.ckpt_command == "hash":
                # streamed and validated as read: a store larger than RAM hashes too
                out = hash_epoch(reader, args.store, *layout)
            else:  # inspect
                arrays, attrs = reader.read_globals()
                validate_globals(arrays, attrs, f"{args.store}: epoch {reader.step}", reader.step)
                info = {"step": attrs["step"], "time": attrs.get("time"),
                        "discs": sum(reader.domain_len(d) for d in reader.domains()),
                        "domains": {str(d): reader.domain_len(d) for d in reader.domains()},
                        "wheel_state": [float(v) for v in arrays["wheel_state"]],
                        "mode": attrs.get("mode")}
                out = json.dumps(info, indent=2)
        finally:
            reader.close()
        _warn_fallback(store)   # after the work: a refusal stays one line
        print(out)
        return 0
    finally:
        store.close()


def cmd_export_trajectory(args):
    from .app.export import ExportError
    from .app.runfiles import read_run_scenario
    from .app.trajectory import Trajectory, write_xdmf
    with Trajectory.of_run(args.run) as traj:
        try:
            out = write_xdmf(traj, args.out, read_run_scenario(Path(args.run)))
        except ExportError as e:
            raise CliError(str(e)) from None
        n, t = len(traj), (float(traj.times[-1]) if len(traj) else 0.0)
    print(f"exported {n} frames (t = 0 .. {t:.6f} s) of {traj.path} as XDMF: {out} "
          f"(open it in ParaView; it refers to the files of {traj.path.name}, keep both)")
    return 0


def cmd_animate(args):
    from .app.animate import animate
    from .app.export import ExportError
    try:
        out, n = animate(args.run, args.out, fps=args.fps, progress=not args.no_progress)
    except ExportError as e:
        raise CliError(str(e)) from None
    print(f"animation: {out} ({n} frames at {args.fps} fps)")
    return 0


def cmd_report(args):
    from .app.plots import make_figures, print_table, read_summary
    out = Path(args.store)
    summary = read_summary(out)   # validated: a hostile or foreign file is a one-line error
    if "slip" in summary:
        figs = make_figures(out)
        print(print_table(summary))
        for fig in figs:
            print(f"figure: {fig}")
    else:
        print(json.dumps(summary, indent=2))
    return 0


def cmd_compare(args):
    from .app.compare import compare_runs
    print(compare_runs(args.a, args.b))
    return 0


def cmd_sweep(args):
    from .app.sweep_slip import run_slip_sweep
    try:
        slips = [float(s) for s in args.slips.split(",") if s.strip()]
    except ValueError:
        raise CliError(f"--slips {args.slips!r}: must be comma-separated numbers") from None
    if not slips or any(not (0.0 <= s < 1.0) for s in slips):
        raise CliError(f"--slips {args.slips!r}: each slip must be in [0, 1)")
    run_slip_sweep(args.scenario, args.set, slips, Path(args.out), progress=not args.no_progress,
                   comm=getattr(args, "comm", None))
    return 0


def cmd_profile(args):
    from .app.profiling import MODES, profile
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    bad = [m for m in modes if m not in MODES]
    if not modes or bad:
        raise CliError(f"--modes {args.modes!r}: each must be one of {', '.join(MODES)}")
    _load(args)  # validate the scenario and overrides before spawning anything
    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise CliError(f"--out {out}: directory exists and is not empty")
    from .engine.memlimit import MemoryLimitError
    from .app.profiling import OomKilled
    try:
        doc = profile(args.scenario, modes, out, overrides=args.set, backend=args.backend,
                      domains=args.domains, block=args.block, steps=args.steps,
                      memory_limit=args.memory_limit)
    except OomKilled as e:
        print(f"ooc-dem: error: {e}", file=sys.stderr)
        return EXIT_OOM
    except MemoryLimitError as e:
        raise CliError(f"--memory-limit: {e}") from None
    except RuntimeError as e:
        raise CliError(str(e)) from None
    print((out / "memory.md").read_text())
    for r in doc["runs"]:
        if r.get("above_baseline_ratio_to_monolithic") is not None and r["mode"] != "monolithic":
            print(f"{r['mode']}: peak above baseline = {r['above_baseline_ratio_to_monolithic']:.3f} x monolithic")
    for r in doc["runs"]:
        lim = r.get("memory_limit")
        if lim:
            print(f"{r['mode']}: under the {lim['memory_limit_bytes'] / 1e6:.1f} MB limit (cgroup v"
                  f"{lim['cgroup_version']}): peak RSS {lim['peak_rss_bytes'] / 1e6:.1f} MB (anonymous "
                  f"{lim['sampled_peak_anon_bytes'] / 1e6:.1f} MB), cgroup peak "
                  f"{lim['cgroup_peak_bytes'] / 1e6:.1f} MB, {lim['rss_samples']} RSS samples over "
                  f"{lim['wall_s']:.1f} s")
    print(f"report: {out / 'memory.json'}  {out / 'memory.md'}  figure: {out / 'memory.png'}")
    return 0


COMMANDS = {"check": cmd_check, "profile": cmd_profile, "run": cmd_run, "prepare": cmd_prepare, "resume": cmd_resume, "checkpoint": cmd_checkpoint,
            "scenarios": cmd_scenarios, "export-trajectory": cmd_export_trajectory, "animate": cmd_animate, "report": cmd_report, "compare": cmd_compare, "sweep": cmd_sweep}


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    known = OocDemError   # every error for the user: its one-line message, exit 2
    if args.command in ("run", "resume"):
        from .engine.mpi import launched, run_ranks
        if launched()[0] > 1:   # under mpiexec: rank 0 runs the command, the others serve it
            return run_ranks(lambda: _dispatch(args, known))
    if args.command == "sweep":
        from .engine.mpi import launched, run_everywhere, world
        if launched()[0] > 1:   # under mpiexec: the slips' runs fan out over the ranks
            args.comm = world()
            # the same plan on every rank fails alike: rank 0 alone says so
            return run_everywhere(args.comm, lambda: _dispatch(args, known, quiet=args.comm.Get_rank() != 0))
    return _dispatch(args, known)


def _dispatch(args, known, quiet: bool = False) -> int:
    try:
        return COMMANDS[args.command](args)
    except known as e:
        msg = _one_line(e) or type(e).__name__
        if not quiet:
            print(f"ooc-dem: error: {msg}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("ooc-dem: interrupted (the last committed epoch is kept; `ooc-dem resume` continues)",
              file=sys.stderr)
        return 130
    except OSError as e:
        where = f"{e.filename}: " if e.filename else ""
        print(f"ooc-dem: error: {where}{_one_line(e.strerror or e)}", file=sys.stderr)
        return EXIT_USAGE
    except MemoryError as e:
        # the plan refuses runs that cannot fit (estimated); this is the machine disagreeing
        detail = _one_line(e) or "an allocation failed"
        print(f"ooc-dem: error: out of memory ({detail}); the last committed epoch is kept",
              file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
