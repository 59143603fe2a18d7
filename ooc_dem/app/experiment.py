"""`ooc-dem experiment FILE --out DIR`: a single-wheel testbed experiment reproduced end to
end (docs/reference/experiment.md).

The soil is calibrated from the file's lab properties only (``calibrate.run_calibrate``;
never from the wheel data), or the calibration's overrides are given in the file; then one
scenario per wheel (the base scenario, the DEM choices, the calibrated overrides, the
wheel), its bed settled once (the bed cache), and for each wheel and slip a slip-controlled
run in OUT/<wheel>/slip_<s>/ as `ooc-dem sweep` makes them: a finished run is reused, a
stopped one resumed from its last committed epoch, any other started. Under mpiexec the
runs fan out over the ranks (run i on rank i mod R). The statistics
(``stats``) and the report (``experiment_report``) follow.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any


from ..errors import OocDemError
from ..model.scenario import Scenario
from .experiment_file import Experiment, ExperimentError, WheelSpec
from .experiment_setup import Geometry, base_scenario, engine_slip, geometry, run_dir_name, run_scenario
from .plan import RunError, RunOptions, plan_run, total_steps

if TYPE_CHECKING:
    from mpi4py import MPI

CALIBRATION_DIR = "calibration"


# ------------------------------------------------------------------------ calibration


def calibrated_overrides(exp: Experiment, out: Path, say: Callable[[str], None]) -> tuple[list[str], dict[str, Any]]:
    """The calibration's overrides: given in the file, or the finished calibration in
    OUT/calibration, or a calibration run now (from the lab properties only)."""
    if exp.dem.calibrated is not None:
        src = exp.dem.calibrated_from or str(exp.source)
        return list(exp.dem.calibrated), {"given": True, "source": src, "overrides": list(exp.dem.calibrated)}
    from .calibrate import CalibrateOptions, LabSoil, read_calibration, run_calibrate, soil_key

    where = out / CALIBRATION_DIR
    base = base_scenario(exp)
    doc = read_calibration(where) if where.is_dir() else None
    if doc is None:
        say(f"calibrating the soil from its lab properties into {where} (tens of minutes)")
        lab = LabSoil(
            friction_angle=exp.soil.friction_angle, cohesion=exp.soil.cohesion, bulk_density=exp.soil.bulk_density
        )
        k = exp.calibration
        opts = CalibrateOptions(
            sigmas=k.sigmas, grains=k.grains, envelope=k.envelope, evaluations=k.evaluations, vary=k.vary
        )
        doc = run_calibrate(base, lab, where, say, opts)
    elif doc.get("soil_key") != soil_key(base):
        raise ExperimentError(
            f"{where}: a calibration of another soil (the file's [dem] or [soil] changed); use a new --out, "
            f"or delete {where}"
        )
    else:
        say(f"calibration: reusing {where}")
    ov = doc.get("overrides")
    if not isinstance(ov, list) or not all(isinstance(x, str) for x in ov):
        raise ExperimentError(f"{where}: the calibration gives no overrides")
    return list(ov), {"given": False, "source": str(where), **doc}


# ------------------------------------------------------------------------------- runs


@dataclass(frozen=True)
class PlannedRun:
    wheel: WheelSpec
    slip: float
    scenario: Scenario
    out: Path


def _same_run(sc: Scenario, d: Path) -> None:
    """A run directory must hold this run (a changed experiment file needs a new --out)."""
    from .runfiles import read_run_scenario

    stored = read_run_scenario(d)
    # the physics (the hash leaves out [output]) and the series' rows; the steady window is
    # the statistics', read from the file each time
    if stored is not None and (
        stored.hash() != sc.hash() or stored.output.series_interval != sc.output.series_interval
    ):
        raise RunError(
            f"{d}: holds a run of another scenario (the experiment file or the calibration changed); "
            f"use a new --out, or delete {d}"
        )


def finished_summary(run: PlannedRun) -> dict[str, Any] | None:
    """The run's summary if it ran to its planned end, else None."""
    from .run import finished_summary as finished

    return finished(run.out, run.scenario, RunOptions())


def run_options(exp: Experiment, sc: Scenario, progress: bool) -> RunOptions:
    """A run's options: monolithic, no figures, an epoch every [dem].checkpoint_interval."""
    every = max(1, round(exp.dem.checkpoint_interval / sc.physics.dt))
    return RunOptions(progress=progress, figures=False, checkpoint_every=every)


def execute(exp: Experiment, run: PlannedRun, progress: bool) -> str:
    """Run ``run`` to its end: reuse it when finished, resume it when stopped, start it
    otherwise. Returns what was done: "reused", "resumed" or "ran"."""
    from .run import run_to_end

    if run.out.exists():
        _same_run(run.scenario, run.out)
    return run_to_end(run.scenario, run.out, run_options(exp, run.scenario, progress))


# --------------------------------------------------------------------------- pipeline


def _wait_for_root(comm: MPI.Comm | None, work: Callable[[], Any]) -> Any:
    """``work()`` on rank 0 while the other ranks sleep (not spin: a calibration takes
    minutes), then its result (or its one-line error) on every rank."""
    if comm is None:
        return work()
    result: Any = None
    error: str | None = None
    if comm.Get_rank() == 0:
        try:
            result = work()
        except OocDemError as e:
            error = str(e)
    req = comm.Ibarrier()
    while not req.Test():
        time.sleep(0.2)
    result, error = comm.bcast((result, error), root=0)
    if error is not None:
        raise RunError(error)
    return result


def run_experiment(
    path: str | Path,
    out: Path,
    only: list[str] | None = None,
    slips: list[float] | None = None,
    progress: bool = True,
    comm: MPI.Comm | None = None,
    plan_only: bool = False,
) -> dict[str, Any] | None:
    """The experiment end to end (see the module's docstring). Returns experiment.json's
    content on rank 0 (None on the other ranks); ``plan_only``: the plan, nothing run."""
    from .experiment_file import load_experiment

    rank, ranks = (comm.Get_rank(), comm.Get_size()) if comm is not None else (0, 1)

    def say(text: str) -> None:
        if progress and rank == 0:
            print(f"ooc-dem experiment: {text}", file=sys.stderr, flush=True)

    exp = load_experiment(path)
    wheels = list(exp.wheels)
    if only:
        unknown = [w for w in only if w not in {x.name for x in wheels}]
        if unknown:
            raise ExperimentError(f"--only {unknown[0]!r}: no such wheel (wheels: {', '.join(x.name for x in wheels)})")
        wheels = [w for w in wheels if w.name in only]
    base = base_scenario(exp)
    geo = geometry(exp, base)
    # every run's scenario planned and checked (uncalibrated) before anything runs
    pairs = []
    for w in wheels:
        chosen = exp.slips_of(w.name) if not slips else [s for s in slips if s in exp.slips_of(w.name)]
        if slips and not chosen:
            raise ExperimentError(f"--slips: none of them is a slip of wheel {w.name!r} ({exp.slips_of(w.name)})")
        pairs += [(w, s) for s in chosen]
    for w, s in pairs:
        sc = run_scenario(exp, geo, [], w, s)
        try:
            plan_run(sc, run_options(exp, sc, False))
        except OocDemError as e:
            raise ExperimentError(f"{exp.source}: wheel {w.name!r} at slip {s:g}: {e}") from None
        if not -1.0 <= sc.wheel.slip < 1.0:
            raise ExperimentError(f"{exp.source}: wheel {w.name!r} at slip {s:g}: engine slip {sc.wheel.slip:g}")
    if plan_only:
        return plan_summary(exp, base, geo, pairs) if rank == 0 else None
    problem: str | None = None
    if rank == 0 and out.is_dir() and any(out.iterdir()) and not (out / "experiment.toml").is_file():
        problem = f"--out {out}: directory exists, is not empty and holds no experiment (use a new directory)"
    if comm is not None:
        problem = comm.bcast(problem, root=0)
    if problem:
        raise RunError(problem)
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        (out / "experiment.toml").write_bytes(Path(path).read_bytes())
    calibrated, calibration = _wait_for_root(comm, lambda: calibrated_overrides(exp, out, say))
    runs = [
        PlannedRun(w, s, run_scenario(exp, geo, calibrated, w, s), out / w.name / run_dir_name(s)) for w, s in pairs
    ]
    for r in runs:
        if r.out.exists():
            _same_run(r.scenario, r.out)

    def settle() -> None:
        from .bed import settled_bed
        from .progress import settling_progress

        todo = {r.scenario.bed_hash(): r.scenario for r in runs if finished_summary(r) is None}
        for sc in todo.values():
            say(f"settling the bed ({sc.soil.n} spheres, cached by its hash)")
            settled_bed(sc, progress=settling_progress(sc) if progress else None)

    _wait_for_root(comm, settle)
    failure: str | None = None
    done: dict[int, str] = {}
    for i in range(rank, len(runs), ranks):
        r = runs[i]
        try:
            done[i] = execute(exp, r, progress and ranks == 1)
        except Exception as e:  # noqa: BLE001 - reported by rank 0 as the experiment's one-line error
            failure = f"wheel {r.wheel.name}, slip {r.slip:g}{f' (rank {rank})' if ranks > 1 else ''}: {e}"
            if comm is None:
                raise
            break
        print(f"{r.wheel.name} slip {r.slip:.3f}: {done[i]} ({r.out})" + (f" (rank {rank})" if ranks > 1 else ""))
    parts = comm.gather((done, failure), root=0) if comm is not None else [(done, failure)]
    if rank != 0 or parts is None:
        return None
    failures = [f for _, f in parts if f]
    if failures:
        raise RunError(failures[0])
    status = {i: s for m, _ in parts for i, s in m.items()}
    from .experiment_report import write_report

    return write_report(exp, out, runs, [status[i] for i in range(len(runs))], geo, calibration, ranks)


def plan_summary(
    exp: Experiment, base: Scenario, geo: Geometry, pairs: list[tuple[WheelSpec, float]]
) -> dict[str, Any]:
    """What `--plan` prints: the model and its runs, from the uncalibrated scenario."""
    steps = total_steps(base, RunOptions())
    return {
        "experiment": exp.name,
        "base": exp.dem.base,
        "spheres": geo.n,
        "bin_m": [geo.length, geo.width, geo.height],
        "bed_depth_m": exp.dem.bed_depth,
        "tiles": {"tile": geo.tile, "across": geo.tiles_across},
        "solid_fraction": geo.solid_fraction,
        "x0_m": geo.x0,
        "longest_travel_m": geo.travel,
        "dt_s": base.physics.dt,
        "steps_per_run": steps,
        "runs": [
            {
                "wheel": w.name,
                "slip": s,
                "engine_slip": engine_slip(exp, w, s),
                "carriage_speed_m_s": (1.0 - engine_slip(exp, w, s)) * w.radius * exp.dem.omega,
            }
            for w, s in pairs
        ],
        "calibration": "given in the file"
        if exp.dem.calibrated is not None
        else f"run from the lab properties (or reused from OUT/{CALIBRATION_DIR})",
    }
