"""Sub-domain policies: vertical slabs of the bin.

A decomposition is an ascending array of D+1 slab bounds; the first is -inf and
the last +inf so every disc has exactly one owner (the slab holding its x).

``wheel`` (the paper's Fig. 3): the slab holding the wheel and the soil under it
is one sub-domain; the soil left and right of it is split into the remaining
sub-domains as evenly as possible by disc count. It is redefined when the wheel
comes within the required margin of its slab's edge.
``equal``: D slabs with equal disc counts (runs without a wheel).

The policies read the discs' x only through an ``XHistogram``: counts in X_BINS fixed
bins over the bin's length, the sum of small per-group summaries (``x_summary``, stored
with each out-of-core group), so a re-decomposition never holds one value per disc of the
whole bed. Counts add exactly, so the bounds are the same whatever the partition into
groups (every mode, D, K, resume); within a bin the count is taken as uniform in x.
Bounds never change a result bit (docs/design.md §3), only how the work is split.
"""

from __future__ import annotations

import numpy as np


X_BINS = 4096  # histogram bins over the bin's length (a summary holds at most this many counts)


def _bins(x: np.ndarray, length: float) -> np.ndarray:
    """Bin index of each x (elementwise, so the same for any grouping); outside [0, length)
    clamped to the end bins."""
    b = np.floor(np.asarray(x, np.float64) * (X_BINS / length))
    return np.clip(b, 0, X_BINS - 1).astype(np.int64)


def x_summary(x: np.ndarray, length: float) -> dict:
    """A group's x summary: {"length", "first", "counts"} = the counts of its discs in bins
    first, first+1, ... (the occupied span only: at most X_BINS small integers)."""
    if not len(x):
        return {"length": float(length), "first": 0, "counts": []}
    b = _bins(x, length)
    first = int(b.min())
    return {"length": float(length), "first": first, "counts": [int(c) for c in np.bincount(b - first)]}


def summary_ok(s, length: float, n) -> bool:
    """Whether `s` is a well-formed x summary over `length` counting n discs (a store is
    untrusted input: a summary that is not is recomputed from the group's x)."""
    if not isinstance(s, dict) or s.get("length") != float(length):
        return False
    first, counts = s.get("first"), s.get("counts")
    if type(first) is not int or not isinstance(counts, list) or not 0 <= first <= X_BINS:
        return False
    if first + len(counts) > X_BINS or any(type(c) is not int or c < 0 for c in counts):
        return False
    return sum(counts) == n


class XHistogram:
    """Disc counts in X_BINS bins over [0, length): the input of the slab policies."""

    def __init__(self, length: float):
        if not (length > 0 and np.isfinite(length)):
            raise ValueError(f"bin length {length!r}: must be > 0")
        self.length = float(length)
        self.counts = np.zeros(X_BINS, np.int64)

    @classmethod
    def of(cls, x: np.ndarray, length: float) -> "XHistogram":
        h = cls(length)
        h.add_x(x)
        return h

    def add_x(self, x: np.ndarray) -> None:
        self.counts += np.bincount(_bins(x, self.length), minlength=X_BINS)

    def add_summary(self, s: dict) -> None:
        c = np.asarray(s["counts"], np.int64)
        self.counts[s["first"] : s["first"] + len(c)] += c

    @property
    def n(self) -> int:
        return int(self.counts.sum())

    def below(self, x: float) -> float:
        """Discs with position < x (uniform within a bin)."""
        if not x > 0:
            return 0.0
        if x >= self.length:
            return float(self.n)
        w = self.length / X_BINS
        b = min(X_BINS - 1, int(x // w))
        return float(self.counts[:b].sum()) + float(self.counts[b]) * (x - b * w) / w

    def position(self, c: float) -> float:
        """The x below which c discs lie (the inverse of ``below``; 0 < c <= n)."""
        cum = np.cumsum(self.counts)
        b = int(np.searchsorted(cum, c, "left"))
        b = min(b, X_BINS - 1)
        before = float(cum[b - 1]) if b else 0.0
        w = self.length / X_BINS
        inside = float(self.counts[b])
        frac = (c - before) / inside if inside else 0.0
        return b * w + min(1.0, max(0.0, frac)) * w


def _quantile_bounds(h: XHistogram, k: int, lo: float, hi: float) -> list[float]:
    """k-1 inner bounds splitting the discs within [lo, hi) into k equal counts."""
    c_lo = h.below(lo) if np.isfinite(lo) else 0.0
    c_hi = h.below(hi) if np.isfinite(hi) else float(h.n)
    out = []
    for j in range(1, k):
        if c_hi <= c_lo:
            # an empty side: degenerate (empty) slabs at its finite end
            out.append(lo if np.isfinite(lo) else hi if np.isfinite(hi) else 0.0)
        else:
            v = h.position(c_lo + j * (c_hi - c_lo) / k)
            out.append(float(min(max(v, lo), hi)))
    return out


def equal_bounds(h: XHistogram, domains: int) -> np.ndarray:
    inner = _quantile_bounds(h, domains, -np.inf, np.inf)
    return np.maximum.accumulate(np.array([-np.inf, *inner, np.inf]))


def wheel_bounds(h: XHistogram, domains: int, wheel_x: float, half_width: float) -> np.ndarray:
    """Bounds with the wheel slab [wheel_x - half_width, wheel_x + half_width).

    The remaining D-1 slabs go left and right in proportion to the disc counts
    there (each non-empty side gets at least one while D-1 >= 2); a side with no
    slab is absorbed by the wheel slab.
    """
    lo, hi = wheel_x - half_width, wheel_x + half_width
    if domains == 1:
        return np.array([-np.inf, np.inf])
    n_left = h.below(lo)
    n_right = h.n - h.below(hi)
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
        bounds += _quantile_bounds(h, k_left, -np.inf, lo) + [lo]
    if k_right > 0:
        bounds += [hi] + _quantile_bounds(h, k_right, hi, np.inf)
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


def group_order(pos: np.ndarray, cell: float) -> np.ndarray:
    """Permutation sorting particles by the cell of a grid of side `cell` anchored at the
    origin: x column first, then y (then z). Groups are stored in this order, so a slab
    read from them (strips in x order) is already in the kernels' cache-friendly order
    (neighbours close in memory: 16 % faster steps than x order at 500k discs) and needs
    no re-sort; x stays sorted up to one column, so strips stay contiguous
    (engine.sweep.read_strip). Memory order never changes a result (docs/design.md section 3)."""
    if not len(pos):
        return np.zeros(0, np.int64)
    # one int64 key per particle: the x column in the high bits, then y (and z) rows in
    # fields of 21 bits (2D) or 16 bits (3D: 65536 rows, 300 m at 5 mm cells), the column
    # keeping the rest (2^41 / 2^30 columns); coordinates past a field are clipped (a
    # particle flown off only loses locality, never a result). Sorted stably: the order of
    # rows already in cell order is found in one pass
    cells = np.floor(pos / cell)
    bits = 21 if pos.shape[1] == 2 else 16
    column = 2.0 ** (62 - bits * (pos.shape[1] - 1))
    key = np.clip(cells[:, 0], -column, column - 1).astype(np.int64)
    for k in range(1, pos.shape[1]):
        row = np.clip(cells[:, k], -(2.0 ** (bits - 1)), 2.0 ** (bits - 1) - 1).astype(np.int64)
        key = (key << bits) + (row + 2 ** (bits - 1))
    return np.argsort(key, kind="stable")
