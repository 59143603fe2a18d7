"""Sub-domain policies: vertical slabs of the bin.

A decomposition is an ascending array of D+1 slab bounds; the first is -inf and
the last +inf so every disc has exactly one owner (the slab holding its x).

``wheel`` (the paper's Fig. 3): the slab holding the wheel and the soil under it
is one sub-domain; the soil left and right of it is split into the remaining
sub-domains as evenly as possible by disc count. It is redefined when the wheel
comes within the required margin of its slab's edge.
``equal``: D slabs with equal disc counts (runs without a wheel).
"""
from __future__ import annotations

import numpy as np


def _quantile_bounds(xs_sorted: np.ndarray, k: int, lo: float, hi: float) -> list[float]:
    """k-1 inner bounds splitting sorted positions within [lo, hi) into k equal counts."""
    sel = xs_sorted[(xs_sorted >= lo) & (xs_sorted < hi)]
    out = []
    for j in range(1, k):
        if len(sel) == 0:
            # an empty side: degenerate (empty) slabs at its finite end
            out.append(lo if np.isfinite(lo) else hi if np.isfinite(hi) else 0.0)
        else:
            idx = min(len(sel) - 1, int(round(j * len(sel) / k)))
            out.append(float(sel[idx]))
    return out


def equal_bounds(x: np.ndarray, domains: int) -> np.ndarray:
    xs = np.sort(np.asarray(x, np.float64))
    inner = _quantile_bounds(xs, domains, -np.inf, np.inf)
    return np.array([-np.inf, *inner, np.inf])


def wheel_bounds(x: np.ndarray, domains: int, wheel_x: float, half_width: float) -> np.ndarray:
    """Bounds with the wheel slab [wheel_x - half_width, wheel_x + half_width).

    The remaining D-1 slabs go left and right in proportion to the disc counts
    there (each non-empty side gets at least one while D-1 >= 2); a side with no
    slab is absorbed by the wheel slab.
    """
    xs = np.sort(np.asarray(x, np.float64))
    lo, hi = wheel_x - half_width, wheel_x + half_width
    if domains == 1:
        return np.array([-np.inf, np.inf])
    n_left = int(np.searchsorted(xs, lo))
    n_right = len(xs) - int(np.searchsorted(xs, hi))
    rest = domains - 1
    if n_left + n_right == 0:
        k_left = rest // 2
    else:
        k_left = int(round(rest * n_left / (n_left + n_right)))
    k_left = min(max(k_left, 0), rest)
    if rest >= 2:
        if n_left > 0 and k_left == 0:
            k_left = 1
        if n_right > 0 and k_left == rest:
            k_left = rest - 1
    k_right = rest - k_left
    bounds = [-np.inf]
    if k_left > 0:
        bounds += _quantile_bounds(xs, k_left, -np.inf, lo) + [lo]
    if k_right > 0:
        bounds += [hi] + _quantile_bounds(xs, k_right, hi, np.inf)
    bounds.append(np.inf)
    b = np.array(bounds)
    # degenerate (equal) bounds are allowed: an empty slab is a valid, empty sub-domain
    return np.maximum.accumulate(b)


def wheel_slab_index(bounds: np.ndarray, wheel_x: float) -> int:
    return int(np.searchsorted(bounds, wheel_x, side="right") - 1)


def wheel_slab_ok(bounds: np.ndarray, wheel_x: float, reach: float, margin: float) -> bool:
    """True while the wheel's reach plus margin stays inside its slab."""
    k = wheel_slab_index(bounds, wheel_x)
    return bounds[k] <= wheel_x - reach - margin and wheel_x + reach + margin < bounds[k + 1]


def owner(bounds: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Slab index of each position."""
    return np.searchsorted(bounds, x, side="right") - 1
