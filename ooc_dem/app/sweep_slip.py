"""Drawbar pull - slip curve: slip-controlled runs (prescribed forward speed v = (1 - s) R omega).

Each slip is one monolithic run in OUT/slip_<s>/ from the same settled bed; the drawbar
pull is the steady-window mean net traction, with its spread (``run_stats``: std and the
95 % confidence half-width from one block per lug passage). OUT/sweep.json names the
scenario, its overrides and the slips: a sweep run again with more slips (the same scenario
and overrides) reuses its finished runs, resumes stopped ones and adds the new ones, then
writes the curve (drawbar_pull_slip.csv) and its figure again. ``sweep_report`` re-plots a
sweep from its runs, ``sweep_overlay`` draws several in one figure.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .drawing import pyplot, save_figure
from .plan import RunError, RunOptions, plan_run
from .runfiles import RunFileError, one_line, read_csv, read_run_scenario, run_file
from ..model.scenario import Scenario, load_scenario

if TYPE_CHECKING:
    from mpi4py import MPI

CSV_NAME = "drawbar_pull_slip.csv"
FIGURE_NAME = "drawbar_pull_slip.png"
SWEEP_FILE = "sweep.json"
MAX_SWEEP_BYTES = 1 << 20
# the curve's quantities with a spread: (CSV column, summary key, label, unit)
CURVE_QUANTITIES = (
    ("drawbar_pull", "net_traction", "drawbar pull", "N"),
    ("gross_traction", "gross_traction", "gross traction", "N"),
    ("torque", "torque", "torque", "N m"),
    ("sinkage", "sinkage", "sinkage", "m"),
    ("dp_w", "dp_w", "DP/W", "-"),
)
# the CSV's columns: the first five as sweeps have always written them, then the spread
CSV_COLUMNS = (
    "slip",
    "drawbar_pull",
    "gross_traction",
    "sinkage",
    "vertical_force",
    "drawbar_pull_std",
    "drawbar_pull_ci95",
    "gross_traction_std",
    "gross_traction_ci95",
    "torque",
    "torque_std",
    "torque_ci95",
    "sinkage_std",
    "sinkage_ci95",
    "dp_w",
    "dp_w_std",
    "dp_w_ci95",
    "blocks",
)


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


def slip_dir(out: Path, slip: float) -> Path:
    return out / f"slip_{slip:.3f}"


def slip_scenario(scenario: str, overrides: list[str], slip: float) -> Scenario:
    return load_scenario(scenario, [*overrides, "wheel.control=slip", f"wheel.slip={slip!r}"])


# ------------------------------------------------------------------------- sweep.json


def read_sweep(out: Path) -> dict[str, Any]:
    """OUT/sweep.json, checked: {"scenario": str, "overrides": [str], "slips": [number],
    "raw": the file's object} (a sweep written before "slips" lists them in its "rows")."""
    f = run_file(out, SWEEP_FILE, required=True)
    if f.stat().st_size > MAX_SWEEP_BYTES:
        raise RunFileError(f"{f}: too large for a sweep's file")
    try:
        doc = json.loads(f.read_bytes())
    except (ValueError, RecursionError) as e:
        raise RunFileError(f"{f}: not valid JSON ({one_line(e)})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("scenario"), str):
        raise RunFileError(f"{f}: not a sweep written by ooc-dem (no 'scenario')")
    overrides = doc.get("overrides", [])
    if not isinstance(overrides, list) or not all(isinstance(x, str) for x in overrides):
        raise RunFileError(f"{f}: 'overrides' must be a list of strings")
    slips: Any = doc.get("slips")
    rows = doc.get("rows", [])
    if slips is None and isinstance(rows, list) and all(isinstance(r, dict) for r in rows):
        slips = [r.get("slip") for r in rows]
    ok = isinstance(slips, list) and all(
        isinstance(s, (int, float)) and not isinstance(s, bool) and -1.0 <= s < 1.0 for s in slips
    )
    if not ok:
        raise RunFileError(f"{f}: 'slips' must be a list of slips in [-1, 1)")
    return {"scenario": doc["scenario"], "overrides": list(overrides), "slips": [float(s) for s in slips], "raw": doc}


def is_sweep(out: str | os.PathLike[str]) -> bool:
    """Whether ``out`` is a sweep's directory (it holds sweep.json)."""
    return Path(out).is_dir() and os.path.lexists(Path(out) / SWEEP_FILE)


def _write_sweep(out: Path, scenario: str, overrides: list[str], slips: list[float], **extra: Any) -> None:
    from .outputs import write_text_atomic

    doc = {"scenario": scenario, "overrides": overrides, "slips": slips, **extra}
    write_text_atomic(out / SWEEP_FILE, json.dumps(doc, indent=2))


def _same_scenario(a: Scenario, b: Scenario) -> bool:
    """The same run: the physics (the scenario's hash) and the outputs (the steady window,
    the series' rows), which the hash leaves out."""
    return a.hash() == b.hash() and a.output == b.output


def _another_scenario(out: Path, sweep: dict[str, Any], where: str) -> RunError:
    given = " ".join(f"--set {o}" for o in sweep["overrides"])
    return RunError(
        f"--out {out}: a sweep of {sweep['scenario']!r}{' ' + given if given else ''}, {where} another scenario "
        f"than this one; extend a sweep with its own scenario and --set, or use a new --out"
    )


def _check_extension(out: Path, sweep: dict[str, Any], slips: list[float], scs: list[Scenario]) -> None:
    """An existing sweep is extended only by its own scenario: the one its sweep.json names
    (when it still loads) and the one every slip directory holds."""
    from ..errors import OocDemError

    try:
        theirs = slip_scenario(sweep["scenario"], sweep["overrides"], slips[0])
    except OocDemError:  # a scenario file moved or changed beyond loading: the runs decide
        theirs = None
    if theirs is not None and not _same_scenario(theirs, scs[0]):
        raise _another_scenario(out, sweep, "which is")
    for s, sc in zip(slips, scs):
        stored = read_run_scenario(slip_dir(out, s)) if slip_dir(out, s).exists() else None
        if stored is not None and not _same_scenario(stored, sc):
            raise _another_scenario(out, sweep, f"whose {slip_dir(out, s).name} is")


# ------------------------------------------------------------------------------ runs


def run_slip_sweep(
    scenario: str,
    overrides: list[str],
    slips: list[float],
    out: Path,
    progress: bool = True,
    comm: MPI.Comm | None = None,
) -> list[dict[str, Any]] | None:
    """The curve, one run per slip; an existing sweep in ``out`` (of the same scenario and
    overrides) is extended by ``slips``. With ``comm`` (an MPI communicator: ``mpiexec -n R
    ooc-dem sweep``) the runs fan out over the ranks (run i on rank i mod R, each the same
    monolithic run as in one process, so the same bits); rank 0 writes the curve from the
    runs' summaries (a file system the ranks share), the others return None."""
    rank, ranks = (comm.Get_rank(), comm.Get_size()) if comm is not None else (0, 1)
    problem: str | None = None
    existing: dict[str, Any] | None = None
    if rank == 0 and out.exists() and any(out.iterdir()):
        if is_sweep(out):
            try:
                existing = read_sweep(out)
            except RunFileError as e:
                problem = str(e)
        else:
            problem = f"--out {out}: directory exists and is not empty (and holds no sweep to extend)"
    if comm is not None:
        problem, existing = comm.bcast((problem, existing), root=0)
    if problem:
        raise RunError(problem)
    names = [slip_dir(out, s).name for s in slips]
    if len(set(names)) != len(names):
        raise RunError("--slips: two slips share the directory name slip_<s to 3 decimals>; give distinct slips")
    # the sweep's slips: the existing ones, then the new ones (a slip given again is reused)
    known = {slip_dir(out, s).name: s for s in (existing["slips"] if existing else [])}
    every = list(known.values()) + [s for s in slips if slip_dir(out, s).name not in known]
    scs = [slip_scenario(scenario, overrides, s) for s in every]
    if not scs[0].wheel.enabled:
        raise RunError(f"scenario {scenario!r} has no wheel (wheel.enabled = false)")
    problem = steady_window_problem(scs[0])
    if problem:
        raise RunError(problem)
    opts = RunOptions(progress=progress and ranks == 1, figures=False)
    sweep = existing or {"scenario": scenario, "overrides": overrides}
    # every run planned (and checked), and every existing run checked to be of this
    # scenario, before the first one starts (on every rank alike)
    for sc in scs:
        plan_run(sc, opts)
    if existing:
        _check_extension(out, existing, every, scs)
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        # written first: a sweep stopped part-way is continued by running it again
        _write_sweep(out, sweep["scenario"], sweep["overrides"], every)
    if comm is not None:
        comm.Barrier()
    from .run import run_to_end

    failure: str | None = None
    for i in range(rank, len(every), ranks):
        try:
            status = run_to_end(scs[i], slip_dir(out, every[i]), opts)
            r = sweep_row(every[i], slip_dir(out, every[i]))
        except Exception as e:  # noqa: BLE001 - reported by rank 0 as the sweep's one-line error
            failure = f"slip {every[i]:g}{f' (rank {rank})' if ranks > 1 else ''}: {e}"
            if comm is None:
                raise
            break
        print(
            f"slip {r['slip']:.3f} ({status}): drawbar pull {_pm(r['drawbar_pull'], r['drawbar_pull_ci95'])} N, "
            f"gross traction {_pm(r['gross_traction'], r['gross_traction_ci95'])} N, "
            f"sinkage {_pm(r['sinkage'], r['sinkage_ci95'], 1e3, 1)} mm" + (f" (rank {rank})" if ranks > 1 else ""),
            flush=True,
        )
    failures: list[str | None] | None = comm.gather(failure, root=0) if comm is not None else [failure]
    if rank != 0 or failures is None:  # gather gives the list on rank 0 only
        return None
    first = next((f for f in failures if f), None)
    if first:
        raise RunError(first)
    rows = write_curve(out, every, window=scs[0].output.steady_start, ranks=ranks)
    print(f"curve: {out / CSV_NAME}  figure: {out / FIGURE_NAME}")
    return rows


def _pm(v: float | None, ci: float | None, scale: float = 1.0, digits: int = 3) -> str:
    """``v ± ci`` (scaled), or ``v`` without an interval, or a dash."""
    if v is None or not math.isfinite(v):
        return "—"
    text = f"{v * scale:.{digits}f}"
    return text + (f" ± {ci * scale:.{digits}f}" if ci is not None and math.isfinite(ci) else "")


def sweep_row(slip: float, d: Path) -> dict[str, Any]:
    """One slip's row of the curve from its run's summary (its spread computed from the
    run's series when the summary predates it)."""
    from .run_stats import read_summary_with_spread
    from .runfiles import summary_field, summary_value

    summary = read_summary_with_spread(d)
    row: dict[str, Any] = {"slip": slip, "vertical_force": summary_value(summary, "vertical_force", "steady")}
    for col, key, _, _ in CURVE_QUANTITIES:
        row[col] = summary_value(summary, key, "steady")
        row[f"{col}_std"] = summary_field(summary, key, "steady", "std")
        row[f"{col}_ci95"] = summary_field(summary, key, "steady", "ci95")
    row["blocks"] = summary_field(summary, "net_traction", "steady", "blocks")
    row["passages"] = summary_field(summary, "net_traction", "steady", "passages")
    row["flag"] = summary_field(summary, "net_traction", "steady", "flag")
    row["run"] = d.name
    return row


def write_curve(out: Path, slips: list[float], **extra: Any) -> list[dict[str, Any]]:
    """drawbar_pull_slip.csv, its figure and sweep.json (its other keys kept, ``extra``
    added) from the finished runs of ``slips``, in slip order; returns the rows."""
    from .outputs import write_text_atomic
    from .runfiles import read_summary

    done = [s for s in sorted(slips) if read_summary(slip_dir(out, s), complete=False) is not None]
    rows = [sweep_row(s, slip_dir(out, s)) for s in done]

    def cell(v: Any) -> str:
        return "nan" if v is None else str(v) if isinstance(v, int) else repr(float(v))

    lines = [",".join(CSV_COLUMNS)] + [",".join(cell(r[c]) for c in CSV_COLUMNS) for r in rows]
    write_text_atomic(out / CSV_NAME, "\n".join(lines) + "\n")
    sweep_plot(out / CSV_NAME, out / FIGURE_NAME)
    doc = read_sweep(out)
    kept = {k: v for k, v in doc["raw"].items() if k not in ("scenario", "overrides", "slips", "rows")}
    _write_sweep(out, doc["scenario"], doc["overrides"], slips, **{**kept, **extra, "rows": rows})
    return rows


# ---------------------------------------------------------------------------- report


def sweep_table(out: Path, rows: list[dict[str, Any]], doc: dict[str, Any]) -> str:
    """The curve as a text table: each quantity's steady mean ± its 95 % half-width."""
    given = " ".join(f"--set {o}" for o in doc["overrides"])
    head = ["slip", "drawbar pull (N)", "gross traction (N)", "torque (N m)", "sinkage (mm)", "DP/W (-)", "blocks"]
    body = []
    for r in rows:
        body.append(
            [
                f"{r['slip']:.3f}",
                _pm(r["drawbar_pull"], r["drawbar_pull_ci95"]),
                _pm(r["gross_traction"], r["gross_traction_ci95"]),
                _pm(r["torque"], r["torque_ci95"], 1.0, 4),
                _pm(r["sinkage"], r["sinkage_ci95"], 1e3, 1),
                _pm(r["dp_w"], r["dp_w_ci95"], 1.0, 4),
                ("—" if r["blocks"] is None else str(r["blocks"])) + (" *" if r.get("flag") else ""),
            ]
        )
    widths = [max(len(x[k]) for x in body + [head]) for k in range(len(head))]

    def line(cells: list[str]) -> str:
        return "  ".join(c.rjust(w) for c, w in zip(cells, widths))

    text = [
        f"Drawbar pull – slip — {doc['scenario']}{' ' + given if given else ''} ({out})",
        line(head),
        "  ".join("-" * w for w in widths),
        *(line(b) for b in body),
        "",
        "steady-window means ± 95 % confidence half-width (Student t over one block per lug passage; "
        "docs/reference/statistics.md)",
    ]
    if any(r.get("flag") for r in rows):
        flags = sorted({r["flag"] for r in rows if r.get("flag")})
        text.append(f"* {'; '.join(flags)}: the interval is missing or unreliable; travel longer")
    missing = [s for s in doc["slips"] if all(abs(s - r["slip"]) > 5e-4 for r in rows)]
    if missing:
        text.append(f"not finished (run the sweep again to complete it): {', '.join(f'{s:g}' for s in missing)}")
    return "\n".join(text)


def sweep_report(out: Path) -> tuple[str, Path]:
    """`ooc-dem report SWEEP`: the curve written again from the runs (CSV, figure,
    sweep.json); returns the table and the figure's path."""
    doc = read_sweep(out)
    rows = write_curve(out, doc["slips"])
    return sweep_table(out, rows, doc), out / FIGURE_NAME


def sweep_label(out: Path, doc: dict[str, Any]) -> str:
    given = " ".join(doc["overrides"])
    return f"{out.name}: {doc['scenario']}" + (f" ({given})" if given and len(given) <= 60 else "")


def sweep_overlay(outs: list[Path], png_path: Path) -> Path:
    """Several sweeps' drawbar pull, DP/W and sinkage against slip in one figure, each with
    its 95 % error bars (from each sweep's CSV, written again by ``sweep_report``)."""
    plt = pyplot()
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(7, 9), constrained_layout=True)
    for k, out in enumerate(outs):
        cols = read_csv(out / CSV_NAME, ("slip", "drawbar_pull"))
        label = sweep_label(out, read_sweep(out))
        order = np.argsort(cols["slip"], kind="stable")
        s = cols["slip"][order]
        for ax, col, scale in ((axes[0], "drawbar_pull", 1.0), (axes[1], "dp_w", 1.0), (axes[2], "sinkage", 1e3)):
            if col not in cols:
                continue
            ax.errorbar(
                s,
                scale * cols[col][order],
                yerr=_yerr(cols, col, order, scale),
                fmt="o-",
                color=f"C{k}",
                capsize=3,
                label=label,
            )
    for ax, name in zip(axes, ("drawbar pull [N]", "DP/W [-]", "sinkage [mm]")):
        ax.set_ylabel(name)
        ax.grid(True, lw=0.3, alpha=0.6)
    axes[0].axhline(0.0, color="0.5", lw=0.6)
    axes[1].axhline(0.0, color="0.5", lw=0.6)
    axes[0].legend(fontsize=7, loc="best")
    axes[0].set_title("drawbar pull – slip (error bars: 95 % confidence of the steady mean)", fontsize=10)
    axes[-1].set_xlabel("slip s [-]")
    png_path.parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, png_path)


def _yerr(cols: dict[str, np.ndarray], col: str, order: np.ndarray, scale: float) -> np.ndarray | None:
    """The error bars of ``col`` (its ``_ci95`` column; none where it is nan), or None."""
    ci = cols.get(f"{col}_ci95")
    if ci is None:
        return None
    return np.where(np.isfinite(ci[order]), scale * ci[order], 0.0)


def sweep_plot(csv_path: str | os.PathLike[str], png_path: str | os.PathLike[str]) -> Path:
    """Drawbar pull (net traction) and gross traction vs slip, and sinkage vs slip, with
    the 95 % error bars of the steady means when the CSV has them.

    ``csv_path`` has a header with columns ``slip,drawbar_pull`` and optionally
    ``gross_traction`` and ``sinkage`` (m), and each one's ``_ci95``; unit suffixes like
    ``drawbar_pull [N]`` are accepted.
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
    bars = "drawbar_pull_ci95" in cols
    ax.errorbar(
        s,
        cols["drawbar_pull"][order],
        yerr=_yerr(cols, "drawbar_pull", order, 1.0),
        fmt="o-",
        color="C1",
        capsize=3,
        label="drawbar pull (net traction)",
    )
    if "gross_traction" in cols:
        ax.errorbar(
            s,
            cols["gross_traction"][order],
            yerr=_yerr(cols, "gross_traction", order, 1.0),
            fmt="s--",
            color="C2",
            capsize=3,
            label="gross traction (torque / R)",
        )
    ax.axhline(0.0, color="0.5", lw=0.6)
    ax.set_ylabel("force [N]")
    ax.legend(fontsize=8, loc="best")
    ax.grid(True, lw=0.3, alpha=0.6)
    ax.set_title(
        "drawbar pull – slip" + (" (error bars: 95 % confidence of the steady mean)" if bars else ""), fontsize=11
    )
    if has_sink:
        a2 = axes[1, 0]
        a2.errorbar(
            s, 1e3 * cols["sinkage"][order], yerr=_yerr(cols, "sinkage", order, 1e3), fmt="^-", color="C4", capsize=3
        )
        a2.set_ylabel("sinkage [mm]")
        a2.grid(True, lw=0.3, alpha=0.6)
    axes[-1, 0].set_xlabel("slip s [-]")
    png_path = Path(png_path)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, png_path)
