"""The report of `ooc-dem experiment`: each run's steady-window statistics against the measured
points, as OUT/comparison.csv, OUT/comparison.md, OUT/figures/experiment.png and
OUT/experiment.json (docs/reference/experiment.md)."""

from __future__ import annotations

import csv
import io
import json
import math
import textwrap
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .drawing import pyplot, save_figure
from .experiment_file import Experiment, WheelSpec
from .stats import WindowStats, difference, window_stats
from .outputs import write_text_atomic
from .runfiles import read_series, read_summary

if TYPE_CHECKING:
    from .experiment import PlannedRun
    from .experiment_setup import Geometry

# the compared quantities: (key, label, unit, the measured key)
QUANTITIES = (
    ("drawbar_pull", "drawbar pull", "N", "drawbar_pull"),
    ("dp_w", "DP/W", "-", "drawbar_pull"),
    ("torque", "torque", "N m", "torque"),
    ("sinkage", "sinkage", "mm", "sinkage"),
)


def block_period(exp: Experiment, w: WheelSpec) -> float:
    """The statistics' block (s): the wheel's lug passage period 2 pi / (n_lugs omega); a
    smooth wheel's is [dem].block_time, else the first lugged wheel's of the file."""
    if w.n_lugs:
        return 2.0 * math.pi / (w.n_lugs * exp.dem.omega)
    if exp.dem.block_time:
        return exp.dem.block_time
    lugged = next(x for x in exp.wheels if x.n_lugs)
    return 2.0 * math.pi / (lugged.n_lugs * exp.dem.omega)


def run_stats(exp: Experiment, run: PlannedRun) -> dict[str, WindowStats]:
    """The steady-window statistics of one run's series (sinkage in mm, in the file's convention)."""
    cols = read_series(run.out / "series.csv")
    w, d = run.wheel, exp.dem
    t = cols["t_travel"]
    period = block_period(exp, w)

    def stats(values: np.ndarray) -> WindowStats:
        return window_stats(t, values, d.steady_start, d.steady_end, period, d.passages_per_block)

    lug = w.tip_radius - w.radius if exp.conventions.sinkage == "lug_tip" else 0.0
    rolled = cols["omega"]
    with np.errstate(divide="ignore", invalid="ignore"):  # omega = 0 while the wheel settles
        slip_rim = 1.0 - cols["vx"] / (rolled * w.radius)
        slip_tip = 1.0 - cols["vx"] / (rolled * w.tip_radius)
    out = {
        "drawbar_pull": stats(cols["net_traction"]),
        "torque": stats(cols["torque"]),
        "sinkage": stats(cols["sinkage"]).scaled(1e3, 1e3 * lug),
        "vertical_force": stats(cols["vertical_force"]),
        "slip_rim": stats(slip_rim),
        "slip_lug_tip": stats(slip_tip),
    }
    out["dp_w"] = out["drawbar_pull"].scaled(1.0 / w.load)
    out["slip"] = out["slip_lug_tip" if exp.conventions.slip_radius == "lug_tip" else "slip_rim"]
    return out


def _num(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def _rel(ours: float, measured: float | None) -> float | None:
    if measured is None or measured == 0.0 or not math.isfinite(ours):
        return None
    return (ours - measured) / measured


def write_report(
    exp: Experiment,
    out: Path,
    runs: list[PlannedRun],
    status: list[str],
    geo: Geometry,
    calibration: dict[str, Any],
    ranks: int,
) -> dict[str, Any]:
    """Statistics of every run, the comparison files and the figure; returns experiment.json's content."""
    rows: list[dict[str, Any]] = []
    stats_of: dict[tuple[str, float], dict[str, WindowStats]] = {}
    for run, st in zip(runs, status):
        w = run.wheel
        s = run_stats(exp, run)
        stats_of[(w.name, run.slip)] = s
        summary = read_summary(run.out)
        m = exp.measured_of(w.name)
        row: dict[str, Any] = {
            "wheel": w.name,
            "slip": run.slip,
            "engine_slip": run.scenario.wheel.slip,
            "carriage_speed": (1.0 - run.scenario.wheel.slip) * w.radius * exp.dem.omega,
            "slip_achieved": s["slip"].mean,
            "slip_rim": s["slip_rim"].mean,
            "slip_lug_tip": s["slip_lug_tip"].mean,
        }
        for key, _, _, mkey in QUANTITIES:
            measured = m.at(mkey, run.slip) if m is not None else None
            if key == "dp_w" and measured is not None:
                measured /= w.load
            q = s[key]
            row[key] = q.mean
            row[f"{key}_std"] = q.std
            row[f"{key}_ci95"] = q.ci95
            row[f"{key}_measured"] = measured
            row[f"{key}_rel_error"] = _rel(q.mean, measured)
        vf = s["vertical_force"]
        row.update(vertical_force=vf.mean, vertical_force_std=vf.std, vertical_force_ci95=vf.ci95)
        row.update(
            blocks=s["drawbar_pull"].blocks,
            window_start=s["drawbar_pull"].window[0],
            window_end=s["drawbar_pull"].window[1],
            spheres=summary["n_discs"],
            wall_time_s=summary["wall_time_s"],
            steps=summary["steps"],
            status=st,
            run=str(run.out.relative_to(out)),
        )
        rows.append(row)
    _lug_gain(exp, rows, stats_of)
    errors = _mean_errors(rows)
    (out / "comparison.csv").write_text(_csv(rows), encoding="utf-8")
    table = _markdown(exp, rows, errors)
    write_text_atomic(out / "comparison.md", table)
    figure = plot_experiment(exp, rows, out / "figures" / "experiment.png")
    doc = {
        "experiment": exp.name,
        "reference": exp.reference,
        "notes": exp.notes,
        "file": str(exp.source),
        "soil": asdict(exp.soil),
        "dem": {**asdict(exp.dem), "grading": dict(exp.dem.grading)},
        "conventions": asdict(exp.conventions),
        "wheels": [asdict(w) | {"tip_radius": w.tip_radius, "block_s": block_period(exp, w)} for w in exp.wheels],
        "geometry": asdict(geo),
        "calibration": calibration,
        "ranks": ranks,
        "runs": [
            {
                **{k: (_num(v) if isinstance(v, float) else v) for k, v in row.items()},
                "stats": {k: v.as_dict() for k, v in stats_of[(row["wheel"], row["slip"])].items()},
                "scenario_overrides_note": "OUT/<wheel>/slip_<s>/scenario.toml holds the run's whole scenario",
            }
            for row in rows
        ],
        "mean_abs_rel_error": errors,
        "figure": str(figure),
    }
    write_text_atomic(out / "experiment.json", json.dumps(doc, indent=2, default=_json_default))
    doc["table"] = table
    return doc


def _json_default(v: object) -> object:
    if isinstance(v, Path):
        return str(v)
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return str(v)  # anything else the calibration's record holds, as text


def _lug_gain(exp: Experiment, rows: list[dict[str, Any]], stats_of: dict[tuple[str, float], Any]) -> None:
    """Each lugged wheel's drawbar pull minus the file's (first) smooth wheel's at the same slip."""
    smooth = next((w for w in exp.wheels if not w.n_lugs), None)
    ms = exp.measured_of(smooth.name) if smooth is not None else None
    for row in rows:
        row.update(lug_gain=None, lug_gain_ci95=None, lug_gain_measured=None)
        w = next(x for x in exp.wheels if x.name == row["wheel"])
        if smooth is None or not w.n_lugs or (smooth.name, row["slip"]) not in stats_of:
            continue
        gain, ci = difference(
            stats_of[(w.name, row["slip"])]["drawbar_pull"], stats_of[(smooth.name, row["slip"])]["drawbar_pull"]
        )
        a = row["drawbar_pull_measured"]
        b = ms.at("drawbar_pull", row["slip"]) if ms is not None else None
        row.update(
            lug_gain=gain, lug_gain_ci95=ci, lug_gain_measured=(a - b) if a is not None and b is not None else None
        )


def _mean_errors(rows: list[dict[str, Any]]) -> dict[str, dict[str, float | None]]:
    """The mean absolute relative error per wheel and quantity (over the slips measured)."""
    out: dict[str, dict[str, float | None]] = {}
    for row in rows:
        out.setdefault(row["wheel"], {})
    for wheel, errs in out.items():
        for key, *_ in QUANTITIES:
            e = [abs(r[f"{key}_rel_error"]) for r in rows if r["wheel"] == wheel and r[f"{key}_rel_error"] is not None]
            errs[key] = float(np.mean(e)) if e else None
    return out


CSV_COLUMNS = (
    "wheel",
    "slip",
    "engine_slip",
    "carriage_speed",
    "slip_achieved",
    "slip_rim",
    "slip_lug_tip",
    *(f"{k}{suffix}" for k, *_ in QUANTITIES for suffix in ("", "_std", "_ci95", "_measured", "_rel_error")),
    "vertical_force",
    "vertical_force_std",
    "vertical_force_ci95",
    "lug_gain",
    "lug_gain_ci95",
    "lug_gain_measured",
    "blocks",
    "window_start",
    "window_end",
    "spheres",
    "steps",
    "wall_time_s",
    "status",
    "run",
)


def _csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(CSV_COLUMNS)
    for row in rows:
        wr.writerow(
            ["" if (v := row.get(c)) is None or (isinstance(v, float) and math.isnan(v)) else v for c in CSV_COLUMNS]
        )
    return buf.getvalue()


def _pm(v: float | None, ci: float | None, fmt: str) -> str:
    if v is None or not math.isfinite(v):
        return "–"
    return format(v, fmt) + (f" ± {format(ci, fmt)}" if ci is not None and math.isfinite(ci) else "")


def _f(v: float | None, fmt: str) -> str:
    return "–" if v is None or not math.isfinite(v) else format(v, fmt)


def _pct(v: float | None) -> str:
    return "–" if v is None else f"{100.0 * v:+.0f} %"


def _markdown(exp: Experiment, rows: list[dict[str, Any]], errors: dict[str, dict[str, float | None]]) -> str:
    lines = [f"# {exp.name}: simulated against measured", ""]
    if exp.reference:
        lines += [f"Reference: {exp.reference}", ""]
    lines += [
        f"Ours: mean over the steady window cut to whole lug passages ± the 95 % confidence interval "
        f"of block means; slip convention: {exp.conventions.slip_radius} radius, sinkage: lowest "
        f"{exp.conventions.sinkage.replace('_', ' ')} point below the initial surface.",
        "",
    ]
    for wheel in dict.fromkeys(r["wheel"] for r in rows):
        lines += [
            f"## {wheel}",
            "",
            "| slip | DP ours (N) | DP meas. | err | DP/W ours | DP/W meas. | torque ours (N m) | torque meas. | err "
            "| sinkage ours (mm) | sinkage meas. | err |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in (r for r in rows if r["wheel"] == wheel):
            lines.append(
                f"| {r['slip']:.3g} | {_pm(r['drawbar_pull'], r['drawbar_pull_ci95'], '.2f')} "
                f"| {_f(r['drawbar_pull_measured'], '.2f')} | {_pct(r['drawbar_pull_rel_error'])} "
                f"| {_pm(r['dp_w'], r['dp_w_ci95'], '.3f')} | {_f(r['dp_w_measured'], '.3f')} "
                f"| {_pm(r['torque'], r['torque_ci95'], '.2f')} | {_f(r['torque_measured'], '.2f')} "
                f"| {_pct(r['torque_rel_error'])} | {_pm(r['sinkage'], r['sinkage_ci95'], '.1f')} "
                f"| {_f(r['sinkage_measured'], '.1f')} | {_pct(r['sinkage_rel_error'])} |"
            )
        e = errors[wheel]
        lines += [
            "",
            "Mean absolute relative error: "
            + ", ".join(f"{label} {_pct(e[key]).lstrip('+')}" for key, label, *_ in QUANTITIES),
            "",
        ]
    gains = [r for r in rows if r.get("lug_gain") is not None]
    if gains:
        lines += ["## Lug gain (lugged − smooth drawbar pull)", "", "| wheel | slip | ours (N) | measured (N) |"]
        lines.append("|---|---|---|---|")
        for r in gains:
            lines.append(
                f"| {r['wheel']} | {r['slip']:.3g} | {_pm(r['lug_gain'], r['lug_gain_ci95'], '.2f')} "
                f"| {_f(r['lug_gain_measured'], '.2f')} |"
            )
        lines.append("")
    return "\n".join(lines)


def plot_experiment(exp: Experiment, rows: list[dict[str, Any]], png: Path) -> Path:
    """Drawbar pull, DP/W, torque and sinkage against slip: each wheel's runs with their 95 %
    intervals as error bars, the measured points as open markers."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5), constrained_layout=True)
    for ax, (key, label, unit, mkey) in zip(axes.ravel(), QUANTITIES):
        for k, wheel in enumerate(dict.fromkeys(r["wheel"] for r in rows)):
            rs = sorted((r for r in rows if r["wheel"] == wheel), key=lambda r: r["slip"])
            s = np.array([r["slip"] for r in rs])
            y = np.array([r[key] for r in rs], dtype=float)
            ci = np.array([np.nan if r[f"{key}_ci95"] is None else r[f"{key}_ci95"] for r in rs], dtype=float)
            colour = f"C{k}"
            ax.errorbar(s, y, yerr=np.nan_to_num(ci), fmt="o-", color=colour, capsize=3, label=f"{wheel} (ooc-dem)")
            m = exp.measured_of(wheel)
            values = getattr(m, mkey) if m is not None else None
            if m is not None and values is not None:  # every measured point, run or not
                scale = 1.0 / next(w.load for w in exp.wheels if w.name == wheel) if key == "dp_w" else 1.0
                meas = sorted((si, vi * scale) for si, vi in zip(m.slip, values))
                ms, mv = zip(*meas)
                ax.plot(ms, mv, "s--", mfc="none", color=colour, lw=0.8, label=f"{wheel} (measured)")
        ax.set_xlabel(f"slip s ({exp.conventions.slip_radius.replace('_', ' ')} radius)")
        ax.set_ylabel(f"{label} [{unit}]")
        ax.grid(True, lw=0.3, alpha=0.6)
        ax.axhline(0.0, color="0.5", lw=0.6)
    axes[0, 0].legend(fontsize=8, loc="best")
    # the reference wrapped, not cut: a title must say whose data these are
    title = f"{exp.name}" + (f" — {exp.reference}" if exp.reference else "")
    fig.suptitle("\n".join(textwrap.wrap(title, 110)[:3]), fontsize=9)
    png.parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, png)
