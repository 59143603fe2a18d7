"""The spread of a wheel run's steady-window results: summary.json's steady entries gain
``mean``, ``std``, ``ci95``, ``blocks``, ``passages``, ``block_s`` and ``stats_window_s``
(and a ``flag`` when the window is too short), computed from the run's series rows with
``stats.window_stats`` (docs/reference/statistics.md).

The block is one lug passage, 2 pi / (n_lugs omega); a wheel without lugs has blocks of
a fixed turn of the rim, SMOOTH_BLOCK_ANGLE (the passage of the paper's 18 lugs), so a
smooth and a lugged wheel at the same omega are cut alike. The entries' ``value`` (the
step-by-step mean over the whole window) is left as it is: ``mean`` is the mean over the
whole blocks the spread is of.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .stats import WindowStats, window_rows, window_stats

if TYPE_CHECKING:
    from ..model.scenario import Scenario

MIN_BLOCKS = 3  # a steady window of fewer whole blocks is flagged
SMOOTH_BLOCK_ANGLE = 2.0 * math.pi / 18.0  # rad the rim turns per block of a wheel without lugs
# the summary quantities whose steady entries carry a spread
SPREAD_QUANTITIES = (
    "slip",
    "net_traction",
    "gross_traction",
    "torque",
    "vertical_force",
    "sinkage",
    "motion_resistance",
    "dp_w",
    "travel_distance",
)


def block_period(sc: Scenario) -> float:
    """The statistics' block (s): a lug passage 2 pi / (n_lugs omega), or the time the rim
    takes to turn SMOOTH_BLOCK_ANGLE without lugs; inf for a wheel that does not turn."""
    w = sc.wheel
    if w.omega <= 0.0:
        return math.inf
    if w.n_lugs > 0:
        return 2.0 * math.pi / (w.n_lugs * w.omega)
    return SMOOTH_BLOCK_ANGLE / w.omega


def short_window_flag(sc: Scenario, blocks: int) -> str | None:
    """The flag of a steady window of ``blocks`` whole blocks (None: long enough)."""
    if blocks >= MIN_BLOCKS:
        return None
    unit = "lug passages" if sc.wheel.n_lugs > 0 else "blocks"
    return f"window shorter than {MIN_BLOCKS} {unit}"


def planned_blocks(sc: Scenario) -> float:
    """Blocks in the scenario's own steady window (its travel not cut short), fractional."""
    o, w = sc.output, sc.wheel
    length = max(0.0, min(o.steady_end, w.travel_time) - o.steady_start)
    period = block_period(sc)
    return length / period if math.isfinite(period) else 0.0


def _num(v: float) -> float | None:
    """A JSON-safe number: None for nan and inf."""
    return float(v) if math.isfinite(v) else None


def _fallback(t: NDArray[np.float64], values: NDArray[np.float64], start: float, end: float) -> WindowStats:
    """A window shorter than one block: the mean and std over all its rows, no interval."""
    idx, step = window_rows(t, start, end)
    if idx.size == 0:
        return WindowStats(math.nan, math.nan, math.nan, 0, 0, 0, (start, start))
    used = values[idx]
    std = float(np.std(used, ddof=1)) if used.size > 1 else math.nan
    window = (float(t[idx[0]] - step), float(t[idx[-1]]))
    return WindowStats(float(used.mean()), std, math.nan, 0, 0, int(used.size), window)


def steady_spread(
    cols: Mapping[str, NDArray[np.float64]], sc: Scenario, window: tuple[float, float]
) -> dict[str, dict[str, Any]]:
    """The spread fields of each summary quantity's steady entry, from the series columns
    ``cols`` (by name, as series.csv holds them) over ``window`` (s of travel: the steady
    entries' window_s)."""
    w = sc.wheel
    t = cols["t_travel"] if "t_travel" in cols else cols["t"] - w.settle_time
    start, end = window
    period = block_period(sc)
    lugged = w.n_lugs > 0

    def stats(values: NDArray[np.float64]) -> WindowStats:
        st = window_stats(t, values, start, end, period) if math.isfinite(period) else None
        return st if st is not None and st.blocks > 0 else _fallback(t, values, start, end)

    net = stats(cols["net_traction"])
    gross = stats(cols["gross_traction"])
    got = {
        "slip": stats(cols["slip"]),
        "net_traction": net,
        "gross_traction": gross,
        "torque": stats(cols["torque"]),
        "vertical_force": stats(cols["vertical_force"]),
        "sinkage": stats(cols["sinkage"]),
        "motion_resistance": stats(cols["gross_traction"] - cols["net_traction"]),
    }
    if w.load > 0.0:
        got["dp_w"] = net.scaled(1.0 / w.load)
    # the distance over the window: its mean speed times the window's length (a row has no
    # distance of its own, so no std)
    got["travel_distance"] = stats(cols["vx"]).scaled(end - start)
    flag = short_window_flag(sc, net.blocks)
    out: dict[str, dict[str, Any]] = {}
    for key, st in got.items():
        entry: dict[str, Any] = {
            "mean": _num(st.mean),
            "std": None if key == "travel_distance" else _num(st.std),
            "ci95": _num(st.ci95),
            "blocks": st.blocks,
            "passages": st.passages if lugged else None,
            "block_s": _num(period),
            "stats_window_s": [float(st.window[0]), float(st.window[1])] if st.rows else None,
        }
        if flag:
            entry["flag"] = flag
        out[key] = entry
    return out


def dp_w_entry(net_traction: dict[str, Any], load: float) -> dict[str, Any]:
    """summary.json's ``dp_w`` (drawbar pull over the wheel's load, the traction
    coefficient) from its ``net_traction`` entry: each window's value over ``load``."""
    out: dict[str, Any] = {"unit": "-"}
    for name in ("whole_travel", "steady"):
        win = net_traction.get(name)
        if isinstance(win, dict):
            v = win.get("value")
            out[name] = {"value": None if v is None or load <= 0.0 else v / load, "window_s": win.get("window_s")}
    return out


def summary_spread(summary: dict[str, Any], cols: Mapping[str, NDArray[np.float64]], sc: Scenario) -> None:
    """Add ``dp_w`` (when absent) and the spread fields of the steady entries to
    ``summary`` (in place); no spread if its steady window holds no step."""
    from .runfiles import summary_window

    if "dp_w" not in summary and isinstance(summary.get("net_traction"), dict):
        summary["dp_w"] = dp_w_entry(summary["net_traction"], sc.wheel.load)
    window = summary_window(summary, "net_traction", "steady")
    if window is None:
        return
    for key, fields in steady_spread(cols, sc, window).items():
        entry = summary.get(key)
        if isinstance(entry, dict) and isinstance(entry.get("steady"), dict):
            entry["steady"].update(fields)


def has_spread(summary: dict[str, Any]) -> bool:
    """Whether the summary's steady entries carry the spread (runs made before it do not)."""
    steady = (summary.get("net_traction") or {}).get("steady")
    return isinstance(steady, dict) and "ci95" in steady


def read_summary_with_spread(out: str | os.PathLike[str]) -> dict[str, Any]:
    """A finished run's summary.json, validated; a run made before the spread was written
    gets it (and ``dp_w``) computed from its series.csv and scenario.toml when it has them."""
    from .runfiles import read_run_scenario, read_series, read_summary, run_file

    summary = read_summary(out)
    if "slip" not in summary or has_spread(summary):
        return summary
    series = run_file(out, "series.csv")
    sc = read_run_scenario(out)
    if series is not None and sc is not None:
        summary_spread(summary, read_series(series), sc)
    return summary
