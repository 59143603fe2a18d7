"""Drawbar pull - slip curve: slip-controlled runs (prescribed forward speed v = (1 - s) R omega).

Each slip is one monolithic run in OUT/slip_<s>/ from the same settled bed; the
drawbar pull is the steady-window mean net traction. ``sweep_plot(csv, png)`` draws the
curve.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .drawing import pyplot, save_figure
from .run import RunError, RunOptions, Simulation
from .runfiles import read_csv
from ..model.scenario import Scenario, load_scenario

if TYPE_CHECKING:
    from mpi4py import MPI

CSV_NAME = "drawbar_pull_slip.csv"


def steady_window_problem(sc: Scenario) -> str | None:
    """Why the steady window (whose mean net traction is the drawbar pull) holds no step, or None."""
    o, w = sc.output, sc.wheel
    end = min(o.steady_end, w.travel_time)
    if end - o.steady_start < sc.physics.dt:
        return (
            f"output.steady_start = {o.steady_start!r}, output.steady_end = {o.steady_end!r}: the steady "
            f"window [{o.steady_start:g}, {end:g}] s of travel (cut at wheel.travel_time = "
            f"{w.travel_time:g} s) holds no step; the drawbar pull is its mean"
        )
    return None


def _steady(summary: dict[str, Any], key: str) -> Any:
    """A run summary's steady-window mean of ``key``."""
    return summary[key]["steady"]["value"]


def run_slip_sweep(
    scenario: str,
    overrides: list[str],
    slips: list[float],
    out: Path,
    progress: bool = True,
    comm: MPI.Comm | None = None,
) -> list[dict[str, Any]] | None:
    """The curve, one run per slip. With ``comm`` (an MPI communicator: ``mpiexec -n R
    ooc-dem sweep``) the runs fan out over the ranks (run i on rank i mod R, each the same
    monolithic run as in one process, so the same bits); rank 0 gathers the rows and
    writes the curve, the others return None."""
    rank, ranks = (comm.Get_rank(), comm.Get_size()) if comm is not None else (0, 1)
    problem: str | None = None
    if rank == 0 and out.exists() and any(out.iterdir()):
        problem = f"--out {out}: directory exists and is not empty"
    if comm is not None:
        problem = comm.bcast(problem, root=0)
    if problem:
        raise RunError(problem)
    dirs = [out / f"slip_{s:.3f}" for s in slips]
    if len(set(dirs)) != len(dirs):
        raise RunError("--slips: two slips share the directory name slip_<s to 3 decimals>; give distinct slips")
    scs = [load_scenario(scenario, [*overrides, "wheel.control=slip", f"wheel.slip={s!r}"]) for s in slips]
    if not scs[0].wheel.enabled:
        raise RunError(f"scenario {scenario!r} has no wheel (wheel.enabled = false)")
    problem = steady_window_problem(scs[0])
    if problem:
        raise RunError(problem)
    # every run planned (and checked) before the first one starts (on every rank alike)
    sims = [Simulation(sc, d, RunOptions(progress=progress and ranks == 1, figures=False)) for sc, d in zip(scs, dirs)]
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    if comm is not None:
        comm.Barrier()
    mine: dict[int, dict[str, Any]] = {}
    failure: str | None = None
    for i in range(rank, len(slips), ranks):
        try:
            summary = sims[i].run()
        except Exception as e:  # noqa: BLE001 - reported by rank 0 as the sweep's one-line error
            failure = f"slip {slips[i]:g}{f' (rank {rank})' if ranks > 1 else ''}: {e}"
            if comm is None:
                raise
            break
        mine[i] = {
            "slip": slips[i],
            "drawbar_pull": _steady(summary, "net_traction"),
            "gross_traction": _steady(summary, "gross_traction"),
            "sinkage": _steady(summary, "sinkage"),
            "vertical_force": _steady(summary, "vertical_force"),
        }
        r = mine[i]
        print(
            f"slip {r['slip']:.3f}: drawbar pull {r['drawbar_pull']:.3f} N, "
            f"gross traction {r['gross_traction']:.3f} N, sinkage {1e3 * r['sinkage']:.1f} mm"
            + (f" (rank {rank})" if ranks > 1 else ""),
            flush=True,
        )
    parts: list[tuple[dict[int, dict[str, Any]], str | None]] | None = (
        comm.gather((mine, failure), root=0) if comm is not None else [(mine, failure)]
    )
    if rank != 0 or parts is None:  # gather gives the list on rank 0 only
        return None
    failures = [f for _, f in parts if f]
    if failures:
        raise RunError(failures[0])
    got = {i: r for m, _ in parts for i, r in m.items()}
    rows = [got[i] for i in range(len(slips))]
    csv = out / CSV_NAME
    with open(csv, "w") as f:
        f.write("slip,drawbar_pull,gross_traction,sinkage,vertical_force\n")
        for r in rows:
            f.write(
                f"{r['slip']!r},{r['drawbar_pull']!r},{r['gross_traction']!r},{r['sinkage']!r},"
                f"{r['vertical_force']!r}\n"
            )
    sweep_plot(csv, out / "drawbar_pull_slip.png")
    (out / "sweep.json").write_text(
        json.dumps(
            {
                "scenario": scenario,
                "overrides": overrides,
                "window": scs[0].output.steady_start,
                "rows": rows,
                "ranks": ranks,
            },
            indent=2,
        )
    )
    print(f"curve: {csv}  figure: {out / 'drawbar_pull_slip.png'}")
    return rows


def sweep_plot(csv_path: str | os.PathLike[str], png_path: str | os.PathLike[str]) -> Path:
    """Drawbar pull (net traction) and gross traction vs slip, and sinkage vs slip.

    ``csv_path`` has a header with columns ``slip,drawbar_pull`` and optionally
    ``gross_traction`` and ``sinkage`` (m); unit suffixes like ``drawbar_pull [N]``
    are accepted.
    """
    plt = pyplot()
    cols = read_csv(csv_path, ("slip", "drawbar_pull"))
    order = np.argsort(cols["slip"], kind="stable")
    s = cols["slip"][order]
    has_sink = "sinkage" in cols
    fig, axes = plt.subplots(
        2 if has_sink else 1,
        1,
        sharex=True,
        squeeze=False,
        figsize=(7, 7 if has_sink else 4.5),
        constrained_layout=True,
    )
    ax = axes[0, 0]
    ax.plot(s, cols["drawbar_pull"][order], "o-", color="C1", label="drawbar pull (net traction)")
    if "gross_traction" in cols:
        ax.plot(s, cols["gross_traction"][order], "s--", color="C2", label="gross traction (torque / R)")
    ax.axhline(0.0, color="0.5", lw=0.6)
    ax.set_ylabel("force [N]")
    ax.legend(fontsize=8, loc="best")
    ax.grid(True, lw=0.3, alpha=0.6)
    ax.set_title("drawbar pull – slip", fontsize=11)
    if has_sink:
        a2 = axes[1, 0]
        a2.plot(s, 1e3 * cols["sinkage"][order], "^-", color="C4")
        a2.set_ylabel("sinkage [mm]")
        a2.grid(True, lw=0.3, alpha=0.6)
    axes[-1, 0].set_xlabel("slip s [-]")
    png_path = Path(png_path)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, png_path)
