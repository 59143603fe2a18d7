"""The `ooc-dem` commands but `checkpoint` (``cli_checkpoint.py``): each takes the parsed
arguments and returns the exit code; a user error is a ``CliError`` (one line)."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from .cli_parser import EXIT_OOM, CliError

if TYPE_CHECKING:
    from collections.abc import Callable

    from ..model.scenario import Scenario
    from ..model.state import Particles
    from .bed import SettleProgress
    from .plan import RunOptions, RunPlan


def _load(args: argparse.Namespace) -> Scenario:
    from ..model.scenario import load_scenario

    return load_scenario(args.scenario, args.set)


def _load_advised(args: argparse.Namespace) -> tuple[Scenario, Callable[[RunPlan], None]]:
    """The scenario, and what prints its warnings (app/advice.py) once its run is planned."""
    from ..model.scenario import scenario_tables
    from ..model.scenario_check import scenario_from_dict
    from .advice import scenario_warnings

    tables, base = scenario_tables(args.scenario, args.set)
    sc = scenario_from_dict(tables)

    def warn(plan: RunPlan) -> None:
        for line in scenario_warnings(sc, plan, tables, base):
            print(f"ooc-dem: warning: {line}", file=sys.stderr, flush=True)

    return sc, warn


def cmd_scenarios(args: argparse.Namespace) -> int:
    from ..model.scenario import builtin_names, load_scenario

    if args.show is not None:
        print(_shown_scenario(args.show), end="")
        return 0
    for name in builtin_names():
        if name == "bed-N":
            print("bed-N        bare bed of N discs (e.g. bed-7000, bed-100k, bed-1m), tiled from `bed`")
            continue
        if name == "bed3d-N":
            print(
                "bed3d-N      bare 3D bed of N spheres (e.g. bed3d-20000, bed3d-1m), tiled from "
                "`bed3d` along x and across the width"
            )
            continue
        sc = load_scenario(name)
        print(f"{name:12s} {sc.scenario.description}")
    return 0


def _shown_scenario(source: str) -> str:
    """`scenarios --show`: the resolved scenario as a complete, commented TOML."""
    from ..model.scenario import load_scenario
    from ..model.scenario_doc import commented_toml

    sc = load_scenario(source)
    return commented_toml(
        sc,
        [
            f"{sc.name}: {' '.join(sc.scenario.description.split())}",
            f"The resolved scenario of {source!r} with every key, its [unit] and meaning",
            "(docs/parameters.md; `ooc-dem scenarios --show` prints it). A file that changes",
            f'a few keys may instead start with base = "{source}" and hold only those.',
            f"scenario_hash = {sc.hash()}",
        ],
    )


def cmd_prepare(args: argparse.Namespace) -> int:
    import numpy as np
    from .bed import bed_info, settled_bed, surface_height, wheel_footprint
    from .plan import check_bed_memory

    sc = _load(args)
    check_bed_memory(sc)  # before the bed is allocated
    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise CliError(f"--out {out}: directory exists and is not empty")
    bed = settled_bed(sc, progress=None if args.no_progress else _settle_progress(sc))
    out.mkdir(parents=True, exist_ok=True)
    columns: dict[str, Any] = bed.arrays()  # Any: savez's stub would match a column to allow_pickle
    np.savez(out / "bed.npz", **columns)
    (out / "scenario.toml").write_text(sc.to_toml(), encoding="utf-8")
    surf = surface_height(bed, sc.bin.length, sc.soil.r_max, across=wheel_footprint(sc))
    info = bed_info(sc, bed, surf)
    (out / "bed.json").write_text(json.dumps(info, indent=2))
    print(json.dumps(info))
    return 0


def _settle_progress(sc: Scenario) -> SettleProgress:
    import time

    state = {"last": 0.0}

    def cb(t: float, speed: float) -> None:
        if time.time() - state["last"] > 1.0:
            state["last"] = time.time()
            print(
                f"settling bed: t = {t:.3f} s, mean speed {speed:.2e} m/s (target {sc.bed.settle_speed:.1e})",
                file=sys.stderr,
                flush=True,
            )

    return cb


def load_bed(path: str | os.PathLike[str], sc: Scenario) -> Particles:
    from .bed import read_bed
    from ..model.state_check import StateError

    f = Path(path) / "bed.npz"
    if not f.is_file():
        raise CliError(f"--bed {path}: no bed.npz (make one with `ooc-dem prepare`)")
    try:
        return read_bed(f, sc, "--bed")  # what a store holding it would be refused for
    except StateError as e:
        raise CliError(str(e)) from None


def _run_options(args: argparse.Namespace) -> RunOptions:
    from .plan import RunOptions

    return RunOptions(
        mode=args.mode,
        backend=args.backend,
        domains=args.domains,
        block=args.block,
        steps=args.steps,
        duration=args.duration,
        checkpoint_every=args.checkpoint_every,
        durable=getattr(args, "durable", False),
        memory=getattr(args, "memory", None),
        progress=not getattr(args, "no_progress", True),
        figures=not getattr(args, "no_figures", True),
        compression=None if getattr(args, "compression", "none") == "none" else args.compression,
        io_overlap=getattr(args, "io_overlap", False),
    )


def cmd_run(args: argparse.Namespace) -> int:
    from .run import Simulation

    sc, warn = _load_advised(args)
    out = args.out or os.path.join("runs", sc.name)
    sim = Simulation(sc, out, _run_options(args))  # plans and checks everything (ooc-dem check)
    warn(sim.plan)
    if sim.opts.memory is not None:
        from ..engine.budget import fmt_bytes

        p = sim.plan
        # the plan records the --memory it was sized for
        assert p.memory_budget_bytes is not None, "a --memory plan without its budget"
        print(
            f"ooc-dem: memory budget {fmt_bytes(p.memory_budget_bytes)}: {p.mode} with D = {p.domains} "
            f"sub-domain{'s' if p.domains > 1 else ''}, K = {p.block} step{'s' if p.block > 1 else ''} per "
            f"sweep; expected peak {fmt_bytes(p.memory_bytes)}",
            file=sys.stderr,
            flush=True,
        )
    bed = load_bed(args.bed, sc) if args.bed else None
    sim.start(bed, streamed=True)  # a tiled bare bed goes into an out-of-core store tile by tile
    summary = sim.run()
    _print_run_result(summary, out)
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    """`run`'s validation and planning (Simulation's own plan_run), without a run."""
    from .plan import estimate_wall_time, plan_run

    sc, warn = _load_advised(args)
    plan = plan_run(sc, _run_options(args))
    warn(plan)
    estimate = estimate_wall_time(sc, plan.steps)
    doc = {"scenario_hash": sc.hash(), **plan.as_dict(), "estimated_wall_time": estimate}
    print(json.dumps(human_floats(doc), indent=2))
    return 0


def human_floats(obj: Any) -> Any:
    """``obj`` with every float cut to 12 significant digits: derived values print as people
    read them (46.0 s, not 46.00000000000001); the files keep full precision."""
    if isinstance(obj, float):
        return float(f"{obj:.12g}") if math.isfinite(obj) else obj
    if isinstance(obj, dict):
        return {k: human_floats(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [human_floats(v) for v in obj]
    return obj


def _print_run_result(summary: dict[str, Any], out: str | os.PathLike[str]) -> None:
    from .tables import print_table

    if "slip" in summary:
        print(print_table(summary))
    omega = summary.get("omega")  # a free-spinning wheel's (wheel.control torque, towed)
    if isinstance(omega, dict):
        shown = [
            f"{win.replace('_', ' ')} {omega[win]['value']:.4f}"
            for win in ("steady", "whole_travel")
            if isinstance(omega.get(win), dict) and isinstance(omega[win].get("value"), float)
        ]
        if shown:
            print(f"wheel omega (measured, rad/s): {', '.join(shown)}")
    print(
        f"steps: {summary['steps']}  simulated: {summary['simulated_time_s']:.4f} s  "
        f"wall: {summary['wall_time_s']:.1f} s  discs: {summary['n_discs']}"
    )
    if isinstance(summary.get("bed"), dict):
        print(bed_line(summary["bed"]))
    _print_repose(summary)
    print(f"state hash: {summary['state_hash']}")
    print(f"output: {out}  (shown by `ooc-dem report {out}`; in Python: ooc_dem.open_run({str(out)!r}))")


def _print_repose(summary: dict[str, Any], stream: TextIO | None = None) -> None:
    """The angle of repose in one line, when the summary holds one (2D or 3D)."""
    from .repose import angle_line

    line = angle_line(summary.get("repose"))
    if line is not None:
        print(line, file=stream or sys.stdout)


def bed_line(info: dict[str, Any]) -> str:
    """One line of a bed's report (bed.json, summary.json's ``bed``)."""
    g = info.get("grading") or {}

    def num(v: Any, fmt: str, scale: float = 1.0) -> str:
        return format(v * scale, fmt) if isinstance(v, (int, float)) else "?"

    return (
        f"bed: bulk density {num(info.get('bulk_density_kg_m3'), '.0f')} kg/m3, porosity "
        f"{num(info.get('porosity'), '.3f')}, coordination number {num(info.get('coordination_number'), '.2f')}, "
        f"d10/d50/d60 {num(g.get('d10_m'), '.3f', 1e3)}/{num(g.get('d50_m'), '.3f', 1e3)}/"
        f"{num(g.get('d60_m'), '.3f', 1e3)} mm, Cu {num(g.get('cu'), '.2f')}"
    )


def cmd_resume(args: argparse.Namespace) -> int:
    from .run import resume_simulation

    sim = resume_simulation(
        args.store,
        steps=args.steps,
        until=args.until,
        progress=not args.no_progress,
        figures=not args.no_figures,
        mode=args.mode,
    )
    if sim is None:
        return 0
    summary = sim.run()
    _print_run_result(summary, args.store)
    return 0


def cmd_export_trajectory(args: argparse.Namespace) -> int:
    from .outfile import ExportError
    from .runfiles import read_run_scenario
    from .trajectory_export import write_xdmf
    from .trajectory_read import Trajectory

    with Trajectory.of_run(args.run) as traj:
        try:
            files = write_xdmf(traj, args.out, read_run_scenario(Path(args.run)))
        except ExportError as e:
            raise CliError(str(e)) from None
        n, t = len(traj), (float(traj.times[-1]) if len(traj) else 0.0)
    print(
        f"exported {n} frames (t = 0 .. {t:.6f} s) of {traj.path} as XDMF 3 time series: "
        + ", ".join(map(str, files))
        + " (ParaView, meshio)"
    )
    return 0


def cmd_animate(args: argparse.Namespace) -> int:
    from .animate import animate
    from .outfile import ExportError

    try:
        out, n = animate(args.run, args.out, fps=args.fps, progress=not args.no_progress, colour=args.colour)
    except ExportError as e:
        raise CliError(str(e)) from None
    print(f"animation: {out} ({n} frames at {args.fps} fps)")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from .drawing import EXTRA_FORMATS, also_saved_as

    formats = tuple(f.strip().lower() for f in args.formats.split(",") if f.strip())
    bad = [f for f in formats if f not in EXTRA_FORMATS]
    if bad:
        raise CliError(f"--formats {args.formats!r}: {bad[0]!r} is not one of {', '.join(EXTRA_FORMATS)}")
    with also_saved_as(formats):
        return _report(args)


def _report(args: argparse.Namespace) -> int:
    from .plots import make_figures
    from .run_stats import read_summary_with_spread
    from .sweep_slip import is_sweep
    from .tables import print_table

    dirs = [Path(d) for d in args.store]
    if len(dirs) > 1 or args.out is not None or is_sweep(dirs[0]):
        return _report_sweeps(dirs, args.out)
    out = dirs[0]
    summary = read_summary_with_spread(out)  # validated: a hostile or foreign file is a one-line error
    if "slip" in summary:
        figs = make_figures(out)
        print(print_table(summary))
        if isinstance(summary.get("bed"), dict):
            print(bed_line(summary["bed"]))
        for fig in figs:
            print(f"figure: {fig}")
        _print_repose(summary)
    else:
        # a bare run's report is its summary as JSON (stdout stays parseable); the angle of
        # repose goes beside it, to stderr
        print(json.dumps(summary, indent=2))
        _print_repose(summary, sys.stderr)
    return 0


def _report_sweeps(dirs: list[Path], overlay: str | None) -> int:
    """`report SWEEP...`: each sweep's curve written again and printed; several (or
    ``--out``): their overlay figure."""
    from .sweep_slip import is_sweep, sweep_overlay, sweep_report

    for d in dirs:
        if not is_sweep(d):
            raise CliError(f"{d}: not a sweep's directory (no sweep.json): only sweeps are overlaid (--out, several)")
    if len(dirs) > 1 and overlay is None:
        raise CliError("report: several sweeps are overlaid in one figure: --out PNG names it")
    if overlay is not None and not overlay.lower().endswith(".png"):
        raise CliError(f"--out {overlay}: the overlay figure is a .png file")
    for k, d in enumerate(dirs):
        table, figure = sweep_report(d)
        print(("\n" if k else "") + table)
        print(f"curve: {d / 'drawbar_pull_slip.csv'}  figure: {figure}")
    if overlay is not None:
        print(f"overlay: {sweep_overlay(dirs, Path(overlay))}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from .compare import compare_runs

    print(compare_runs(args.a, args.b))
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from .sweep_slip import run_slip_sweep

    try:
        slips = [float(s) for s in args.slips.split(",") if s.strip()]
    except ValueError:
        raise CliError(f"--slips {args.slips!r}: must be comma-separated numbers") from None
    # negative slips brake (wheel.slip's range)
    if not slips or any(not (-1.0 <= s < 1.0) for s in slips):
        raise CliError(f"--slips {args.slips!r}: each slip must be in [-1, 1)")
    comm = getattr(args, "comm", None)
    if comm is None or comm.Get_rank() == 0:
        _sweep_warnings(args, slips[0])
    run_slip_sweep(args.scenario, args.set, slips, Path(args.out), progress=not args.no_progress, comm=comm)
    return 0


def _sweep_warnings(args: argparse.Namespace, slip: float) -> None:
    """What `check` would warn of the sweep's scenario (at its first slip), on stderr."""
    from ..model.scenario import scenario_tables
    from ..model.scenario_check import scenario_from_dict
    from .advice import scenario_warnings

    tables, base = scenario_tables(args.scenario, [*args.set, "wheel.control=slip", f"wheel.slip={slip!r}"])
    for line in scenario_warnings(scenario_from_dict(tables), None, tables, base):
        print(f"ooc-dem: warning: {line}", file=sys.stderr, flush=True)


def cmd_experiment(args: argparse.Namespace) -> int:
    from .experiment import run_experiment

    try:
        slips = [float(s) for s in args.slips.split(",") if s.strip()]
    except ValueError:
        raise CliError(f"--slips {args.slips!r}: must be comma-separated numbers") from None
    doc = run_experiment(
        args.file,
        Path(args.out),
        only=args.only or None,
        slips=slips or None,
        progress=not args.no_progress,
        comm=getattr(args, "comm", None),
        plan_only=args.plan,
    )
    if doc is None:  # a rank other than 0
        return 0
    if args.plan:
        print(json.dumps(doc, indent=2))
        return 0
    print(doc["table"])
    out = Path(args.out)
    print(
        f"report: {out / 'comparison.md'}  {out / 'comparison.csv'}  {out / 'experiment.json'}  figure: {doc['figure']}"
    )
    return 0


def cmd_shear(args: argparse.Namespace) -> int:
    from .shear import ShearOptions, mohr_coulomb_line, run_shear

    try:
        sigmas = tuple(float(s) for s in args.sigma.split(",") if s.strip())
    except ValueError:
        raise CliError(f"--sigma {args.sigma!r}: must be comma-separated numbers (Pa)") from None
    opts = ShearOptions(
        sigmas=sigmas,
        grains=args.grains,
        inertial=args.inertial,
        speed=args.speed or 0.0,
        displacement=args.displacement,
    )
    opts.check()
    sc = _load(args)
    say = None if args.no_progress else (lambda text: print(f"ooc-dem shear: {text}", file=sys.stderr, flush=True))
    out = Path(args.out)
    result = run_shear(sc, opts, out, figures=not args.no_figures, progress=say)
    for t in result["tests"]:
        print(
            f"sigma = {t['sigma']:g} Pa: peak tau = {t['peak']['tau']:.4g} Pa (sigma_n {t['peak']['sigma']:.4g}), "
            f"residual tau = {t['residual']['tau']:.4g} Pa (sigma_n {t['residual']['sigma']:.4g}), "
            f"I = {t['inertial_number']:.2g}"
        )
    print(mohr_coulomb_line("peak", result["peak_fit"]))
    print(mohr_coulomb_line("residual", result["residual_fit"]))
    print(f"report: {out / 'shear.json'}")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from .calibrate import CalibrateOptions, LabSoil, calibration_lines, run_calibrate

    try:
        sigmas = tuple(float(s) for s in args.sigma.split(",") if s.strip())
    except ValueError:
        raise CliError(f"--sigma {args.sigma!r}: must be comma-separated numbers (Pa)") from None
    lab = LabSoil(friction_angle=args.friction_angle, cohesion=args.cohesion, bulk_density=args.bulk_density)
    opts = CalibrateOptions(
        sigmas=sigmas, grains=args.grains, envelope=args.envelope, evaluations=args.evaluations, vary=args.vary
    )
    lab.check()
    opts.check()
    sc = _load(args)
    say = None if args.no_progress else (lambda text: print(f"ooc-dem calibrate: {text}", file=sys.stderr, flush=True))
    out = Path(args.out)
    result = run_calibrate(sc, lab, out, progress=say, opts=opts)
    for line in calibration_lines(result):
        print(line)
    print(f"report: {out / 'calibration.json'}  scenario fragment: {out / 'calibrated.toml'}")
    return 0


def cmd_sinkage(args: argparse.Namespace) -> int:
    from .sinkage import SinkageOptions, run_sinkage

    try:
        widths = tuple(float(s) for s in args.widths.split(",") if s.strip())
    except ValueError:
        raise CliError(f"--widths {args.widths!r}: must be comma-separated numbers (m)") from None
    opts = SinkageOptions(widths=widths, depth=args.depth or 0.0, speed=args.speed)
    opts.check()
    sc = _load(args)
    say = None if args.no_progress else (lambda text: print(f"ooc-dem sinkage: {text}", file=sys.stderr, flush=True))
    out = Path(args.out)
    result = run_sinkage(sc, opts, out, figures=not args.no_figures, progress=say)
    fit = result["bekker"]
    for k in fit["k_per_width"]:
        print(f"b = {k['width']:g} m: k = {k['k']:.4g}")
    print(
        f"Bekker: n = {fit['n']:.3f}, k_c = {fit['k_c']:.4g} N/m^(n+1), k_phi = {fit['k_phi']:.4g} N/m^(n+2) "
        f"(R^2 of log p {fit['r2_log_p']:.3f})"
    )
    print(f"report: {out / 'sinkage.json'}")
    return 0


def cmd_profile(args: argparse.Namespace) -> int:
    from .profiling import PROFILED_MODES, profile

    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    bad = [m for m in modes if m not in PROFILED_MODES]
    if not modes or bad:
        from ..model.schema import did_you_mean

        hint = did_you_mean(bad[0], PROFILED_MODES) if bad else ""
        raise CliError(f"--modes {args.modes!r}: each must be one of {', '.join(PROFILED_MODES)}{hint}")
    _load(args)  # validate the scenario and overrides before spawning anything
    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise CliError(f"--out {out}: directory exists and is not empty")
    from ..engine.memlimit import MemoryLimitError
    from .profiling import OomKilled

    try:
        doc = profile(
            args.scenario,
            modes,
            out,
            overrides=args.set,
            backend=args.backend,
            domains=args.domains,
            block=args.block,
            steps=args.steps,
            memory_limit=args.memory_limit,
        )
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
            print(
                f"{r['mode']}: under the {lim['memory_limit_bytes'] / 1e6:.1f} MB limit (cgroup v"
                f"{lim['cgroup_version']}): peak RSS {lim['peak_rss_bytes'] / 1e6:.1f} MB (anonymous "
                f"{lim['sampled_peak_anon_bytes'] / 1e6:.1f} MB), cgroup peak "
                f"{lim['cgroup_peak_bytes'] / 1e6:.1f} MB, {lim['rss_samples']} RSS samples over "
                f"{lim['wall_s']:.1f} s"
            )
    print(f"report: {out / 'memory.json'}  {out / 'memory.md'}  figure: {out / 'memory.png'}")
    return 0
