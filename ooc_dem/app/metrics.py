"""Wheel performance: slip, net traction, gross traction, torque, sinkage.

Sign conventions: the wheel drives in +x turning clockwise at omega > 0;
net traction = horizontal soil force on the wheel (+ forward);
torque = soil torque on the wheel, counter-clockwise positive (it resists the
clockwise drive, so it is positive when driving); gross traction = torque / R;
slip s = 1 - v / (R omega), omega the prescribed one, or the measured one when the
wheel's spin is free (wheel.control torque, towed); sinkage = initial surface height -
lowest rim point.

Accumulation is sequential, step by step, so the numbers do not depend on how
the steps were grouped into blocks (modes and restarts give the same bits).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from .run_stats import dp_w_entry, summary_spread
from ..physics.layout import REC_DB, REC_FX, REC_FY, REC_T, REC_TQ, REC_VX, REC_WZ, REC_X, REC_Y

if TYPE_CHECKING:
    from ..model.scenario import Scenario

SERIES_COLUMNS = (
    "t",
    "t_travel",
    "x",
    "y",
    "vx",
    "omega",
    "slip",
    "net_traction",
    "vertical_force",
    "torque",
    "gross_traction",
    "sinkage",
    "drawbar",
)
SERIES_UNITS = ("s", "s", "m", "m", "m/s", "rad/s", "-", "N", "N", "N m", "N", "m", "N")

# series row layout: the column index of each SERIES_COLUMNS name
(
    S_T,
    S_T_TRAVEL,
    S_X,
    S_Y,
    S_VX,
    S_OMEGA,
    S_SLIP,
    S_NET_TRACTION,
    S_VERTICAL_FORCE,
    S_TORQUE,
    S_GROSS_TRACTION,
    S_SINKAGE,
    S_DRAWBAR,
) = range(len(SERIES_COLUMNS))
N_SERIES = len(SERIES_COLUMNS)
SERIES_START_ROWS = 1024  # the series buffer starts this long and doubles when full

# interval accumulator layout
I_N, I_VX, I_WZ, I_FX, I_FY, I_TQ, I_Y, I_DB, I_X, I_YLAST, I_T = range(11)
N_IACC = 11
# window accumulator layout (per window)
W_N, W_FX, W_FY, W_TQ, W_SINK, W_X0, W_X1, W_T0, W_T1 = range(9)
N_WACC = 9


@njit(cache=True)
def _accumulate(
    rec: NDArray[np.float64],
    steps_per_row: int,
    step0: int,
    iacc: NDArray[np.float64],
    rows: NDArray[np.float64],
    nrows: NDArray[np.int64],
    wacc: NDArray[np.float64],
    windows: NDArray[np.float64],
    surface: float,
    radius: float,
    omega: float,
) -> None:
    """Fold per-step records into interval rows and window sums (sequentially)."""
    for s in range(rec.shape[0]):
        t = rec[s, REC_T]
        iacc[I_N] += 1.0
        iacc[I_VX] += rec[s, REC_VX]
        iacc[I_WZ] += rec[s, REC_WZ]
        iacc[I_FX] += rec[s, REC_FX]
        iacc[I_FY] += rec[s, REC_FY]
        iacc[I_TQ] += rec[s, REC_TQ]
        iacc[I_Y] += rec[s, REC_Y]
        iacc[I_DB] += rec[s, REC_DB]
        iacc[I_X] = rec[s, REC_X]
        iacc[I_YLAST] = rec[s, REC_Y]
        iacc[I_T] = t
        for k in range(windows.shape[0]):
            if t >= windows[k, 0] and t < windows[k, 1]:
                if wacc[k, W_N] == 0.0:
                    wacc[k, W_X0] = rec[s, REC_X]
                    wacc[k, W_T0] = t
                wacc[k, W_N] += 1.0
                wacc[k, W_FX] += rec[s, REC_FX]
                wacc[k, W_FY] += rec[s, REC_FY]
                wacc[k, W_TQ] += rec[s, REC_TQ]
                wacc[k, W_SINK] += surface - (rec[s, REC_Y] - radius)
                wacc[k, W_X1] = rec[s, REC_X]
                wacc[k, W_T1] = t
        if ((step0 + s + 1) % steps_per_row) == 0:
            n = iacc[I_N]
            r = nrows[0]
            if r < rows.shape[0]:  # the caller sized rows for this record (WheelMetrics.add)
                rows[r, S_T] = t
                rows[r, S_X] = iacc[I_X]
                rows[r, S_Y] = iacc[I_YLAST]
                rows[r, S_VX] = iacc[I_VX] / n
                rows[r, S_OMEGA] = -iacc[I_WZ] / n
                rows[r, S_SLIP] = (
                    (1.0 - (iacc[I_VX] / n) / (radius * omega)) if omega > 0 and iacc[I_WZ] != 0.0 else np.nan
                )
                rows[r, S_NET_TRACTION] = iacc[I_FX] / n
                rows[r, S_VERTICAL_FORCE] = iacc[I_FY] / n
                rows[r, S_TORQUE] = iacc[I_TQ] / n
                rows[r, S_GROSS_TRACTION] = iacc[I_TQ] / n / radius
                rows[r, S_SINKAGE] = surface - (iacc[I_Y] / n - radius)
                rows[r, S_DRAWBAR] = iacc[I_DB] / n
                nrows[0] = r + 1
            iacc[:] = 0.0


@njit(cache=True)
def _accumulate_spin(rec: NDArray[np.float64], windows: NDArray[np.float64], wspin: NDArray[np.float64]) -> None:
    """Sum each window's measured omega (-wz) step by step (sequentially): the distance the
    rim rolled when the spin is free."""
    for s in range(rec.shape[0]):
        t = rec[s, REC_T]
        for k in range(windows.shape[0]):
            if t >= windows[k, 0] and t < windows[k, 1]:
                wspin[k] -= rec[s, REC_WZ]


class WheelMetrics:
    """Time series and window averages of the wheel's performance."""

    def __init__(self, sc: Scenario, surface: float, total_steps: int) -> None:
        self.sc = sc
        self.surface = float(surface)
        dt = sc.physics.dt
        self.steps_per_row = max(1, int(round(sc.output.series_interval / dt)))
        self.iacc = np.zeros(N_IACC)
        # sized by the rows kept so far, not by the run's total step count (--steps 1e10 must
        # not allocate the whole series up front); grown by doubling (amortised) in add()
        self.rows = np.full((min(total_steps // self.steps_per_row + 1, SERIES_START_ROWS), N_SERIES), np.nan)
        self.nrows = np.zeros(1, np.int64)
        w = sc.wheel
        t0 = w.settle_time
        self.windows = np.array(
            [
                [t0, t0 + w.travel_time],
                [t0 + sc.output.steady_start, t0 + min(sc.output.steady_end, w.travel_time)],
                [t0 - min(0.1 * w.settle_time, 0.1), t0],  # static sinkage: end of settling
            ]
        )
        self.wacc = np.zeros((len(self.windows), N_WACC))
        # omega free (torque, towed): the slip is that of the measured omega
        self.free_spin = w.control in ("torque", "towed")
        self.wspin = np.zeros(len(self.windows))

    def add(self, rec: NDArray[np.float64], step0: int) -> None:
        if len(rec) == 0:
            return
        self._reserve(int(self.nrows[0]) + len(rec) // self.steps_per_row + 1)
        w = self.sc.wheel
        _accumulate(
            rec,
            self.steps_per_row,
            step0,
            self.iacc,
            self.rows,
            self.nrows,
            self.wacc,
            self.windows,
            self.surface,
            w.radius,
            w.omega,
        )
        if self.free_spin:
            _accumulate_spin(rec, self.windows, self.wspin)

    def _reserve(self, rows: int) -> None:
        """Room for at least ``rows`` series rows (never fewer than before; the new rows NaN)."""
        have = self.rows.shape[0]
        if rows <= have:
            return
        grown = np.full((max(rows, 2 * have), N_SERIES), np.nan)
        grown[:have] = self.rows
        self.rows = grown

    # ---- persistence (checkpoint) ----------------------------------------
    def state_arrays(self) -> dict[str, NDArray[np.float64]]:
        n = int(self.nrows[0])
        return {
            "metrics_iacc": self.iacc.copy(),
            "metrics_wacc": self.wacc.copy(),
            "metrics_rows": self.rows[:n].copy(),
            **({"metrics_wspin": self.wspin.copy()} if self.free_spin else {}),
        }

    def load_state(self, arrays: Mapping[str, NDArray[Any]]) -> None:
        self.iacc[:] = arrays["metrics_iacc"]
        self.wacc[:] = arrays["metrics_wacc"]
        rows = arrays["metrics_rows"]
        self._reserve(len(rows))
        self.rows[: len(rows)] = rows
        self.nrows[0] = len(rows)
        if self.free_spin:
            self.wspin[:] = arrays["metrics_wspin"]

    # ---- results -----------------------------------------------------------
    def series(self) -> NDArray[np.float64]:
        rows = self.rows[: int(self.nrows[0])].copy()
        rows[:, S_T_TRAVEL] = rows[:, S_T] - self.sc.wheel.settle_time
        if self.free_spin:  # the slip of the interval's measured omega (NaN while it is 0)
            rolled = self.sc.wheel.radius * rows[:, S_OMEGA]
            with np.errstate(divide="ignore", invalid="ignore"):
                rows[:, S_SLIP] = np.where(rolled != 0.0, 1.0 - rows[:, S_VX] / rolled, np.nan)
        return rows

    def _window(self, k: int) -> dict[str, Any]:
        a = self.wacc[k]
        w = self.sc.wheel
        n = a[W_N]
        if n == 0:
            return {"steps": 0}
        dt = self.sc.physics.dt
        t0 = self.windows[k, 0] - w.settle_time
        t1 = self.windows[k, 1] - w.settle_time
        # a run stopped early (--steps, --until) covers only part of the window: say so
        covered = a[W_T1] + dt - w.settle_time
        if covered < t1 - 0.5 * dt:
            t1 = covered
        dur = a[W_T1] - a[W_T0] + dt
        dist = a[W_X1] - a[W_X0]
        # slip needs a distance the rim would roll; a vanishing radius or omega has none
        rolled = w.radius * w.omega * dur
        if self.free_spin:
            rolled = w.radius * (self.wspin[k] / n) * dur
        return {
            "steps": int(n),
            "window_s": [float(t0), float(t1)],
            "slip": float(1.0 - dist / rolled) if rolled > 0 else None,
            "net_traction": float(a[W_FX] / n),
            "vertical_force": float(a[W_FY] / n),
            "torque": float(a[W_TQ] / n),
            "gross_traction": float(a[W_TQ] / n / w.radius),
            "sinkage": float(a[W_SINK] / n),
            "travel_distance": float(dist),
        }

    def summary(self) -> dict[str, Any]:
        whole, steady, static = self._window(0), self._window(1), self._window(2)

        def q(key: str, unit: str) -> dict[str, Any]:
            return {
                "unit": unit,
                "whole_travel": {"value": whole.get(key), "window_s": whole.get("window_s")},
                "steady": {"value": steady.get(key), "window_s": steady.get("window_s")},
            }

        out: dict[str, Any] = {
            "time_origin": "start of travel (end of the wheel's settling)",
            "slip": q("slip", "-"),
            "net_traction": q("net_traction", "N"),
            "gross_traction": q("gross_traction", "N"),
            "torque": q("torque", "N m"),
            "vertical_force": q("vertical_force", "N"),
            "travel_distance": q("travel_distance", "m"),
            "sinkage": q("sinkage", "m"),
        }
        mr = {}
        for name, win in (("whole_travel", whole), ("steady", steady)):
            if win.get("steps"):
                mr[name] = {"value": win["gross_traction"] - win["net_traction"], "window_s": win["window_s"]}
        out["motion_resistance"] = {"unit": "N", **mr}
        out["dp_w"] = dp_w_entry(out["net_traction"], self.sc.wheel.load)
        out["sinkage"]["static"] = {
            "value": static.get("sinkage"),
            "window_s": static.get("window_s"),
            "note": "mean over the last part of the settling phase (omega = 0)",
        }
        out["surface_height"] = {"unit": "m", "value": self.surface}
        if self.free_spin:
            w = self.sc.wheel
            omega = {}
            for name, win, k in (("whole_travel", whole, 0), ("steady", steady, 1)):
                if win.get("steps"):
                    omega[name] = {"value": float(self.wspin[k] / win["steps"]), "window_s": win["window_s"]}
            out["omega"] = {"unit": "rad/s", **omega, "note": f"measured (wheel.control = {w.control})"}
        # the steady entries' spread, from the series rows (the values above are the step
        # accumulator's and stay as they are)
        rows = self.series()
        summary_spread(out, {name: rows[:, k] for k, name in enumerate(SERIES_COLUMNS)}, self.sc)
        return out
