"""Drawbar pull - slip curve: slip-controlled runs (prescribed forward speed v = (1 - s) R omega).

Each slip is one monolithic run in OUT/slip_<s>/ from the same settled bed; the
drawbar pull is the steady-window mean net traction.
"""
from __future__ import annotations

import json
from pathlib import Path

from .engine.run import RunError, RunOptions, Simulation
from .scenario import load_scenario

CSV_NAME = "drawbar_pull_slip.csv"


def steady_window_problem(sc) -> str | None:
    """Why the steady window (whose mean net traction is the drawbar pull) holds no step, or None."""
    o, w = sc.output, sc.wheel
    end = min(o.steady_end, w.travel_time)
    if end - o.steady_start < sc.physics.dt:
        return (f"output.steady_start = {o.steady_start!r}, output.steady_end = {o.steady_end!r}: the steady "
                f"window [{o.steady_start:g}, {end:g}] s of travel (cut at wheel.travel_time = "
                f"{w.travel_time:g} s) holds no step; the drawbar pull is its mean")
    return None


def run_slip_sweep(scenario: str, overrides: list[str], slips: list[float], out: Path,
                   progress: bool = True) -> list[dict]:
    if out.exists() and any(out.iterdir()):
        raise RunError(f"--out {out}: directory exists and is not empty")
    dirs = [out / f"slip_{s:.3f}" for s in slips]
    if len(set(dirs)) != len(dirs):
        raise RunError("--slips: two slips share the directory name slip_<s to 3 decimals>; give distinct slips")
    scs = [load_scenario(scenario, [*overrides, "wheel.control=slip", f"wheel.slip={s!r}"]) for s in slips]
    if not scs[0].wheel.enabled:
        raise RunError(f"scenario {scenario!r} has no wheel (wheel.enabled = false)")
    problem = steady_window_problem(scs[0])
    if problem:
        raise RunError(problem)
    # every run planned (and checked) before the first one starts
    sims = [Simulation(sc, d, RunOptions(progress=progress, figures=False)) for sc, d in zip(scs, dirs)]
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for s, sim in zip(slips, sims):
        summary = sim.run()
        st = lambda k: summary[k]["steady"]["value"]
        rows.append({"slip": s, "drawbar_pull": st("net_traction"), "gross_traction": st("gross_traction"),
                     "sinkage": st("sinkage"), "vertical_force": st("vertical_force")})
        print(f"slip {s:.3f}: drawbar pull {rows[-1]['drawbar_pull']:.3f} N, "
              f"gross traction {rows[-1]['gross_traction']:.3f} N, sinkage {1e3 * rows[-1]['sinkage']:.1f} mm",
              flush=True)
    csv = out / CSV_NAME
    with open(csv, "w") as f:
        f.write("slip,drawbar_pull,gross_traction,sinkage,vertical_force\n")
        for r in rows:
            f.write(f"{r['slip']!r},{r['drawbar_pull']!r},{r['gross_traction']!r},{r['sinkage']!r},"
                    f"{r['vertical_force']!r}\n")
    from .plots import sweep_plot
    sweep_plot(csv, out / "drawbar_pull_slip.png")
    (out / "sweep.json").write_text(json.dumps({"scenario": scenario, "overrides": overrides,
                                                "window": scs[0].output.steady_start, "rows": rows}, indent=2))
    print(f"curve: {csv}  figure: {out / 'drawbar_pull_slip.png'}")
    return rows
