"""Steady-window statistics of a run's series (a run's summary, `ooc-dem sweep`, `ooc-dem
experiment`; docs/reference/statistics.md): the window cut to a whole number of lug
passages, the mean and standard deviation over its rows, and a 95 % confidence interval of
the mean from block averages (one block per lug passage, or per group of passages; Student
t with nb - 1 degrees of freedom).

A lugged wheel's forces oscillate with the lug passage period 2 pi / (n_lugs omega): a
window of whole passages averages whole oscillations (its mean does not depend on where
the window starts within a passage), and the passages' means are nearly independent
samples of the steady state, so their spread gives the mean's uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


def t_quantile_975(dof: int) -> float:
    """The 97.5 % quantile of Student's t (the half-width factor of a two-sided 95 %
    interval) for ``dof`` >= 1 degrees of freedom."""
    from scipy.stats import t

    if dof < 1:
        raise ValueError(f"degrees of freedom {dof}: must be >= 1")
    return float(t.ppf(0.975, dof))


@dataclass(frozen=True)
class WindowStats:
    """A quantity over the steady window cut to whole lug passages."""

    mean: float
    std: float  # over the window's rows (ddof = 1)
    ci95: float  # half-width of the mean's 95 % interval (nan with fewer than 2 blocks)
    blocks: int
    passages: int
    rows: int
    window: tuple[float, float]  # s of travel, the part of the window used

    def scaled(self, factor: float, offset: float = 0.0) -> WindowStats:
        """The statistics of factor * quantity + offset."""
        return WindowStats(
            factor * self.mean + offset,
            abs(factor) * self.std,
            abs(factor) * self.ci95,
            self.blocks,
            self.passages,
            self.rows,
            self.window,
        )

    def as_dict(self) -> dict[str, object]:
        return {
            "mean": self.mean,
            "std": self.std,
            "ci95": None if math.isnan(self.ci95) else self.ci95,
            "blocks": self.blocks,
            "passages": self.passages,
            "rows": self.rows,
            "window_s": list(self.window),
        }


def window_rows(t_end: NDArray[np.float64], start: float, end: float) -> tuple[NDArray[np.intp], float]:
    """The rows (by index) whose whole interval lies in [start, end] (each row is the mean
    over the interval ending at its time ``t_end``), and the row interval."""
    if len(t_end) < 2:
        return np.arange(0, dtype=np.intp), math.nan
    step = float(np.median(np.diff(t_end)))
    eps = 1e-6 * step
    inside = (t_end - step >= start - eps) & (t_end <= end + eps)
    return np.flatnonzero(inside), step


def window_stats(
    t_end: NDArray[np.float64],
    values: NDArray[np.float64],
    start: float,
    end: float,
    period: float,
    passages_per_block: int = 1,
) -> WindowStats:
    """Statistics of ``values`` (rows ending at ``t_end``) over the window [start, end] cut
    to a whole number of blocks of ``passages_per_block`` passages of ``period`` (s): block j
    is rows [round(j m), round((j + 1) m)) of the window, m = rows per block (not a whole
    number in general; with a whole number the cut is exact)."""
    idx, step = window_rows(t_end, start, end)
    per_block = passages_per_block * period / step if idx.size else math.nan
    nb = int(math.floor(idx.size / per_block + 1e-9)) if idx.size else 0
    if nb < 1:
        return WindowStats(math.nan, math.nan, math.nan, 0, 0, 0, (start, start))
    bounds = [int(round(j * per_block)) for j in range(nb + 1)]
    used = values[idx[: bounds[-1]]]
    block_means = np.array([values[idx[a:b]].mean() for a, b in zip(bounds, bounds[1:])])
    ci = math.nan
    if nb >= 2:
        ci = t_quantile_975(nb - 1) * float(np.std(block_means, ddof=1)) / math.sqrt(nb)
    t0 = float(t_end[idx[0]] - step)
    t1 = float(t_end[idx[bounds[-1] - 1]])
    return WindowStats(
        mean=float(used.mean()),
        std=float(np.std(used, ddof=1)) if used.size > 1 else math.nan,
        ci95=ci,
        blocks=nb,
        passages=nb * passages_per_block,
        rows=int(used.size),
        window=(t0, t1),
    )


def difference(a: WindowStats, b: WindowStats) -> tuple[float, float]:
    """(a - b, the 95 % half-width of the difference of two independent means: Welch's
    interval, its degrees of freedom rounded down)."""
    diff = a.mean - b.mean
    if a.blocks < 2 or b.blocks < 2 or math.isnan(a.ci95) or math.isnan(b.ci95):
        return diff, math.nan
    se_a = a.ci95 / t_quantile_975(a.blocks - 1)
    se_b = b.ci95 / t_quantile_975(b.blocks - 1)
    se2 = se_a**2 + se_b**2
    if se2 == 0.0:
        return diff, 0.0
    dof = se2**2 / (se_a**4 / (a.blocks - 1) + se_b**4 / (b.blocks - 1))
    return diff, t_quantile_975(max(1, int(math.floor(dof)))) * math.sqrt(se2)
