"""A run's outputs in its directory: summary.json, series.csv and the figures.

Each file is written under a temporary name and renamed (``atomic.write_replacing``), so
a kill leaves each either absent or complete; ``complete_outputs`` (run by resume after
the last commit) writes whichever a kill left unwritten.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..storage.atomic import write_replacing


def run_summary(
    *,
    scenario: str,
    scenario_hash: str,
    mode: str,
    backend: str,
    steps: int,
    dt: float,
    wall_time: float,
    n_discs: int,
    engine: dict[str, Any],
    results: dict[str, Any],
    state_hash: str,
) -> dict[str, Any]:
    """summary.json's content, keys in the order the file shows them: the run, the
    engine's info, the results (wheel metrics, the repose heap) and the final state's hash."""
    summary: dict[str, Any] = {
        "scenario": scenario,
        "scenario_hash": scenario_hash,
        "mode": mode,
        "backend": backend,
        "steps": steps,
        "simulated_time_s": steps * dt,
        "wall_time_s": round(wall_time, 3),
        "n_discs": n_discs,
        "engine": engine,
    }
    summary.update(results)
    summary["state_hash"] = state_hash
    return summary


def write_outputs(out: Path, summary: dict[str, Any], series: NDArray[np.float64] | None, figures: bool) -> None:
    """series.csv (if there is a series), summary.json, then the figures (if asked)."""
    out = Path(out)
    if series is not None:
        write_series_csv(out / "series.csv", series)
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=2))
    if figures:
        from .plots import make_figures

        make_figures(out)


def complete_outputs(
    out: Path,
    step: int,
    write_all: Callable[[], object],
    *,
    series: bool,
    figures: Sequence[str] = (),
    summary_figures: Sequence[str] = (),
) -> list[str]:
    """After the last commit at ``step``: write whichever outputs a kill left unwritten
    (``write_all`` writes them all); return their names. ``series``: the run has a
    series.csv; ``figures``: the files ``make_figures`` writes for the run, relative to
    ``out`` (``plots.figure_files``; empty: none); ``summary_figures``: figures written
    with the summary, before it (a missing one means writing them all again)."""
    from .plots import make_figures

    out = Path(out)
    try:
        summary = json.loads((out / "summary.json").read_text())
        complete = isinstance(summary, dict) and summary.get("steps") == step
    except (OSError, ValueError):
        complete = False
    if not complete or not all((out / "figures" / f).is_file() for f in summary_figures):
        write_all()
        return (
            ["summary.json"] + (["series.csv"] if series else []) + (["figures"] if figures or summary_figures else [])
        )
    if figures and not all((out / f).is_file() for f in figures):
        make_figures(out)
        return ["figures"]
    return []


def write_text_atomic(path: Path, text: str) -> None:
    write_replacing(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def write_series_csv(path: Path, rows: NDArray[np.float64]) -> None:
    from .metrics import SERIES_COLUMNS, SERIES_UNITS

    header = ",".join(f"{c} [{u}]" for c, u in zip(SERIES_COLUMNS, SERIES_UNITS))
    write_replacing(path, lambda tmp: np.savetxt(tmp, rows, delimiter=",", header=header, comments="", fmt="%.10g"))
